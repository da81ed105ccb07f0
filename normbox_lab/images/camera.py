"""The camera model: a pinhole camera and the spectral image it forms.

Image formation (`PinholeCamera`): perspective, `fov_deg` on the horizontal (x) axis as Mitsuba's
`perspective` with fov_axis="x", square pixels, row 0 at the top.  A pixel is a box filter:
its rays are uniform (jittered) over the pixel's area on the image plane, so a pixel value is the
mean radiance over the pixel, in W·sr⁻¹·m⁻²·nm⁻¹ on the bands of `bandpath.BandGrid`
(380…780 nm every 5 nm, triangular hats).

`SpectralImage` holds the radiance, its light-path layers (`LAYERS`, they sum to the radiance),
the Wilkie & Weidlich (2009) auxiliary images CWNI and NWCI (`AUX_IMAGES`), the per-pixel
Monte-Carlo standard error, and depth, normal and material slot from one ray through each pixel
centre.  `normbox_lab.images.tracer.CameraTracer` renders them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: the light-path layers; they sum to `SpectralImage.radiance`
LAYERS = ("emission", "diffuse", "specular", "indirect")
#: the Wilkie & Weidlich auxiliary images
AUX_IMAGES = ("cwni", "nwci")


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera looking from `origin_m` at `target_m`; `fov_deg` is the horizontal field
    of view (Mitsuba's fov_axis="x"), pixels are square, row 0 is the top of the image."""

    origin_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 40.0
    width_px: int = 320
    height_px: int = 240

    def __post_init__(self) -> None:
        if int(self.width_px) < 1 or int(self.height_px) < 1:
            raise ValueError(f"image size must be ≥ 1×1, got {self.width_px}×{self.height_px}")
        if not 0.0 < float(self.fov_deg) < 180.0:
            raise ValueError(f"fov_deg must be in (0, 180), got {self.fov_deg}")

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(forward, right, up) unit vectors of the image plane, world space."""
        o = np.asarray(self.origin_m, dtype=np.float64)
        f = np.asarray(self.target_m, dtype=np.float64) - o
        f /= np.linalg.norm(f)
        right = np.cross(f, np.asarray(self.up, dtype=np.float64))
        norm = np.linalg.norm(right)
        if norm < 1e-12:
            raise ValueError("camera `up` is parallel to the viewing direction")
        right /= norm
        return f, right, np.cross(right, f)

    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """tan of the half field of view on x and on y."""
        tx = math.tan(math.radians(float(self.fov_deg)) / 2.0)
        return tx, tx * int(self.height_px) / int(self.width_px)

    def ray_direction(self, col: Any, row: Any) -> np.ndarray:
        """Unit world direction through image-plane position (col, row) in pixels (the pixel
        (i, j) covers cols j…j+1, rows i…i+1); numpy, for checks and overlays."""
        f, right, up = self.frame()
        tx, ty = self.tan_half_fov
        x = (2.0 * np.asarray(col, dtype=np.float64) / int(self.width_px) - 1.0) * tx
        y = (1.0 - 2.0 * np.asarray(row, dtype=np.float64) / int(self.height_px)) * ty
        d = f * np.ones_like(x)[..., None] + right * x[..., None] + up * y[..., None]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, point_m: Any) -> np.ndarray:
        """Image-plane (col, row) in pixels of world points [..., 3] (in front of the camera)."""
        f, right, up = self.frame()
        tx, ty = self.tan_half_fov
        v = np.asarray(point_m, dtype=np.float64) - np.asarray(self.origin_m, dtype=np.float64)
        z = v @ f
        col = ((v @ right) / z / tx + 1.0) / 2.0 * int(self.width_px)
        row = (1.0 - (v @ up) / z / ty) / 2.0 * int(self.height_px)
        return np.stack([col, row], axis=-1)


@dataclass
class SpectralImage:
    """A spectral image: (H, W, B) float32 arrays on `wavelength_nm` (B,), in W·sr⁻¹·m⁻²·nm⁻¹.

    `radiance` = emission + diffuse + specular + indirect (see the module docstring for the
    layers and CWNI/NWCI).  `std_error`: per-pixel, per-band Monte-Carlo standard error of
    `radiance` (None for spp < 2); `luminance_se_cd_m2` likewise for the luminance.
    `depth_m` (H, W): +inf where the pixel-centre ray misses; `normal` (H, W, 3): face normal
    towards the camera, zeros where it misses; `slot_id` (H, W): index into `slot_names`, −1 miss.
    The layers and CWNI/NWCI are None for a radiance-only render (`CameraTracer.render(...,
    layers=False)`).
    """

    wavelength_nm: np.ndarray
    radiance: np.ndarray
    emission: np.ndarray | None
    diffuse: np.ndarray | None
    specular: np.ndarray | None
    indirect: np.ndarray | None
    cwni: np.ndarray | None
    nwci: np.ndarray | None
    std_error: np.ndarray | None
    luminance_se_cd_m2: np.ndarray | None
    depth_m: np.ndarray
    normal: np.ndarray
    slot_id: np.ndarray
    slot_names: list[str]
    camera: PinholeCamera
    spp: int
    time_s: float
    info: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def mean_of(cls, images: list[SpectralImage]) -> SpectralImage:
        """The image of all paths of `images`: renders of one view with the same spp and
        independent seeds, averaged (layers kept only when every image has them); standard
        errors combine as those of a mean of independent estimates."""
        if not images:
            raise ValueError("no images to average")
        first = images[0]
        if any(im.spp != first.spp or im.radiance.shape != first.radiance.shape
               for im in images):
            raise ValueError("images of different sizes or spp cannot be averaged")
        k = len(images)

        def mean(name: str) -> np.ndarray | None:
            arrays = [getattr(im, name) for im in images]
            if any(a is None for a in arrays):
                return None
            return (np.sum([np.asarray(a, np.float64) for a in arrays], axis=0) / k
                    ).astype(np.float32)

        def se(name: str) -> np.ndarray | None:
            arrays = [getattr(im, name) for im in images]
            if any(a is None for a in arrays):
                return None
            return (np.sqrt(np.sum([np.asarray(a, np.float64) ** 2 for a in arrays], axis=0))
                    / k).astype(np.float32)

        info = dict(first.info)
        info["n_paths"] = int(sum(int(im.info.get("n_paths", 0)) for im in images))
        info["seeds"] = [im.info.get("seed") for im in images]
        return cls(wavelength_nm=first.wavelength_nm.copy(), radiance=mean("radiance"),
                   emission=mean("emission"), diffuse=mean("diffuse"),
                   specular=mean("specular"), indirect=mean("indirect"), cwni=mean("cwni"),
                   nwci=mean("nwci"), std_error=se("std_error"),
                   luminance_se_cd_m2=se("luminance_se_cd_m2"), depth_m=first.depth_m,
                   normal=first.normal, slot_id=first.slot_id,
                   slot_names=list(first.slot_names), camera=first.camera,
                   spp=first.spp * k, time_s=float(sum(im.time_s for im in images)),
                   info=info)

    #: the array fields, in `save`'s file (those that are None are left out)
    ARRAYS = ("wavelength_nm", "radiance", *LAYERS, "cwni", "nwci", "std_error",
              "luminance_se_cd_m2", "depth_m", "normal", "slot_id")

    def save(self, path: Path, **extra: np.ndarray) -> None:
        """Write the image, and `extra` arrays, to `path` (.npz, uncompressed float32: a
        320×240 image with its layers is about 200 MB), whole or not at all."""
        import json
        from dataclasses import asdict

        from normbox_lab.core.npzfile import write_npz

        meta = {"slot_names": list(self.slot_names), "camera": asdict(self.camera),
                "spp": int(self.spp), "time_s": float(self.time_s), "info": self.info}
        arrays = {k: getattr(self, k) for k in self.ARRAYS if getattr(self, k) is not None}
        write_npz(path, meta=json.dumps(meta), **arrays,
                  **{f"extra_{k}": v for k, v in extra.items()})

    @classmethod
    def load(cls, path: Path) -> tuple[SpectralImage, dict[str, np.ndarray]] | None:
        """What `save` wrote: (image, extra arrays), or None when `path` is missing or
        unreadable."""
        import json

        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                fields = {k: (z[k] if k in z.files else None) for k in cls.ARRAYS}
                extra = {k[len("extra_"):]: z[k] for k in z.files if k.startswith("extra_")}
        except (OSError, KeyError, ValueError):
            return None
        cam = meta["camera"]
        camera = PinholeCamera(**{k: tuple(v) if isinstance(v, list) else v
                                  for k, v in cam.items()})
        return cls(**fields, slot_names=list(meta["slot_names"]), camera=camera,
                   spp=int(meta["spp"]), time_s=float(meta["time_s"]),
                   info=dict(meta["info"])), extra

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.radiance.shape[0]), int(self.radiance.shape[1]))

    @property
    def layers(self) -> dict[str, np.ndarray]:
        """The light-path layers (they sum to `radiance`)."""
        return {name: getattr(self, name) for name in LAYERS}

    def mask(self, slot: str) -> np.ndarray:
        """(H, W) bool: pixels whose centre ray first hits the material slot `slot`."""
        if slot not in self.slot_names:
            raise KeyError(f"no slot {slot!r}; slots: {self.slot_names}")
        return self.slot_id == self.slot_names.index(slot)

    def XYZ(self, image: str = "radiance") -> np.ndarray:
        """Absolute CIE 1931 XYZ (H, W, 3) of `radiance` or any layer / auxiliary image
        (Y in cd/m²), through `normbox_lab.images.color`."""
        from normbox_lab.images.color import spectral_to_XYZ

        return spectral_to_XYZ(self.wavelength_nm, np.asarray(getattr(self, image), np.float64))

    def luminance_cd_m2(self) -> np.ndarray:
        return self.XYZ()[..., 1]
