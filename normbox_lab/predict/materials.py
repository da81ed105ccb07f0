"""Materials of the virtual Normbox: the 24 ColorChecker patches, the grey wall, the black holder.

A `Material` is plain data (numpy arrays and floats) so that it can come from colour-science
(the *truth* of the virtual world) or from a fit (`normbox_lab.predict.brdf_model.MaterialFit`, the
*prediction*).  One BRDF family covers both:

    f(λ, ωi, ωo) = kd(λ)/π + ks(λ) · D(h; α) · F(ωi·h; η(λ)) · G1(ωi) G1(ωo) / (4 cosθi cosθo) − c
                   + kb(λ) · exp((ωi·ωo − 1) / σb²) / π                     (backscatter lobe)

with η(λ) = η + dη_per_100nm · (λ − 550 nm) / 100 nm.  With kb = 0 and dη = 0 this is exactly
the fit model `normbox_lab.predict.brdf_model.ct_ggx_brdf` (`truth_brdf` then calls it).  The truth
materials (`truth_material(n, truth="default")`) switch both extras on, so the fit model cannot
represent them exactly (as the paper found: blue-dominated backscatter, a wavelength-dependent
Fresnel reflection that is stronger in the red); `truth="model"` drops them (closure test).

Patch numbering (ColorChecker N Ohta order, colour-science's `SDS_COLOURCHECKERS`):
 1 dark skin      2 light skin     3 blue sky       4 foliage        5 blue flower    6 bluish green
 7 orange         8 purplish blue  9 moderate red  10 purple        11 yellow green  12 orange yellow
13 blue          14 green         15 red           16 yellow        17 magenta       18 cyan
19 white 9.5     20 neutral 8     21 neutral 6.5   22 neutral 5     23 neutral 3.5   24 black 2

The grey wall paint (RAL 7004, L*≈65, a*, b* < 1) is spectrally flat with ρ = Y/100 from the CIE
inverse of L*: Y/Yn = ((L* + 16)/116)³ for L* > 8 (κ-branch below), so L* = 65 → ρ = 0.3404.
The black holder paint is a flat diffuse ρ = 0.04 (a matte black paint).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.core.spectral import BAND_WAVELENGTHS_NM, COLORCHECKER_DATASET, PATCH_NAMES
from normbox_lab.predict.brdf_model import GgxParameters

#: the common grid the materials are tabulated on (the ColorChecker N Ohta data: 5 nm)
MATERIAL_WAVELENGTHS_NM = BAND_WAVELENGTHS_NM

WALL_LIGHTNESS_L = 65.0
HOLDER_REFLECTANCE = 0.04

#: Truth parameters per patch: (alpha, ks, eta at 550 nm, dη per 100 nm, backscatter b).
#: Rough patches α 0.30–0.60; patch 18 (cyan) is the smooth one (α 0.15, the paper's outlier).
#: ks is spectrally flat (the binder's dielectric surface), 0.48–0.60, η ≈ 1.45–1.60; dη > 0 makes the Fresnel
#: reflection redder at grazing angles; b scales the blue-growing backscatter lobe.
TRUTH_PATCH_PARAMS: dict[int, tuple[float, float, float, float, float]] = {
    1: (0.45, 0.54, 1.50, 0.020, 0.20),
    2: (0.40, 0.54, 1.52, 0.020, 0.22),
    3: (0.50, 0.51, 1.50, 0.025, 0.25),
    4: (0.55, 0.51, 1.48, 0.020, 0.20),
    5: (0.45, 0.54, 1.50, 0.025, 0.25),
    6: (0.40, 0.54, 1.52, 0.020, 0.22),
    7: (0.35, 0.57, 1.55, 0.030, 0.18),
    8: (0.45, 0.54, 1.50, 0.025, 0.28),
    9: (0.40, 0.54, 1.52, 0.025, 0.20),
    10: (0.50, 0.51, 1.50, 0.020, 0.25),
    11: (0.45, 0.54, 1.50, 0.020, 0.20),
    12: (0.35, 0.57, 1.55, 0.030, 0.18),
    13: (0.50, 0.51, 1.48, 0.025, 0.30),
    14: (0.55, 0.51, 1.50, 0.020, 0.22),
    15: (0.35, 0.57, 1.55, 0.030, 0.18),
    16: (0.30, 0.57, 1.58, 0.030, 0.15),
    17: (0.40, 0.54, 1.52, 0.025, 0.22),
    18: (0.15, 0.60, 1.60, 0.040, 0.12),
    19: (0.60, 0.48, 1.50, 0.015, 0.15),
    20: (0.55, 0.48, 1.50, 0.015, 0.18),
    21: (0.50, 0.51, 1.50, 0.015, 0.20),
    22: (0.50, 0.51, 1.50, 0.015, 0.22),
    23: (0.45, 0.51, 1.50, 0.015, 0.25),
    24: (0.40, 0.54, 1.50, 0.015, 0.30),
}
#: the grey wall paint: (alpha, ks, eta, dη per 100 nm, b)
TRUTH_WALL_PARAMS = (0.50, 0.36, 1.50, 0.020, 0.15)
#: backscatter lobe width σb (exp((cos γ − 1)/σb²); γ = angle between ωi and ωo): 1/e at γ ≈ 25°
BACKSCATTER_SIGMA = 0.30
#: backscatter colour: kb(λ) = b · kd(λ) · (550 nm / λ)^BACKSCATTER_BLUE_EXPONENT
BACKSCATTER_BLUE_EXPONENT = 3.0

TRUTH_KINDS = ("default", "model", "paper")

#: `truth="paper"`: the default truth with the backscatter lobe ×1.5 and the Fresnel dispersion
#: dη ×2 (fit errors 6–10 % instead of 4–7 %, the paper's 5–10 %), and patch 18 (cyan, the
#: smooth one) with a strong backscatter and dispersion (fit error ≈ 18 %, the paper's outlier);
#: calibrated with the fits of the gonio data (docs/error-budget.md).  Keys "wall" or 1..24.
PAPER_BACKSCATTER_FACTOR = 1.5
PAPER_DISPERSION_FACTOR = 2.0
PAPER_TRUTH_CHANGES: dict[int | str, tuple[float, float, float, float, float]] = {
    **{n: (a, ks, eta, de * PAPER_DISPERSION_FACTOR, b * PAPER_BACKSCATTER_FACTOR)
       for n, (a, ks, eta, de, b) in TRUTH_PATCH_PARAMS.items()},
    "wall": (TRUTH_WALL_PARAMS[0], TRUTH_WALL_PARAMS[1], TRUTH_WALL_PARAMS[2],
             TRUTH_WALL_PARAMS[3] * PAPER_DISPERSION_FACTOR,
             TRUTH_WALL_PARAMS[4] * PAPER_BACKSCATTER_FACTOR),
    18: (0.15, 0.60, 1.60, 0.12, 0.90),
}


@dataclass
class Material(GgxParameters):
    """One material of the BRDF family above: the fit model's parameters (`GgxParameters`) and
    the truth's extras.  Spectra on `wavelength_nm` (any increasing grid; constant
    extrapolation outside it).  `kb` None = no backscatter lobe."""

    c: float = 0.0
    deta_per_100nm: float = 0.0
    kb: np.ndarray | None = None
    backscatter_sigma: float = BACKSCATTER_SIGMA
    metadata: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelength_nm, dtype=np.float64)
        object.__setattr__(self, "wavelength_nm", wl)
        for name in ("kd", "ks", "kb"):
            v = getattr(self, name)
            if v is None:
                continue
            arr = np.broadcast_to(np.asarray(v, dtype=np.float64), wl.shape).copy()
            object.__setattr__(self, name, arr)
        if self.alpha <= 0:
            raise ValueError(f"material {self.name}: alpha must be > 0, got {self.alpha}")

    @property
    def is_model_family(self) -> bool:
        """True if exactly the fit model (no backscatter, no dispersion)."""
        return (self.kb is None or not np.any(self.kb)) and self.deta_per_100nm == 0.0

    def spectra_at(self, wavelength_nm: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(kd, ks, kb) interpolated linearly onto `wavelength_nm`."""
        wl = np.asarray(wavelength_nm, dtype=np.float64)
        kd = np.interp(wl, self.wavelength_nm, self.kd)
        ks = np.interp(wl, self.wavelength_nm, self.ks)
        kb = np.zeros_like(wl) if self.kb is None else np.interp(wl, self.wavelength_nm, self.kb)
        return kd, ks, kb

    def eta_at(self, wavelength_nm: Any) -> np.ndarray:
        wl = np.asarray(wavelength_nm, dtype=np.float64)
        return self.eta + self.deta_per_100nm * (wl - 550.0) / 100.0

    def digest(self) -> str:
        """A content hash (cache key part): everything that changes the rendered radiance."""
        h = hashlib.sha256()
        h.update(json.dumps([self.alpha, self.eta, self.c, self.deta_per_100nm,
                             self.backscatter_sigma]).encode())
        for arr in (self.wavelength_nm, self.kd, self.ks, self.kb):
            h.update(b"none" if arr is None else np.ascontiguousarray(arr, np.float64).tobytes())
        return h.hexdigest()[:24]

    def without_c(self) -> Material:
        return replace(self, c=0.0)

    @classmethod
    def from_fit(cls, fit: Any, name: str | None = None) -> Material:
        """From a `MaterialFit` (or anything with wavelength_nm, kd, ks, alpha, eta, c)."""
        return cls(name=name or getattr(fit, "name", "fit"), wavelength_nm=fit.wavelength_nm,
                   kd=fit.kd, ks=fit.ks, alpha=float(fit.alpha), eta=float(fit.eta),
                   c=float(fit.c), metadata={"source": "fit"})

    @classmethod
    def diffuse(cls, name: str, reflectance: Any, wavelength_nm: Any = None) -> Material:
        """A Lambertian material (ks = 0)."""
        wl = MATERIAL_WAVELENGTHS_NM if wavelength_nm is None else wavelength_nm
        return cls(name=name, wavelength_nm=wl, kd=reflectance, ks=0.0, alpha=0.5, eta=1.5)


# --- data ---------------------------------------------------------------------------------------
def _cache_dir() -> Path:
    return Path(os.environ.get("NORMBOX_LAB_CACHE", Path.home() / ".cache" / "normbox-lab"))


def colorchecker_reflectances() -> np.ndarray:
    """(24, 81) ColorChecker N Ohta reflectances on MATERIAL_WAVELENGTHS_NM; patch n at row n−1.

    colour-science takes seconds to import, so the table is cached under $NORMBOX_LAB_CACHE."""
    path = _cache_dir() / "colorchecker_n_ohta_380_780_5nm.npy"
    try:
        data = np.load(path)
        if data.shape == (24, MATERIAL_WAVELENGTHS_NM.size):
            return data
    except (OSError, ValueError):
        pass
    import colour

    sds = colour.SDS_COLOURCHECKERS[COLORCHECKER_DATASET]
    data = np.array([np.interp(MATERIAL_WAVELENGTHS_NM, sd.wavelengths, sd.values)
                     for sd in sds.values()])
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npy")
        with os.fdopen(fd, "wb") as f:
            np.save(f, data)
        os.replace(tmp, path)
    except OSError:
        pass
    return data


def reflectance_from_lightness(L: float) -> float:
    """Y/Yn from CIE L* (the CIE 1976 inverse): ((L*+16)/116)³ above L* = 8, L*/κ below."""
    kappa = 24389.0 / 27.0
    if L > 8.0:
        return ((L + 16.0) / 116.0) ** 3
    return L / kappa


def _check_truth(truth: str) -> None:
    if truth not in TRUTH_KINDS:
        raise ValueError(f"truth must be one of {TRUTH_KINDS}, got {truth!r}")


def _truth_from_params(name: str, kd: np.ndarray, params: tuple[float, ...], truth: str,
                       extra: dict[str, Any]) -> Material:
    if truth == "paper":
        key: int | str = extra.get("patch", "wall")
        params = PAPER_TRUTH_CHANGES.get(key, params)
    alpha, ks, eta, deta, b = params
    wl = MATERIAL_WAVELENGTHS_NM
    if truth == "model":
        return Material(name, wl, kd, ks, alpha, eta, 0.0,
                        metadata={"truth": "model", **extra})
    kb = b * kd * (550.0 / wl) ** BACKSCATTER_BLUE_EXPONENT
    return Material(name, wl, kd, ks, alpha, eta, 0.0, deta_per_100nm=deta, kb=kb,
                    metadata={"truth": truth, **extra})


def truth_patch(n: int, truth: str = "default") -> Material:
    """The virtual world's ColorChecker patch n (1..24); kd(λ) = the N Ohta reflectance."""
    _check_truth(truth)
    if not 1 <= int(n) <= 24:
        raise ValueError(f"no ColorChecker patch {n} (1..24)")
    kd = colorchecker_reflectances()[int(n) - 1]
    return _truth_from_params(f"patch-{int(n)}", kd, TRUTH_PATCH_PARAMS[int(n)], truth,
                              {"patch": int(n), "colorchecker": PATCH_NAMES[int(n) - 1]})


def truth_wall(truth: str = "default", lightness_L: float = WALL_LIGHTNESS_L) -> Material:
    """The grey wall paint: flat kd = Y(L*)."""
    _check_truth(truth)
    kd = np.full(MATERIAL_WAVELENGTHS_NM.shape, reflectance_from_lightness(lightness_L))
    return _truth_from_params("wall", kd, TRUTH_WALL_PARAMS, truth, {"lightness_L": lightness_L})


def holder_material() -> Material:
    return Material.diffuse("holder", HOLDER_REFLECTANCE)


def truth_material(name: str | int, truth: str = "default",
                   wall_lightness_L: float = WALL_LIGHTNESS_L) -> Material:
    """By name: "patch-1".."patch-24" (or an int / "1".."24"), "wall", "holder"."""
    if isinstance(name, (int, np.integer)):
        return truth_patch(int(name), truth)
    s = str(name).strip().lower()
    s = s.removeprefix("patch-")
    if s.isdigit():
        return truth_patch(int(s), truth)
    if s == "wall":
        return truth_wall(truth, wall_lightness_L)
    if s == "holder":
        return holder_material()
    raise ValueError(f"unknown material {name!r}; expected patch-1..patch-24, wall or holder")


# --- the BRDF in closed form --------------------------------------------------------------------
def _fresnel_ct(cos_beta: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Cook-Torrance unpolarised dielectric Fresnel, broadcasting over a spectral η."""
    c = np.clip(cos_beta, 0.0, 1.0)
    g = np.sqrt(eta * eta - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def truth_brdf(material: Material, wi: np.ndarray, wo: np.ndarray,
               wavelength_nm: Any) -> np.ndarray:
    """BRDF (sr⁻¹), shape (…, n_λ), for unit directions (…, 3) with z the surface normal.

    For a model-family material this *is* `brdf_model.ct_ggx_brdf` (called directly)."""
    from normbox_lab.predict import brdf_model as bm

    wl = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))
    kd, ks, kb = material.spectra_at(wl)
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    if material.is_model_family:
        return bm.ct_ggx_brdf(wi, wo, kd, ks, material.alpha, material.eta, material.c)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    cos_i, cos_o, cos_h = wi[..., 2], wo[..., 2], h[..., 2]
    cos_d = np.sum(wi * h, axis=-1)
    valid = (cos_i > 0.0) & (cos_o > 0.0)
    dg = (bm.ggx_d(cos_h, material.alpha) * bm.smith_g1(cos_i, material.alpha)
          * bm.smith_g1(cos_o, material.alpha))
    den = 4.0 * np.where(valid, cos_i * cos_o, 1.0)
    geo = np.where(valid, dg / den, 0.0)[..., None]
    fres = _fresnel_ct(cos_d[..., None], material.eta_at(wl))
    spec = ks * geo * fres
    cos_g = np.sum(wi * wo, axis=-1)[..., None]
    back = kb / np.pi * np.exp((cos_g - 1.0) / material.backscatter_sigma ** 2)
    back = np.where(valid[..., None], back, 0.0)
    return kd / np.pi + spec + back - material.c


def truth_brdf_inplane(material: Material, theta_i_deg: Any, theta_o_deg: Any,
                       wavelength_nm: Any, tilt_deg: float = 4.0) -> np.ndarray:
    """The gonioreflectometer's view: signed in-plane angles, arms tilted ±tilt_deg."""
    from normbox_lab.predict.brdf_model import inplane_directions

    wi, wo = inplane_directions(theta_i_deg, theta_o_deg, tilt_deg)
    return truth_brdf(material, wi, wo, wavelength_nm)
