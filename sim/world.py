"""The virtual Normbox: the physics behind every emulator (the `World` protocol of sim/core.py).

World state (`sim.world_state.WorldState`, shared with `analytic_world.AnalyticWorld`): the
patch on the holder, the sample angle (the attached rotator emulator's, else
`set_sample_angle`), the lamp (the attached sphere emulator's output and state, else
`lamp_level`), the light-map aim, and the gonioreflectometer's sample
(`mount_gonio_material("patch-1".."patch-24" | "wall")`, validated here).

Error sources (`core.error_sources.ErrorSources`, from `errors=` or the lab config's
`[render] errors`), all off by default: the sample-angle errors move the rendered angle;
geometry and homogeneity make the truth geometry (`self.geometry`) differ from the nominal one
(`self.nominal_geometry`, what the prediction uses); diffusivity and lamp scale the light on
the sample but not the light map's view of the panel; the CS-1000A's gain and wavelength shift
act on `radiance_in_view()`; the gonioreflectometer's calibration, non-linearity and noise on
`brdf_truth()`.

What the instruments see:
- `radiance_in_view()` → (wavelength_nm 380…780 step 1, W·sr⁻¹·m⁻²·nm⁻¹): a Mitsuba render
  of the box with the truth materials (`normbox_lab.predict.render.render_view`, cached on disk by
  patch × angle × lamp × quality), interpolated from the 5 nm render bands; the full result with
  its Monte-Carlo standard error is kept in `last_render`.  The radiometer emulator adds the
  instrument's own behaviour (noise, wavelength shift, timing) on top.
- `brdf_truth(θi, θo, tilt, λ)`: the truth BRDF of the mounted material in closed form.
- `luminance_cd_m2(patch, angle_deg)`: the luminance of a configuration (renders if needed).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from normbox_lab.core.error_sources import ErrorSources, error_sources_from_config, parse_error_spec
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.predict.materials import (
    Material,
    holder_material,
    truth_material,
    truth_patch,
    truth_wall,
)
from normbox_lab.predict.render import Lamp, RenderResult, luminance_cd_m2, render_view
from normbox_lab.predict.scene import as_geometry, panel_map_at
from normbox_lab.sim.world_state import WorldState

#: seed base of the world's (truth's) renders: a stream of its own, independent of the
#: prediction's (which renders with seed 0 through `render_view`, or `fast_world.PREDICTION_SEED`)
TRUTH_RENDER_SEED = 7919
#: render angles are rounded to this (rotator encoder noise must not defeat the cache)
ANGLE_RESOLUTION_DEG = 0.001


class VirtualNormbox(WorldState):
    """The `World` protocol, rendered with Mitsuba.  Cheap to construct: nothing renders (and
    Mitsuba is not imported) until the first `radiance_in_view()`."""

    def __init__(self, config: Any = None, *, geometry: Any = None, truth: str | None = None,
                 quality: str | None = None, lamp: Lamp | None = None,
                 cache_dir: str | None = None, variant: str | None = None,
                 errors: ErrorSources | str | None = None) -> None:
        super().__init__()
        render_cfg = dict(getattr(config, "render", None) or {})
        if isinstance(errors, ErrorSources):
            self.errors = errors
        elif config is not None:
            self.errors = error_sources_from_config(config, errors)
        else:
            self.errors = parse_error_spec(errors)
        self.nominal_geometry = as_geometry(geometry if geometry is not None else config)
        self.geometry = self.errors.perturbed_geometry(self.nominal_geometry)
        self.box_light_gain = self.errors.box_light_gain()
        #: the seed (base) of the truth's renders: independent of the prediction's
        self.render_seed = TRUTH_RENDER_SEED + int(self.errors.seed)
        self.readings_per_config: dict[tuple[int | None, float], int] = {}
        self.last_angle_error_deg = 0.0
        self.truth = truth or render_cfg.get("truth", "default")
        self.quality = quality or render_cfg.get("quality", "default")
        self.cache_dir = cache_dir or render_cfg.get("cache_dir")
        self.variant = variant or render_cfg.get("variant")
        self.lamp = lamp if lamp is not None else Lamp(
            cct_K=float(render_cfg.get("lamp_cct_K", 3100.0)),
            luminance_cd_m2=float(render_cfg.get("panel_luminance_cd_m2", 3000.0)))
        self.wavelength_nm = RADIOMETER_WAVELENGTHS_NM.copy()
        self.wall = truth_wall(self.truth, self.geometry.wall_lightness_L)
        self.holder = holder_material()
        self.last_render: RenderResult | None = None
        #: the truth's Monte-Carlo noise as its renders achieved it: per configuration (patch,
        #: commanded angle to 0.1°) the relative standard error of the last reading's render on
        #: the radiometer grid (`truth_relative_se`; the demo stores it with the sweep, and
        #: the error budget's `render` term takes it instead of the stated target)
        self.achieved_rel_se: dict[tuple[int | None, float], np.ndarray] = {}
        self._gonio_truth_memo: tuple[tuple[Any, ...], Material] | None = None

    # --- what the operator changes (the rest: `WorldState`) -------------------------------------
    def mount_gonio_material(self, name: str | int) -> None:
        truth_material(name, self.truth)          # validates the name
        self.gonio_material = name

    # --- state as the instruments see it -------------------------------------------------------
    def patch_material(self, n: int | None) -> Material:
        return self.holder if n is None else truth_patch(int(n), self.truth)

    def materials(self) -> dict[str, Material]:
        """The world's truth materials by name: "patch-1".."patch-24", "wall", "holder"."""
        out = {f"patch-{n}": truth_patch(n, self.truth) for n in range(1, 25)}
        out["wall"] = self.wall
        out["holder"] = self.holder
        return out

    # --- what the instruments see --------------------------------------------------------------
    def render(self, patch: int | None, angle_deg: float, *, direct_only: bool = False,
               quality: str | None = None) -> RenderResult:
        """The render of one configuration at full lamp output (relative output 1)."""
        angle = round(float(angle_deg) / ANGLE_RESOLUTION_DEG) * ANGLE_RESOLUTION_DEG
        return render_view(self.geometry, patch=self.patch_material(patch), wall=self.wall,
                           holder=self.holder, angle_deg=angle, lamp=self.lamp,
                           quality=quality or self.quality, direct_only=direct_only,
                           seed=self.render_seed, cache_dir=self.cache_dir,
                           variant=self.variant)

    def panel_radiance(self, x_mm: float, y_mm: float) -> np.ndarray:
        """Spectral radiance of the opal panel at a point (mm from its centre), closed form."""
        return self.lamp.radiance(self.wavelength_nm) * panel_map_at(x_mm, y_mm, self.geometry)

    def radiance_in_view(self) -> tuple[np.ndarray, np.ndarray]:
        output = self.relative_output()
        if self.aim is not None:
            return self.wavelength_nm.copy(), self.panel_radiance(*self.aim) * output
        if output == 0.0:
            return self.wavelength_nm.copy(), np.zeros_like(self.wavelength_nm)
        commanded = self.angle_deg()
        key = (self.patch, round(commanded, 1))
        reading = self.readings_per_config.get(key, 0)
        self.readings_per_config[key] = reading + 1
        # the hand-placement error belongs to the placement, not to the call
        self.last_angle_error_deg = self.errors.angle_error_deg(commanded, self.patch,
                                                                len(self.placed))
        result = self.render(self.patch, commanded + self.last_angle_error_deg)
        self.last_render = result.scaled(output * self.box_light_gain)
        _, radiance = self.last_render.to_1nm(self.wavelength_nm)
        self.achieved_rel_se[key] = np.interp(self.wavelength_nm, result.wavelength_nm,
                                              result.relative_std_error)
        radiance = self.errors.radiometer(self.wavelength_nm, radiance, (*key, reading))
        return self.wavelength_nm.copy(), radiance

    def truth_relative_se(self, patches: list[int], angles_deg: np.ndarray) -> np.ndarray:
        """[patch, angle, λ]: the relative standard error of the truth's render behind each
        configuration's last reading (`achieved_rel_se`), NaN where none was rendered."""
        out = np.full((len(patches), len(angles_deg), self.wavelength_nm.size), np.nan)
        for i, p in enumerate(patches):
            for j, a in enumerate(angles_deg):
                se = self.achieved_rel_se.get((int(p), round(float(a), 1)))
                if se is not None:
                    out[i, j] = se
        return out

    def _gonio_truth(self, name: str | int) -> Material:
        """The mounted sample's truth material, built once per (name, truth, wall L*): the
        gonio asks for it at every spectrum (3 per BRDF reading), and building it reads the
        ColorChecker table from disk."""
        key = (name, self.truth, self.geometry.wall_lightness_L)
        if self._gonio_truth_memo is None or self._gonio_truth_memo[0] != key:
            self._gonio_truth_memo = (key, truth_material(name, self.truth,
                                                          self.geometry.wall_lightness_L))
        return self._gonio_truth_memo[1]

    def luminance_cd_m2(self, patch: int | None, angle_deg: float) -> float:
        r = self.render(patch, angle_deg)
        return luminance_cd_m2(r.wavelength_nm, r.radiance) * self.relative_output()

    def brdf_truth(self, theta_i_deg: float, theta_o_deg: float, tilt_deg: float,
                   wavelength_nm: np.ndarray) -> np.ndarray:
        from normbox_lab.predict.materials import truth_brdf_inplane

        material = (self.holder if self.gonio_material is None
                    else self._gonio_truth(self.gonio_material))
        f = truth_brdf_inplane(material, theta_i_deg, theta_o_deg, wavelength_nm, tilt_deg)
        if self.gonio_material is None:
            return f
        key = (str(self.gonio_material), round(float(theta_i_deg), 1),
               round(float(theta_o_deg), 1))
        return self.errors.gonio(f, key)
