"""The Normbox paper's Fig. 1, virtually: the box rendered with the truth materials and with the
fitted ones (common random numbers), the ΔE00 between them, and the Monte-Carlo noise floor.

Per-pixel ΔE00 at a few hundred samples per pixel is mostly Monte-Carlo noise.  The converged
map is unbiased per region: the image is cut into square blocks, and within each block the
pixels of one material slot (patch, wall, holder…) are averaged before ΔE00 is taken, so each
value is the ΔE00 of that region's mean colour (the mean of unbiased pixel estimates is an
unbiased estimate of the region's mean radiance; nothing is smoothed across a material edge).
The block size grows (2, 4, 8, 16 px) until the measured noise floor is below the target
(0.3 ΔE00 at the 95th percentile over the box surfaces) or the largest block is reached.

The noise floor is measured, not modelled: what noise alone produces between two images of
identical materials, the same block ΔE00 between the truth and a second, independent truth.
That second truth costs no render of its own: the truth is rendered as two halves of spp/2
paths per pixel with independent seeds, A and B; the truth image is their mean T = (A + B)/2,
and the second truth is N = T + (A − B)/√2.  A − B is independent noise (uncorrelated with
A + B, the halves being i.i.d.) with variance 2·σ²/(spp/2), so N − T has exactly the
variance 2·σ²/spp of the difference of two independent spp renders.  The fitted image is
rendered the same way with the same two seeds (common random numbers), radiance only, so the
truth-vs-fitted map's noise is at most the floor's.  (Odd spp: a third render, independent
seed, as before.)

Public API: figure1(truth, fitted, angle_deg, ...) -> Figure1; region_block_means(...)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
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
    block_px: int = 1              # block size of the converged maps
    delta_e00_blocks: np.ndarray | None = None    # (H, W) ΔE00 of block × slot means, NaN off
    noise_floor_blocks: np.ndarray | None = None  # (H, W) same, truth vs an independent truth
    target_noise_delta_e: float = 0.3

    def noise_summary(self) -> dict[str, float]:
        """The converged maps over the box surfaces: block size, noise floor (median, 95th
        percentile, max), block ΔE00 (mean, p95, max) and the share of surface pixels whose
        block ΔE00 exceeds three times the noise floor's 95th percentile."""
        keys = ("block_px", "noise_median", "noise_p95", "noise_max", "mean", "p95", "max",
                "share_above_noise")
        if self.delta_e00_blocks is None or self.noise_floor_blocks is None:
            return dict.fromkeys(keys, float("nan"))
        m = self.scene_mask & np.isfinite(self.delta_e00_blocks)
        de, nf = self.delta_e00_blocks[m], self.noise_floor_blocks[m]
        if de.size == 0:
            return dict.fromkeys(keys, float("nan"))
        p95 = float(np.percentile(nf, 95.0))
        return {"block_px": float(self.block_px), "noise_median": float(np.median(nf)),
                "noise_p95": p95, "noise_max": float(np.max(nf)), "mean": float(np.mean(de)),
                "p95": float(np.percentile(de, 95.0)), "max": float(np.max(de)),
                "share_above_noise": float(np.mean(de > 3.0 * p95))}

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


def region_block_means(XYZ: np.ndarray, slot_id: np.ndarray, mask: np.ndarray,
                       block_px: int) -> np.ndarray:
    """(H, W, 3): each masked pixel replaced by the mean XYZ of the masked pixels of its
    `block_px` × `block_px` block that hit the same material slot; NaN outside `mask`."""
    h, w = slot_id.shape
    b = max(int(block_px), 1)
    rows, cols = np.nonzero(mask)
    key = ((rows // b) * ((w + b - 1) // b) + cols // b) * (int(slot_id.max()) + 2) \
        + slot_id[rows, cols] + 1
    _, inv = np.unique(key, return_inverse=True)
    count = np.bincount(inv).astype(np.float64)
    out = np.full((h, w, 3), np.nan)
    vals = np.asarray(XYZ, dtype=np.float64)[rows, cols]
    for k in range(3):
        out[rows, cols, k] = (np.bincount(inv, weights=vals[:, k]) / count)[inv]
    return out


def converged_maps(truth_XYZ: np.ndarray, fitted_XYZ: np.ndarray, noise_XYZ: np.ndarray,
                   slot_id: np.ndarray, mask: np.ndarray, white_XYZ: np.ndarray,
                   target_noise_delta_e: float = 0.3,
                   blocks_px: tuple[int, ...] = (2, 4, 8, 16)
                   ) -> tuple[int, np.ndarray, np.ndarray]:
    """(block_px, ΔE00 map, noise-floor map) at the smallest block size whose noise floor's
    95th percentile over `mask` is below `target_noise_delta_e` (else the largest)."""
    from normbox_lab.images.color import delta_e00_map

    result: tuple[int, np.ndarray, np.ndarray] | None = None
    for b in blocks_px:
        t = region_block_means(truth_XYZ, slot_id, mask, b)
        f = region_block_means(fitted_XYZ, slot_id, mask, b)
        n = region_block_means(noise_XYZ, slot_id, mask, b)
        ok = mask & np.isfinite(t[..., 1])
        de = np.full(mask.shape, np.nan)
        nf = np.full(mask.shape, np.nan)
        de[ok] = delta_e00_map(t[ok], f[ok], white_XYZ)
        nf[ok] = delta_e00_map(t[ok], n[ok], white_XYZ)
        result = (int(b), de, nf)
        if ok.any() and float(np.percentile(nf[ok], 95.0)) < float(target_noise_delta_e):
            break
    assert result is not None
    return result


#: the camera's modules, part of a kept view's key with the radiometer renderer's
CAMERA_MODULES = ("tracer", "camera", "normbox_view", "color")


def rendered_view(nc: Any, mats: Mapping[str, Any], *, layers: bool, seeds: tuple[int, ...],
                  kw: Mapping[str, Any], cache_dir: str | Path | None = None
                  ) -> tuple[SpectralImage, np.ndarray]:
    """The view of `mats` rendered once per seed (`NormboxCamera.render` with `kw`): the mean
    image of the renders and each render's XYZ, (seed, H, W, 3).  With `cache_dir`, kept there
    under a key of everything it depends on (materials, lamp, view, seeds, the scene, the
    Mitsuba and Dr.Jit versions and the renderers' source code) and read back bit for bit;
    one process traces it while another that wants it waits (`render.cached_render`)."""
    def compute() -> tuple[SpectralImage, np.ndarray]:
        parts = [nc.render(patch=mats["patch"], wall=mats["wall"], holder=mats.get("holder"),
                           seed=s, layers=layers, **kw) for s in seeds]
        return SpectralImage.mean_of(parts), np.stack([p.XYZ() for p in parts])

    if cache_dir is None:
        return compute()
    from normbox_lab.predict.render import cached_render

    def load(path: Path) -> tuple[SpectralImage, np.ndarray] | None:
        kept = SpectralImage.load(path)
        return None if kept is None or "xyz_parts" not in kept[1] else (kept[0],
                                                                        kept[1]["xyz_parts"])

    def save(path: Path, value: tuple[SpectralImage, np.ndarray]) -> None:
        try:
            value[0].save(path, xyz_parts=value[1])
        except OSError:               # a full disk: render again next time
            pass

    key = view_key(nc, mats, layers=layers, seeds=seeds, kw=kw)
    return cached_render(Path(cache_dir) / f"camera-{key}.npz", compute, load, save)


def view_key(nc: Any, mats: Mapping[str, Any], *, layers: bool, seeds: tuple[int, ...],
             kw: Mapping[str, Any]) -> str:
    """The key of a `rendered_view`: a hash of its inputs and of the code that renders it."""
    import hashlib
    import json

    from normbox_lab.predict.fastrender import renderer_source_digest
    from normbox_lab.predict.materials import holder_material

    box = nc.box
    here = Path(__file__).resolve().parent
    source = hashlib.sha256(renderer_source_digest().encode())
    for name in CAMERA_MODULES:
        source.update((here / f"{name}.py").read_bytes())
    lamp = kw.get("lamp")
    payload = {"materials": {k: mats[k].digest() for k in ("patch", "wall")},
               "holder": (mats.get("holder") or holder_material()).digest(),
               "layers": bool(layers), "seeds": [int(s) for s in seeds],
               "view": {k: v for k, v in kw.items() if k != "lamp"},
               "lamp": lamp.key() if lamp is not None else None,
               "geometry": repr(box.geometry), "variant": box.variant,
               "grid": [box.grid.start_nm, box.grid.stop_nm, box.grid.step_nm],
               "max_depth": box.max_depth, "rr_depth": box.rr_depth,
               "chunk_paths": nc.chunk_paths, "source": source.hexdigest()}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def _white_patch_like(patch: Any) -> Any:
    """The truth world's white patch (19) of the same truth kind as `patch` ("default" unless
    its metadata says "model")."""
    from normbox_lab.predict.materials import TRUTH_KINDS, truth_patch

    kind = getattr(patch, "metadata", {}).get("truth", "default")
    return truth_patch(19, kind if kind in TRUTH_KINDS else "default")


def figure1(truth: Mapping[str, Any], fitted: Mapping[str, Any], angle_deg: float, *,
            lamp: Any = None, geometry: Any = None, width: int = 320, height: int = 240,
            spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0, white_XYZ: Any = None,
            white_patch: Any = None, noise_floor: bool = True,
            target_noise_delta_e: float = 0.3, cache_dir: str | Path | None = None) -> Figure1:
    """The Normbox paper's Fig. 1, virtually: the box with the truth materials and with the
    fitted ones (`{"patch": Material, "wall": Material, "holder": Material (optional)}` each),
    rendered with the same seed, and the per-pixel ΔE00 between them.

    ΔE00 follows `normbox_lab.analyze.compare`: both images' XYZ divided by the Y of one white
    reference, Lab with D65, kL = kC = kH = 1.  The white (`white_XYZ`, absolute, cd/m²) is by
    default the radiometer reading of the white patch at 30° in the truth world
    (`white_reference_XYZ`; the white patch is `white_patch`, else `truth["white"]`, else
    ColorChecker 19 of the truth patch's kind), i.e. the normalisation of the comparison
    tables, so image and tables speak the same ΔE.  The sRGB previews use the same white for scale (no white
    balance: the 3100 K lamp shows warm).

    With `noise_floor` the truth is rendered once more with an independent seed and the
    converged region maps are made (see the module docstring, `converged_maps`).

    `cache_dir`: keep the renders there (`rendered_view`) and read them back when everything
    they depend on is the same (the demo's second run); None renders every time."""
    from normbox_lab.images.color import XYZ_to_srgb, delta_e00_map

    nc = normbox_camera_renderer(geometry)
    halves = bool(noise_floor) and int(spp) >= 2 and int(spp) % 2 == 0
    kw = {"angle_deg": angle_deg, "lamp": lamp, "width": width, "height": height,
          "spp": int(spp) // 2 if halves else int(spp)}
    seeds = (int(seed), int(seed) + 7919) if halves else (int(seed),)

    img_t, xyz_parts = rendered_view(nc, truth, layers=True, seeds=seeds, kw=kw,
                                     cache_dir=cache_dir)
    img_f, _ = rendered_view(nc, fitted, layers=False, seeds=seeds, kw=kw, cache_dir=cache_dir)
    if white_XYZ is None:
        if white_patch is None:
            white_patch = truth.get("white") or _white_patch_like(truth["patch"])
        white = white_reference_XYZ(truth["wall"], white_patch=white_patch,
                                    holder=truth.get("holder"), lamp=lamp, geometry=geometry,
                                    seed=seed, cache_dir=cache_dir)
        source = "radiometer: white patch at 30° in the truth world"
    else:
        white = np.asarray(white_XYZ, dtype=np.float64)
        source = "given"
    xyz_t, xyz_f = img_t.XYZ(), img_f.XYZ()
    white_Y = float(white[1])
    scene_mask = np.isfinite(img_t.depth_m) & (img_t.slot_id > 0) & \
        (img_t.slot_id != img_t.slot_names.index("panel"))
    fig = Figure1(float(angle_deg), img_t, img_f, xyz_t, xyz_f,
                  XYZ_to_srgb(xyz_t, white_Y), XYZ_to_srgb(xyz_f, white_Y),
                  delta_e00_map(xyz_t, xyz_f, white), white, source, scene_mask,
                  target_noise_delta_e=float(target_noise_delta_e))
    if noise_floor:
        if halves:            # the second truth from the halves (module docstring)
            xyz_n = xyz_t + (xyz_parts[0] - xyz_parts[1]) / np.sqrt(2.0)
        else:
            xyz_n = nc.render(patch=truth["patch"], wall=truth["wall"],
                              holder=truth.get("holder"), seed=int(seed) + 7919, layers=False,
                              **kw).XYZ()
        fig.block_px, fig.delta_e00_blocks, fig.noise_floor_blocks = converged_maps(
            xyz_t, xyz_f, xyz_n, img_t.slot_id, scene_mask, white, target_noise_delta_e)
    return fig
