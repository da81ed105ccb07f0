"""A small Cornell-box-like test room for the camera tracer (white-balance checks and the
`normbox-lab image white-balance` command): `cornell_scene`, `cornell_materials`,
`render_cornell`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from normbox_lab.images.camera import PinholeCamera, SpectralImage
from normbox_lab.images.tracer import CameraTracer
from normbox_lab.predict.bandpath import RectEmitter
from normbox_lab.predict.mitsuba_setup import in_variant, jit_variant

#: material slots of `cornell_scene` (the light's slot is "light")
CORNELL_SLOTS = ("floor", "ceiling", "back", "left", "right", "box")


@dataclass
class CornellScene:
    """`cornell_scene`'s product: the tracer (scene, slots, light, camera) and its layout."""

    tracer: CameraTracer
    camera: PinholeCamera
    emitter: RectEmitter
    bsdf_slots: list[tuple[Any, str]]
    box_centre_m: tuple[float, float, float]
    box_half_m: float


def cornell_scene(width: int = 64, height: int = 48, *, variant: str | None = None,
                  max_depth: int = 12) -> CornellScene:
    """A 1 m Cornell-like box, open at y = −0.5: floor z = 0, ceiling z = 1, back y = +0.5,
    left x = −0.5, right x = +0.5; a 0.3 × 0.3 m light facing down 5 mm below the ceiling's
    centre (slot "light"); one cube of 0.36 m turned 20° about z standing on the floor (slot
    "box"); the camera outside on −y, looking +y.  Material slots: `CORNELL_SLOTS`."""

    variant = jit_variant("mono", variant)
    light_z = 0.995
    half_light = 0.15
    centre = (0.12, 0.08, 0.18)
    half = 0.18
    with in_variant(variant) as mi:
        T = mi.ScalarTransform4f
        bsdfs = {name: mi.load_dict({"type": "diffuse", "reflectance": 0.05 + 0.1 * i})
                 for i, name in enumerate(CORNELL_SLOTS + ("light",))}

        def rect(t: Any, name: str) -> dict[str, Any]:
            return {"type": "rectangle", "to_world": t @ T().scale([0.5, 0.5, 1.0]),
                    "bsdf": bsdfs[name]}

        d = {"type": "scene",
             "floor": rect(T(), "floor"),
             "ceiling": rect(T().translate([0, 0, 1]).rotate([1, 0, 0], 180), "ceiling"),
             "back": rect(T().translate([0, 0.5, 0.5]).rotate([1, 0, 0], 90), "back"),
             "left": rect(T().translate([-0.5, 0, 0.5]).rotate([0, 1, 0], 90), "left"),
             "right": rect(T().translate([0.5, 0, 0.5]).rotate([0, 1, 0], -90), "right"),
             "box": {"type": "cube", "bsdf": bsdfs["box"],
                     "to_world": T().translate(list(centre)).rotate([0, 0, 1], 20)
                     .scale([half, half, half])},
             "light": {"type": "rectangle", "bsdf": bsdfs["light"],
                       "to_world": T().translate([0, 0, light_z]).rotate([1, 0, 0], 180)
                       .scale([half_light, half_light, 1.0])}}
        scene = mi.load_dict(d)
    emitter = RectEmitter((0.0, 0.0, light_z), half_light, half_light)
    # the opening (1 m) fills the image height with a 5 % margin, 1.4 m in front of it
    tan_y = 1.05 * 0.5 / 1.4
    camera = PinholeCamera(origin_m=(0.0, -1.9, 0.5), target_m=(0.0, 0.0, 0.5),
                           fov_deg=math.degrees(2.0 * math.atan(tan_y * width / height)),
                           width_px=int(width), height_px=int(height))
    slots = [(bsdfs[n], n) for n in CORNELL_SLOTS + ("light",)]
    tracer = CameraTracer(scene, slots, emitter, camera, variant=variant, emitter_slot="light",
                          max_depth=max_depth)
    return CornellScene(tracer, camera, emitter, slots, centre, half)


def cornell_materials() -> dict[str, Any]:
    """Default materials per slot: red left wall, green right wall, grey floor / ceiling /
    back (reflectance 0.5), white box (0.85); all Lambertian, smooth spectra."""
    from normbox_lab.predict.materials import MATERIAL_WAVELENGTHS_NM, Material

    wl = MATERIAL_WAVELENGTHS_NM
    red = 0.05 + 0.65 / (1.0 + np.exp(-(wl - 600.0) / 12.0))
    green = 0.06 + 0.45 * np.exp(-0.5 * ((wl - 530.0) / 35.0) ** 2)
    grey = np.full(wl.shape, 0.5)
    return {"left": Material.diffuse("red", red, wl), "right": Material.diffuse("green", green, wl),
            "floor": Material.diffuse("grey", grey, wl),
            "ceiling": Material.diffuse("grey", grey, wl),
            "back": Material.diffuse("grey", grey, wl),
            "box": Material.diffuse("white", np.full(wl.shape, 0.85), wl)}


_CORNELL: dict[tuple[int, int, str], CornellScene] = {}


def render_cornell(materials: Mapping[str, Any] | None, lamp_wavelength_nm: Any,
                   lamp_radiance: Any, width: int = 64, height: int = 48, spp: int = 64,
                   seed: int = 0) -> SpectralImage:
    """The Cornell-like scene (`cornell_scene`) under a light of spectral radiance
    `lamp_radiance` (W·sr⁻¹·m⁻²·nm⁻¹ on `lamp_wavelength_nm`); `materials` (slot → Material)
    override `cornell_materials()` per slot.  The white cube's pixels: `image.mask("box")`."""
    key = (int(width), int(height), jit_variant("mono"))
    cs = _CORNELL.get(key)
    if cs is None:
        cs = _CORNELL[key] = cornell_scene(int(width), int(height))
    mats = {**cornell_materials(), **dict(materials or {})}
    image = cs.tracer.render(mats, lamp_wavelength_nm, lamp_radiance, spp=spp, seed=seed)
    image.info["scene"] = "cornell"
    return image
