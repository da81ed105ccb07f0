"""Spectral images → CIE 1931 2° XYZ → sRGB, and per-pixel ΔE00, all through colour-science.

Conventions (one way for the whole images package):
- spectra are arrays `[..., B]` on a regular wavelength grid `wavelength_nm` (B,);
- `spectral_to_XYZ` of a radiance (W·sr⁻¹·m⁻²·nm⁻¹) is absolute: Y is the luminance in cd/m²
  (K_m = 683 lm/W times the CIE 1931 ȳ integral, as `normbox_lab.predict.render.luminance_cd_m2`);
- `reflectance_to_XYZ` is the object colour under an illuminant (default D65): Y = 1 for the
  perfect white reflector;
- `XYZ_to_srgb` maps XYZ scaled so that `white_Y` → 1 to IEC 61966-2-1 sRGB (D65), clipping the
  linear values to [0, 1] before the transfer function — the display preview, not a colorimetric
  product.  A non-D65 scene white is adapted first by `normbox_lab.images.whitebalance`;
- `delta_e00_map`: CIE 2000 ΔE between two XYZ images, both normalised by one reference white
  (`white_XYZ`, Y of the white → 1), Lab with D65 — the convention of the comparison, from
  `normbox_lab.core.colorimetry` (kL = kC = kH = 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: maximum luminous efficacy of photopic vision, lm/W
KM_LM_PER_W = 683.0


def spectral_to_XYZ(wavelength_nm: Any, radiance: Any) -> np.ndarray:
    """Absolute XYZ of spectral radiances [..., B] (Y = luminance in cd/m²)."""
    from normbox_lab.core.colorimetry import spectra_to_XYZ

    # compare.spectra_to_XYZ integrates with k = 1 and colour-science's division by 100
    return spectra_to_XYZ(np.asarray(radiance, dtype=np.float64),
                          np.asarray(wavelength_nm, dtype=np.float64)) * (100.0 * KM_LM_PER_W)


def reflectance_to_XYZ(wavelength_nm: Any, reflectance: Any, illuminant: str = "D65") -> np.ndarray:
    """XYZ of reflectance spectra [..., B] under a CIE illuminant; Y = 1 for the perfect white."""
    import colour
    from colour.colorimetry.tristimulus_values import msds_to_XYZ_integration

    wl = _regular(wavelength_nm)
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    sd_illuminant = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    return msds_to_XYZ_integration(np.asarray(reflectance, dtype=np.float64), cmfs,
                                   sd_illuminant, shape=shape) / 100.0


def XYZ_to_xy(XYZ: Any) -> np.ndarray:
    """Chromaticity of XYZ [..., 3] (colour-science; black maps to the D65 white point)."""
    import colour

    return np.asarray(colour.XYZ_to_xy(np.asarray(XYZ, dtype=np.float64)))


def D65_xy() -> np.ndarray:
    import colour

    return np.asarray(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def default_white_Y(XYZ: Any, percentile: float = 99.0) -> float:
    """A display white for an image: the `percentile` of its Y (robust to a few hot pixels)."""
    Y = np.asarray(XYZ, dtype=np.float64)[..., 1]
    Y = Y[np.isfinite(Y)]
    white = float(np.percentile(Y, percentile)) if Y.size else 0.0
    return white if white > 0.0 else 1.0


def XYZ_to_srgb(XYZ: Any, white_Y: float | None = None) -> np.ndarray:
    """Display sRGB in [0, 1] (encoded) of XYZ [..., 3]: scaled by 1/white_Y (default: the 99th
    percentile of Y), linear sRGB through colour-science's matrix, clipped, then encoded."""
    import colour

    XYZ = np.nan_to_num(np.asarray(XYZ, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    white = float(white_Y) if white_Y is not None else default_white_Y(XYZ)
    if not white > 0.0:
        raise ValueError(f"white_Y must be > 0, got {white_Y!r}")
    rgb_linear = colour.XYZ_to_RGB(XYZ / white, colour.RGB_COLOURSPACES["sRGB"],
                                   apply_cctf_encoding=False)
    return np.asarray(colour.cctf_encoding(np.clip(rgb_linear, 0.0, 1.0), function="sRGB"))


def spectral_to_srgb(wavelength_nm: Any, radiance: Any, white_Y: float | None = None) -> np.ndarray:
    """`XYZ_to_srgb(spectral_to_XYZ(...))` (no white balance: the scene white shows its cast)."""
    return XYZ_to_srgb(spectral_to_XYZ(wavelength_nm, radiance), white_Y)


def delta_e00_map(XYZ_a: Any, XYZ_b: Any, white_XYZ: Any) -> np.ndarray:
    """Per-pixel CIE 2000 ΔE between two XYZ images [..., 3] normalised by one white."""
    from normbox_lab.core.colorimetry import XYZ_to_Lab_D65, delta_e00

    white_Y = float(np.asarray(white_XYZ, dtype=np.float64)[1])
    if not white_Y > 0.0:
        raise ValueError(f"the reference white must have Y > 0, got {white_XYZ!r}")
    lab_a = XYZ_to_Lab_D65(np.asarray(XYZ_a, dtype=np.float64) / white_Y)
    lab_b = XYZ_to_Lab_D65(np.asarray(XYZ_b, dtype=np.float64) / white_Y)
    return np.asarray(delta_e00(lab_a, lab_b))


def to_uint8(srgb: Any) -> np.ndarray:
    """Encoded sRGB in [0, 1] → uint8 (rounded)."""
    return np.round(np.clip(np.asarray(srgb, dtype=np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def write_png(path: str | Path, srgb: Any) -> Path:
    """Write an encoded sRGB image (H, W, 3) in [0, 1] as an 8-bit PNG (matplotlib, no pyplot)."""
    from matplotlib.image import imsave

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    imsave(path, to_uint8(srgb))
    return path


def _regular(wavelength_nm: Any) -> np.ndarray:
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    step = np.diff(wl)
    if wl.ndim != 1 or wl.size < 2 or not np.allclose(step, step[0]):
        raise ValueError("spectral images need a regular wavelength grid (B ≥ 2, equal steps)")
    return wl
