"""A cheap closed-form Normbox world for tests and the engine bench (the `World` protocol).

    L(λ) = ρ_patch(λ)/π · L_panel(λ) · (Ω_direct · max(cos s, 0) + Ω_indirect)

- ρ_patch: ColorChecker "N Ohta" reflectances from colour-science (5 nm, interpolated to 1 nm);
  an empty holder is black (ρ = 0.03).
- L_panel: a Planckian spectrum (default 3100 K) scaled to `panel_luminance_cd_m2` (3000 cd/m²,
  the virtual Normbox's defaults).
- s: the sample angle (0° = facing the light, 90° = facing the radiometer); the direct term is
  the panel's solid angle seen from the sample times cos s, the indirect term a constant.

The gonioreflectometer truth is Lambertian: f = ρ/π.  The light map sees the panel with a smooth
±`panel_homogeneity_percent` variation.  Milliseconds per call; no rendering.

The 24 reflectances come from the virtual Normbox's cached table (`materials.py`), kept in
``$NORMBOX_LAB_CACHE`` (default ``~/.cache/normbox-lab``) after the first use.
"""

from __future__ import annotations

import numpy as np

from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.sim.world_state import WorldState

H_J_S = 6.62607015e-34
C_M_S = 2.99792458e8
K_J_K = 1.380649e-23
KM_LM_W = 683.002
HOLDER_REFLECTANCE = 0.03


def colorchecker_reflectances() -> np.ndarray:
    """(24, 401) reflectances at RADIOMETER_WAVELENGTHS_NM, patch N at row N - 1 (the virtual
    Normbox's cached 5 nm table — the Ohta data's own grid — interpolated to 1 nm)."""
    from normbox_lab.predict.materials import MATERIAL_WAVELENGTHS_NM
    from normbox_lab.predict.materials import colorchecker_reflectances as table_5nm

    return np.array([np.interp(RADIOMETER_WAVELENGTHS_NM, MATERIAL_WAVELENGTHS_NM, row)
                     for row in table_5nm()])


def planck_W_sr_m2_nm(wavelength_nm: np.ndarray, temperature_K: float) -> np.ndarray:
    wl_m = np.asarray(wavelength_nm, dtype=float) * 1e-9
    return (2 * H_J_S * C_M_S**2 / wl_m**5
            / np.expm1(H_J_S * C_M_S / (wl_m * K_J_K * temperature_K))) * 1e-9


def _v_lambda() -> np.ndarray:
    """CIE 1924 photopic V(λ), Gaussian approximation (only used to scale the lamp)."""
    wl = RADIOMETER_WAVELENGTHS_NM
    return 1.019 * np.exp(-285.4 * (wl / 1000.0 - 0.559) ** 2)


class AnalyticWorld(WorldState):
    """The `World` protocol in closed form; state (`WorldState`) is changed by the operator and
    the rotator."""

    def __init__(self, *, lamp_cct_K: float = 3100.0, panel_luminance_cd_m2: float = 3000.0,
                 direct_solid_angle_sr: float = 0.25, indirect_solid_angle_sr: float = 0.08,
                 panel_homogeneity_percent: float = 3.0) -> None:
        self.wavelength_nm = RADIOMETER_WAVELENGTHS_NM.copy()
        self.reflectance = colorchecker_reflectances()
        spd = planck_W_sr_m2_nm(self.wavelength_nm, lamp_cct_K)
        lum = KM_LM_W * float(np.sum(spd * _v_lambda()))
        self.panel_W_sr_m2_nm = spd * (panel_luminance_cd_m2 / lum)
        self.direct_sr = direct_solid_angle_sr
        self.indirect_sr = indirect_solid_angle_sr
        self.homogeneity = panel_homogeneity_percent / 100.0
        super().__init__()

    # --- what the instruments see -----------------------------------------------------------
    def _rho(self, material: str | int | None) -> np.ndarray:
        if material is None:
            return np.full_like(self.wavelength_nm, HOLDER_REFLECTANCE)
        if isinstance(material, str) and material.startswith("patch-"):
            material = int(material[6:])
        if isinstance(material, str) and not material.isdigit():
            # the wall paint: a flat grey of lightness L≈65 (Y≈0.34)
            return np.full_like(self.wavelength_nm, 0.34)
        return self.reflectance[int(material) - 1]

    def panel_factor(self, x_mm: float, y_mm: float) -> float:
        """Smooth fall-off towards the panel's corners, ±homogeneity over the panel."""
        r2 = (x_mm / 110.0) ** 2 + (y_mm / 100.0) ** 2
        return 1.0 + self.homogeneity * (1.0 - r2)

    def radiance_at(self, patch: int | None, angle_deg: float) -> np.ndarray:
        """At full lamp output."""
        geometry = self.direct_sr * max(np.cos(np.radians(angle_deg)), 0.0) + self.indirect_sr
        return self._rho(patch) / np.pi * self.panel_W_sr_m2_nm * geometry

    def radiance_in_view(self) -> tuple[np.ndarray, np.ndarray]:
        output = self.relative_output()
        if self.aim is not None:
            return self.wavelength_nm.copy(), self.panel_radiance(*self.aim) * output
        return self.wavelength_nm.copy(), self.radiance_at(self.patch, self.angle_deg()) * output

    def panel_radiance(self, x_mm: float, y_mm: float) -> np.ndarray:
        return self.panel_W_sr_m2_nm * self.panel_factor(x_mm, y_mm)

    def panel_luminance_cd_m2(self, x_mm: float = 0.0, y_mm: float = 0.0) -> float:
        return KM_LM_W * float(np.sum(self.panel_radiance(x_mm, y_mm) * _v_lambda()))

    def luminance_cd_m2(self, patch: int | None, angle_deg: float) -> float:
        return KM_LM_W * float(np.sum(self.radiance_at(patch, angle_deg) * _v_lambda()))

    def brdf_truth(self, theta_i_deg: float, theta_o_deg: float, tilt_deg: float,
                   wavelength_nm: np.ndarray) -> np.ndarray:
        rho = np.interp(np.asarray(wavelength_nm, dtype=float), self.wavelength_nm,
                        self._rho(self.gonio_material))
        return rho / np.pi
