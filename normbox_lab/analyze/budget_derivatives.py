"""The error budget's derivatives: ∂P/∂s per patch × angle, and the relative geometry and
homogeneity derivatives per patch × angle, by central differences with the fast renderer
(each pair of renders shares its seed: common random numbers).

Geometry and homogeneity are derivatives per patch: they change the light's distribution
(direct against indirect, the panel's bright parts against its edges), which a glossy patch
near the mirror geometry (40–50°) weighs differently from a matte one — with the panel map 6 %
off, patch 18 at 45° moved −0.82 % where most patches moved −0.12 %, so the white patch's
derivative for every patch (as before) attributed only 0.54–0.70 of the effect there.  All
patches of one angle come from one set of paths (`FastNormbox.render_patches`): the ± renders
share it, so its noise cancels in the difference to first order."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from normbox_lab.core.error_sources import GEOMETRY_FIELDS

#: steps of the central differences: geometry (mm), homogeneity (fraction), angle (deg)
GEOMETRY_STEP_MM = 2.0
HOMOGENEITY_STEP = 0.03
ANGLE_STEP_DEG = 1.0


def render_derivatives(patch_materials: Sequence[Any], wall: Any, angle_deg: Sequence[float],
                       wavelength_nm: np.ndarray, *, geometry: Any, lamp: Any = None,
                       white: Any = None, n_paths: int = 1 << 14, seed: int = 11,
                       with_geometry: bool = True,
                       progress: Callable[[str, int, int], None] | None = None
                       ) -> dict[str, Any]:
    """∂P/∂s, and the relative geometry / homogeneity derivatives (``d_geometry_rel`` per
    field, ``d_homogeneity_rel``), each [patch, angle, λ], by central differences; each pair
    of renders shares its seed (common random numbers).  `white` is not used any more (the
    derivatives are per patch); kept for callers."""
    from dataclasses import replace

    from normbox_lab.predict.fastrender import FastNormbox, config_seed

    progress = progress or (lambda stage, done, total: None)
    angles = [float(a) for a in angle_deg]

    def interp(r: Any) -> np.ndarray:
        return np.interp(wavelength_nm, r.wavelength_nm, r.radiance)

    box = FastNormbox(geometry)
    n_p = len(patch_materials)
    d_angle = np.zeros((n_p, len(angles), wavelength_nm.size))
    total = 2 * n_p * len(angles) + (2 * (len(GEOMETRY_FIELDS) + 1) * len(angles)
                                     if with_geometry else 0)
    done = 0
    # one configuration at a time, not all patches per path: the offset estimate sums over
    # the patches, and derivative noise shared by all of them (one set of paths) adds up
    # coherently there; measured on the paper campaign it pulled every offset by about −1°
    for ai, a in enumerate(angles):
        for pi, m in enumerate(patch_materials):
            s = config_seed(seed, f"{m.name}@{a:g}")
            pair = [interp(box.render_view(patch=m, wall=wall, angle_deg=a + sgn * ANGLE_STEP_DEG,
                                           lamp=lamp, n_paths=n_paths, seed=s))
                    for sgn in (1, -1)]
            d_angle[pi, ai] = (pair[0] - pair[1]) / (2 * ANGLE_STEP_DEG)
            done += 2
            progress("derivatives", done, total)
    out: dict[str, Any] = {"d_angle": d_angle}
    if not with_geometry:
        return out
    g0 = box.geometry
    steps: dict[str, tuple[float, str]] = {f: (GEOMETRY_STEP_MM, f) for f in GEOMETRY_FIELDS}
    steps["homogeneity"] = (HOMOGENEITY_STEP, "panel_homogeneity_percent")
    rel: dict[str, np.ndarray] = {}
    for key, (step, attr) in steps.items():
        unit = 100.0 if key == "homogeneity" else 1.0
        boxes = [FastNormbox(replace(g0, **{attr: getattr(g0, attr) + sgn * step * unit}))
                 for sgn in (1, -1)]
        r = np.zeros((n_p, len(angles), wavelength_nm.size))
        for ai, a in enumerate(angles):
            s = config_seed(seed, f"{key}@{a:g}")
            up, down = (np.array([interp(x) for x in b.render_patches(
                patches=list(patch_materials), wall=wall, angle_deg=a, lamp=lamp,
                n_paths=n_paths, seed=s)]) for b in boxes)
            mid = 0.5 * (up + down)
            with np.errstate(divide="ignore", invalid="ignore"):
                r[:, ai] = np.where(mid > 0, (up - down) / (2 * step) / mid, 0.0)
            done += 2
            progress("derivatives", done, total)
        rel[key] = r
    out["d_homogeneity_rel"] = rel.pop("homogeneity")
    out["d_geometry_rel"] = rel
    return out
