"""The Normbox paper's Fig. 1, virtually: the box rendered with the truth materials and with the
fitted ones (common random numbers), and the per-pixel ΔE00 between them.

Public API: figure1(truth, fitted, angle_deg, ...) -> Figure1
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from normbox_lab.images.camera import SpectralImage
from normbox_lab.images.normbox_view import (
    NORMBOX_DEFAULT_SPP,
    normbox_camera_renderer,
    white_reference_XYZ,
)


@dataclass
class Figure1:
    """Truth and fitted images of the same view (same seed: common random numbers), their
    XYZ, display sRGB (scaled so the white reference → 1, no white balance) and ΔE00 map."""

    angle_deg: float
    truth: SpectralImage
    fitted: SpectralImage
    truth_XYZ: np.ndarray
    fitted_XYZ: np.ndarray
    truth_srgb: np.ndarray
    fitted_srgb: np.ndarray
    delta_e00: np.ndarray          # (H, W)
    white_XYZ: np.ndarray          # absolute XYZ (cd/m²) of the white reference
    white_source: str
    scene_mask: np.ndarray         # (H, W) pixels on a box surface (not the light, not a miss)

    def summary(self) -> dict[str, float]:
        """ΔE00 statistics over the box surfaces (mean, median, 95th percentile, max)."""
        de = self.delta_e00[self.scene_mask]
        if de.size == 0:
            return {"mean": float("nan"), "median": float("nan"), "p95": float("nan"),
                    "max": float("nan")}
        return {"mean": float(np.mean(de)), "median": float(np.median(de)),
                "p95": float(np.percentile(de, 95.0)), "max": float(np.max(de))}

    def delta_e_rgb(self, max_delta_e: float = 5.0) -> np.ndarray:
        """The ΔE00 map as an RGB image in [0, 1] (matplotlib 'magma', 0 … max_delta_e)."""
        from matplotlib import colormaps

        x = np.clip(np.nan_to_num(self.delta_e00) / float(max_delta_e), 0.0, 1.0)
        return np.asarray(colormaps["magma"](x))[..., :3]

    def write_pngs(self, directory: Any, stem: str = "figure1") -> dict[str, Any]:
        """truth / fitted / ΔE00 PNGs in `directory`; returns their paths."""
        from pathlib import Path

        from normbox_lab.images.color import write_png

        d = Path(directory)
        return {"truth": write_png(d / f"{stem}-truth.png", self.truth_srgb),
                "fitted": write_png(d / f"{stem}-fitted.png", self.fitted_srgb),
                "delta_e00": write_png(d / f"{stem}-delta-e00.png", self.delta_e_rgb())}


def _white_patch_like(patch: Any) -> Any:
    """The truth world's white patch (19) of the same truth kind as `patch` ("default" unless
    its metadata says "model")."""
    from normbox_lab.predict.materials import TRUTH_KINDS, truth_patch

    kind = getattr(patch, "metadata", {}).get("truth", "default")
    return truth_patch(19, kind if kind in TRUTH_KINDS else "default")


def figure1(truth: Mapping[str, Any], fitted: Mapping[str, Any], angle_deg: float, *,
            lamp: Any = None, geometry: Any = None, width: int = 320, height: int = 240,
            spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0, white_XYZ: Any = None,
            white_patch: Any = None) -> Figure1:
    """The Normbox paper's Fig. 1, virtually: the box with the truth materials and with the
    fitted ones (`{"patch": Material, "wall": Material, "holder": Material (optional)}` each),
    rendered with the same seed, and the per-pixel ΔE00 between them.

    ΔE00 follows `normbox_lab.analyze.compare`: both images' XYZ divided by the Y of one white
    reference, Lab with D65, kL = kC = kH = 1.  The white (`white_XYZ`, absolute, cd/m²) is by
    default the radiometer reading of the white patch at 30° in the truth world
    (`white_reference_XYZ`; the white patch is `white_patch`, else `truth["white"]`, else
    ColorChecker 19 of the truth patch's kind), i.e. the normalisation of the comparison
    tables, so image and tables speak the same ΔE.  The sRGB previews use the same white for scale (no white
    balance: the 3100 K lamp shows warm)."""
    from normbox_lab.images.color import XYZ_to_srgb, delta_e00_map

    nc = normbox_camera_renderer(geometry)
    kw = {"angle_deg": angle_deg, "lamp": lamp, "width": width, "height": height, "spp": spp,
          "seed": seed}
    img_t = nc.render(patch=truth["patch"], wall=truth["wall"], holder=truth.get("holder"), **kw)
    img_f = nc.render(patch=fitted["patch"], wall=fitted["wall"], holder=fitted.get("holder"),
                      **kw)
    if white_XYZ is None:
        if white_patch is None:
            white_patch = truth.get("white") or _white_patch_like(truth["patch"])
        white = white_reference_XYZ(truth["wall"], white_patch=white_patch,
                                    holder=truth.get("holder"), lamp=lamp, geometry=geometry,
                                    seed=seed)
        source = "radiometer: white patch at 30° in the truth world"
    else:
        white = np.asarray(white_XYZ, dtype=np.float64)
        source = "given"
    xyz_t, xyz_f = img_t.XYZ(), img_f.XYZ()
    white_Y = float(white[1])
    scene_mask = np.isfinite(img_t.depth_m) & (img_t.slot_id > 0) & \
        (img_t.slot_id != img_t.slot_names.index("panel"))
    return Figure1(float(angle_deg), img_t, img_f, xyz_t, xyz_f,
                   XYZ_to_srgb(xyz_t, white_Y), XYZ_to_srgb(xyz_f, white_Y),
                   delta_e00_map(xyz_t, xyz_f, white), white, source, scene_mask)
