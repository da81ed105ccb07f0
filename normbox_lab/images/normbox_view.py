"""The Normbox seen from its open side (the virtual equivalent of the paper's Fig. 1 view):
the camera placement, `NormboxCamera` (the fast renderer's loaded box scene seen by a
`CameraTracer`) and the radiometer's white reference on the same scene.

Public API: normbox_camera(geometry, width, height), NormboxCamera(geometry).render(...),
normbox_camera_renderer(geometry), render_normbox_camera(patch, wall, angle_deg, ...),
white_reference_XYZ(wall, ...)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from normbox_lab.images.camera import PinholeCamera, SpectralImage
from normbox_lab.images.tracer import CameraTracer
from normbox_lab.predict.fastrender import STAND_INS, FastNormbox
from normbox_lab.predict.mitsuba_setup import jit_variant
from normbox_lab.predict.precision import DEFAULT_TARGET_SE

#: default samples per pixel of the Normbox view: with the quasi-random samples per pixel and the
#: noise floor from two half renders (`figure1`), 96 keep the Fig. 1 noise floor below the old
#: 128-spp one (median block ΔE00 0.066 vs 0.059–0.07) at about 40 % of the old CPU time
NORMBOX_DEFAULT_SPP = 96


def normbox_camera(geometry: Any = None, width: int = 320, height: int = 240, *,
                   distance_m: float | None = None, margin: float = 1.06) -> PinholeCamera:
    """A camera outside the box on the open (−y) side, on the axis of the opening, looking +y:
    the whole opening fills the image height with `margin`, so the walls, the floor, the lit
    aperture (seen from below, its back half and the panel through it), the sample holder and
    the patch are in view.  `distance_m` from the opening plane (default 10/6 of the box size,
    1.0 m for the 600 mm box)."""
    from normbox_lab.predict.scene import as_geometry

    g = as_geometry(geometry)
    size_m = g.box_inner_mm / 1000.0
    dist = float(distance_m) if distance_m is not None else size_m / 0.6
    tan_y = margin * size_m / 2.0 / dist
    fov_deg = math.degrees(2.0 * math.atan(tan_y * int(width) / int(height)))
    y0 = -size_m / 2.0 - dist
    return PinholeCamera(origin_m=(0.0, y0, size_m / 2.0), target_m=(0.0, 0.0, size_m / 2.0),
                         up=(0.0, 0.0, 1.0), fov_deg=fov_deg, width_px=int(width),
                         height_px=int(height))


class NormboxCamera:
    """The virtual Normbox (`fastrender.FastNormbox`'s one loaded mono scene, patch and holder
    plate moved in place per angle) seen by a `CameraTracer`; the same object also gives
    radiometer readings (`box.render_view`) on the same scene."""

    def __init__(self, geometry: Any = None, *, variant: str | None = None,
                 max_depth: int = 12, rr_depth: int = 6, chunk_paths: int = 1 << 16) -> None:
        self.box = FastNormbox(geometry, variant=variant, max_depth=max_depth,
                               rr_depth=rr_depth)
        self.geometry = self.box.geometry
        self.chunk_paths = int(chunk_paths)
        self._tracer: CameraTracer | None = None
        self._tracer_angle_deg: float | None = None

    def tracer(self, angle_deg: float) -> CameraTracer:
        """The camera tracer with the patch at `angle_deg` (builds the scene once)."""
        bt = self.box.tracer(angle_deg)            # loads the scene / moves the patch in place
        # the stand-in BSDFs are FastNormbox internals: the camera shares its loaded scene
        if self._tracer is None:
            slots = [(self.box._stand_in[r], STAND_INS[r]) for r in STAND_INS]
            self._tracer = CameraTracer(bt.scene, slots, bt.emitter, normbox_camera(self.geometry),
                                        variant=self.box.variant, emitter_slot="panel",
                                        grid=self.box.grid, max_depth=self.box.max_depth,
                                        rr_depth=self.box.rr_depth,
                                        chunk_paths=self.chunk_paths)
        elif self._tracer_angle_deg != float(angle_deg):
            self._tracer.refresh_geometry()
        self._tracer_angle_deg = float(angle_deg)
        return self._tracer

    def render(self, *, patch: Any, wall: Any, angle_deg: float, holder: Any = None,
               lamp: Any = None, width: int = 320, height: int = 240,
               spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0,
               camera: PinholeCamera | None = None, layers: bool = True) -> SpectralImage:
        """The box interior with `patch` at `angle_deg` (default camera: `normbox_camera`);
        `layers=False`: radiance only (`CameraTracer.render`)."""
        from normbox_lab.predict.materials import holder_material
        from normbox_lab.predict.render import LAMP_GRID_NM, Lamp

        holder = holder if holder is not None else holder_material()
        lamp = lamp if lamp is not None else Lamp()
        cam = camera if camera is not None else normbox_camera(self.geometry, width, height)
        tr = self.tracer(angle_deg)
        image = tr.render({"patch": patch, "wall": wall, "holder": holder}, LAMP_GRID_NM,
                          lamp.radiance(LAMP_GRID_NM), spp=spp, seed=seed, camera=cam,
                          layers=layers)
        image.info.update({"scene": "normbox", "angle_deg": float(angle_deg),
                           "patch": patch.name, "wall": wall.name, "holder": holder.name})
        return image


_NORMBOX_CAMERAS: dict[tuple[str, str], NormboxCamera] = {}


def normbox_camera_renderer(geometry: Any = None, variant: str | None = None) -> NormboxCamera:
    """This process's `NormboxCamera` for a geometry (one loaded scene, reused)."""
    from normbox_lab.predict.scene import as_geometry

    key = (repr(as_geometry(geometry)), jit_variant("mono", variant))
    nc = _NORMBOX_CAMERAS.get(key)
    if nc is None:
        nc = _NORMBOX_CAMERAS[key] = NormboxCamera(geometry, variant=variant)
    return nc


def render_normbox_camera(patch: Any, wall: Any, angle_deg: float, *, holder: Any = None,
                          lamp: Any = None, width: int = 320, height: int = 240,
                          spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0,
                          geometry: Any = None) -> SpectralImage:
    """The box interior seen from the open side (`normbox_camera`): the virtual equivalent of
    the Normbox paper's Fig. 1.  `patch`, `wall`, `holder` are `materials.Material`s (truth or
    fitted), `lamp` a `render.Lamp`."""
    return normbox_camera_renderer(geometry).render(
        patch=patch, wall=wall, angle_deg=angle_deg, holder=holder, lamp=lamp, width=width,
        height=height, spp=spp, seed=seed)


def white_reference_XYZ(wall: Any, *, white_patch: Any = None, holder: Any = None,
                        lamp: Any = None, geometry: Any = None, angle_deg: float = 30.0,
                        target_rel_se: float = DEFAULT_TARGET_SE, seed: int = 0,
                        cache_dir: Any = None) -> np.ndarray:
    """Absolute XYZ of the white reference of `normbox_lab.analyze.compare`: the white ColorChecker
    patch (default: `materials.truth_patch(19)`) at 30° seen by the radiometer in the world
    with `wall` (same scene as the camera: the radiometer of `FastNormbox`; kept in
    `cache_dir` when given, as `FastNormbox.render_view`)."""
    from normbox_lab.images.color import spectral_to_XYZ
    from normbox_lab.predict.materials import truth_patch

    white = white_patch if white_patch is not None else truth_patch(19)
    box = normbox_camera_renderer(geometry).box
    r = box.render_view(patch=white, wall=wall, angle_deg=angle_deg, holder=holder, lamp=lamp,
                        target_rel_se=target_rel_se, seed=seed, cache_dir=cache_dir)
    return spectral_to_XYZ(r.wavelength_nm, r.radiance)
