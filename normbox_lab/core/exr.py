"""Multilayer spectral OpenEXR: radiance, its diffuse / specular / indirect parts, depth, normal.
In `core`: a file format that the images, the renderers' import and the pipeline all read.

Channel names follow "An OpenEXR Layout for Spectral Images" (Fichet, Pacanowski & Wilkie, JCGT
10(3), 2021, http://jcgt.org/published/0010/03/01/): an emissive spectral channel is
``S0.<wavelength><unit>`` with a *comma* as decimal separator, written here as the authors'
reference library does (six decimals, nanometres): ``S0.380,000000nm``. The header carries
``spectralLayoutVersion = "1.0"`` and ``emissiveUnits = "W.m^-2.sr^-1"``; an optional linear-sRGB
preview goes to ``R, G, B`` as the layout asks. The layout defines one image; the extra layers of
a MIST-style multilayer file use OpenEXR's layer convention (``layer.channel``):

    radiance        S0.<λ>nm                 (H, W, B)  W·sr⁻¹·m⁻²·nm⁻¹
    diffuse         diffuse.S0.<λ>nm         (H, W, B)
    specular        specular.S0.<λ>nm        (H, W, B)
    indirect        indirect.S0.<λ>nm        (H, W, B)
    depth_m         Z                        (H, W)     camera-to-surface distance, metres
    normal          normal.X, normal.Y, normal.Z (H, W, 3)  world-space unit normal
    preview_rgb     R, G, B                  (H, W, 3)  linear sRGB (scene-referred)

Every channel is float32 (EXR's FLOAT); files are written losslessly (PIZ) through Mitsuba's
`mi.Bitmap`, already a dependency, imported only when a file is written or read.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SPECTRAL_LAYERS: tuple[str, ...] = ("radiance", "diffuse", "specular", "indirect")
"""Spectral layers in file order; `radiance` is the layout's main (unprefixed) S0 image."""
DEPTH_CHANNEL = "Z"
NORMAL_CHANNELS: tuple[str, ...] = ("normal.X", "normal.Y", "normal.Z")
PREVIEW_CHANNELS: tuple[str, ...] = ("R", "G", "B")
LAYOUT_ATTRIBUTES: dict[str, str] = {"spectralLayoutVersion": "1.0",
                                     "emissiveUnits": "W.m^-2.sr^-1"}
DEPTH_UNITS_ATTRIBUTE = "normboxDepthUnits"
_RESERVED_KEYS = frozenset({*SPECTRAL_LAYERS, "wavelength_nm", "depth_m", "normal", "preview_rgb",
                            "other", "channel_names", "attributes", "S0", "R", "G", "B", "Z"})

_SPECTRAL_RE = re.compile(r"^(?:(?P<layer>[A-Za-z_][A-Za-z0-9_]*)\.)?S0\."
                          r"(?P<number>\d*,?\d*(?:[eE][-+]?\d+)?)nm$")


def spectral_channel_name(wavelength_nm: float, layer: str = "radiance") -> str:
    """``S0.380,000000nm`` for radiance, ``<layer>.S0.380,000000nm`` for any other layer."""
    number = f"{float(wavelength_nm):.6f}".replace(".", ",")
    prefix = "" if layer == "radiance" else f"{layer}."
    return f"{prefix}S0.{number}nm"


def parse_spectral_channel(name: str) -> tuple[str, float] | None:
    """``diffuse.S0.380,000000nm`` → ("diffuse", 380.0); a non-spectral name → None."""
    match = _SPECTRAL_RE.match(name)
    if match is None or match.group("number") in ("", ","):
        return None
    return match.group("layer") or "radiance", float(match.group("number").replace(",", "."))


@dataclass(frozen=True)
class _Layer:
    names: list[str]
    data: np.ndarray  # (H, W, C) float32


def _as_float32(name: str, value: Any, expected_ndim: int) -> np.ndarray:
    arr = np.asarray(value)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise TypeError(f"{name} must be numeric, got dtype {arr.dtype}")
    if arr.ndim != expected_ndim:
        raise ValueError(f"{name} must have {expected_ndim} dimensions, got shape {arr.shape}")
    return arr.astype(np.float32, copy=False)


def write_spectral_exr(path: str | Path, image: Any = None, *,
                       wavelength_nm: Any = None,
                       radiance: Any = None, diffuse: Any = None, specular: Any = None,
                       indirect: Any = None, depth_m: Any = None, normal: Any = None,
                       preview_rgb: Any = None,
                       extra_spectral: dict[str, Any] | None = None,
                       attributes: dict[str, str] | None = None) -> Path:
    """Write one multilayer spectral EXR and return its path.

    Layers come as numpy arrays (keywords) or from `image`, any object with the attributes
    wavelength_nm, radiance, diffuse, specular, indirect, depth_m, normal (and optionally
    preview_rgb), e.g. `images.camera.SpectralImage`; a keyword given explicitly wins over the
    object's attribute. Absent (None) layers are left out. `extra_spectral` adds more (H, W, B)
    layers on the same wavelengths, e.g. {"emission": ..., "cwni": ...}, written as
    ``<name>.S0.<λ>nm`` and read back under their name. `attributes` adds string header
    attributes (they cannot replace the layout's own)."""
    given = {"wavelength_nm": wavelength_nm, "radiance": radiance, "diffuse": diffuse,
             "specular": specular, "indirect": indirect, "depth_m": depth_m, "normal": normal,
             "preview_rgb": preview_rgb}
    if image is not None:
        for key, value in given.items():
            if value is None:
                given[key] = getattr(image, key, None)

    extra = dict(extra_spectral or {})
    for name in extra:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or name in _RESERVED_KEYS:
            raise ValueError(f"extra spectral layer name {name!r} is not a free identifier")
    layers: list[_Layer] = []
    given.update(extra)
    spectral_present = [k for k in (*SPECTRAL_LAYERS, *extra) if given[k] is not None]
    if spectral_present:
        if given["wavelength_nm"] is None:
            raise ValueError("spectral layers need wavelength_nm")
        wl = np.asarray(given["wavelength_nm"], dtype=np.float64)
        if wl.ndim != 1 or wl.size == 0 or not np.all(np.isfinite(wl)) or np.any(wl <= 0):
            raise ValueError("wavelength_nm must be a non-empty 1-D array of positive values")
        names_per_wl = [spectral_channel_name(w) for w in wl]
        if len(set(names_per_wl)) != wl.size:
            raise ValueError("wavelength_nm values must be distinct at 1e-6 nm")
        for key in spectral_present:
            data = _as_float32(key, given[key], 3)
            if data.shape[2] != wl.size:
                raise ValueError(f"{key} has {data.shape[2]} bands, wavelength_nm {wl.size}")
            layers.append(_Layer([spectral_channel_name(w, key) for w in wl], data))
    if given["depth_m"] is not None:
        layers.append(_Layer([DEPTH_CHANNEL], _as_float32("depth_m", given["depth_m"], 2)[..., None]))
    if given["normal"] is not None:
        layers.append(_Layer(list(NORMAL_CHANNELS), _as_float32("normal", given["normal"], 3)))
    if given["preview_rgb"] is not None:
        layers.append(_Layer(list(PREVIEW_CHANNELS),
                             _as_float32("preview_rgb", given["preview_rgb"], 3)))
    if not layers:
        raise ValueError("nothing to write: every layer is None")
    height, width = layers[0].data.shape[:2]
    for layer in layers:
        if layer.data.shape[:2] != (height, width):
            raise ValueError(f"layer {layer.names[0]} is {layer.data.shape[:2]}, "
                             f"expected {(height, width)}")
        if layer.data.shape[2] != len(layer.names):
            raise ValueError(f"layer {layer.names[0]} has {layer.data.shape[2]} channels, "
                             f"expected {len(layer.names)}")
    if height == 0 or width == 0:
        raise ValueError("an EXR image needs at least one pixel")

    import mitsuba as mi

    channel_names = [n for layer in layers for n in layer.names]
    pixels = np.ascontiguousarray(np.concatenate([layer.data for layer in layers], axis=2))
    bitmap = mi.Bitmap(pixels, pixel_format=mi.Bitmap.PixelFormat.MultiChannel,
                       channel_names=channel_names)
    metadata = bitmap.metadata()
    layout = LAYOUT_ATTRIBUTES if spectral_present else {}
    for key, value in {**(attributes or {}), **layout}.items():
        metadata[key] = str(value)
    if given["depth_m"] is not None:
        metadata[DEPTH_UNITS_ATTRIBUTE] = "m"
    out = Path(path)
    bitmap.write(str(out), mi.Bitmap.FileFormat.OpenEXR)
    return out


def read_spectral_exr(path: str | Path) -> dict[str, Any]:
    """Read a file written by `write_spectral_exr` (or any spectral EXR with S0 channels in nm).

    Returns a dict with "wavelength_nm" (B,) float64 (ascending, parsed from channel names),
    "radiance", "diffuse", "specular", "indirect" (H, W, B) float32 for those present,
    "depth_m" (H, W), "normal" (H, W, 3), "preview_rgb" (H, W, 3) where present,
    "other" {channel: (H, W)} for channels not in this layout, "channel_names" in file order and
    "attributes" {name: value} from the header."""
    import mitsuba as mi

    bitmap = mi.Bitmap(str(path))
    names = [field.name for field in bitmap.struct_()]
    pixels = np.array(bitmap, copy=True)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    column = {name: i for i, name in enumerate(names)}

    known = {DEPTH_CHANNEL}
    for group in (NORMAL_CHANNELS, PREVIEW_CHANNELS):
        if all(n in column for n in group):
            known.update(group)
    spectral: dict[str, dict[float, int]] = {}
    other: dict[str, np.ndarray] = {}
    for name, i in column.items():
        parsed = parse_spectral_channel(name)
        if parsed is not None and (parsed[0] in SPECTRAL_LAYERS
                                   or parsed[0] not in _RESERVED_KEYS):
            layer, wl = parsed
            spectral.setdefault(layer, {})[wl] = i
        elif name not in known:
            other[name] = np.ascontiguousarray(pixels[..., i])

    result: dict[str, Any] = {"channel_names": names}
    wavelength_nm: np.ndarray | None = None
    for layer, by_wl in spectral.items():
        wl = np.array(sorted(by_wl), dtype=np.float64)
        if wavelength_nm is None:
            wavelength_nm = wl
        elif not np.array_equal(wl, wavelength_nm):
            raise ValueError(f"{path}: layer {layer!r} has other wavelengths than the first layer")
        result[layer] = np.ascontiguousarray(pixels[..., [by_wl[w] for w in wl]])
    if wavelength_nm is not None:
        result["wavelength_nm"] = wavelength_nm
    if DEPTH_CHANNEL in column:
        result["depth_m"] = np.ascontiguousarray(pixels[..., column[DEPTH_CHANNEL]])
    if all(n in column for n in NORMAL_CHANNELS):
        result["normal"] = np.ascontiguousarray(pixels[..., [column[n] for n in NORMAL_CHANNELS]])
    if all(n in column for n in PREVIEW_CHANNELS):
        result["preview_rgb"] = np.ascontiguousarray(
            pixels[..., [column[n] for n in PREVIEW_CHANNELS]])
    result["other"] = other
    metadata = bitmap.metadata()
    result["attributes"] = {str(key): metadata[key] for key in metadata}
    return result
