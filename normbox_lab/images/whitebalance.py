"""Wilkie & Weidlich 2009, "A Robust Illumination Estimate for Chromatic Adaptation in Rendered
Images": the illuminant from the renderer's auxiliary images, and a Bradford transform to the
display white.  Pure image math (numpy + colour-science) on images a renderer has produced:

- raw   the rendered image;
- CWNI  "Coloured World, Neutralised Illuminants": at the first hit the incident light is
        replaced by its spectral average (a flat spectrum of the same mean), the BRDF kept;
- NWCI  "Neutralised World, Coloured Illuminants": the BRDF at the first hit is replaced by a
        neutral one of the same albedo, the incident light kept.

Images are XYZ (H, W, 3), or spectral (H, W, B) with `wavelength_nm` (converted by
`normbox_lab.images.color.spectral_to_XYZ`, CIE 1931 2°).  The steps (paper §3.2–3.3):

1. "1 − Chroma" image from the CWNI image in CIE LCh(ab) (paper eq. 1):
       g = ((1 − (C − Cmin)/(Cmax − Cmin)) · L/Lmax)^w
   with Cmin, Cmax, Lmax over all pixels.  The exponent applies to the whole product (in the
   paper's layout w closes the bracket after L/Lmax; and only then is g "dark in areas that are
   not well lit", as its Fig. 7 says).  The Lab reference white is the neutralised light's own
   white, equal energy (CIE E: a flat spectrum), with the CWNI image scaled so that its largest Y
   is 1.  w (selectivity) default 2, 1…4 (the paper's practical range); others are refused.
2. "NWCI multiplied" = NWCI · g per pixel.
3. Illuminant = gray world on the NWCI-multiplied image.  The paper: "averaging of the pixel
   chromaticities … equivalent to a simple gray world approach".  Scaling a pixel by g does not
   change its chromaticity, so an unweighted average of per-pixel xy would ignore step 1; the
   average that is a gray world and keeps the weights is that of XYZ, i.e. of the chromaticities
   weighted by X + Y + Z.  `estimate_illuminant` returns the mean XYZ and its xy.
4. Bradford (von Kries in Bradford's cone space) from the estimated illuminant white to the
   display white (D65), `colour.adaptation.chromatic_adaptation_VonKries(..., 'Bradford')`.

Plain gray world on the raw image (`gray_world(raw)`) is the image-only baseline it beats.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

W_MIN = 1.0
W_MAX = 4.0
W_DEFAULT = 2.0
#: CIE 1931 2° chromaticities of the whites used here
E_XY = (1.0 / 3.0, 1.0 / 3.0)


@dataclass
class WWEstimate:
    """The Wilkie–Weidlich illumination estimate and its intermediate images."""

    illuminant_XYZ: np.ndarray        # (3,) mean XYZ of the NWCI-multiplied image (its units)
    illuminant_xy: np.ndarray         # (2,) CIE 1931 xy of that
    one_minus_chroma: np.ndarray      # (H, W) g in [0, 1]
    nwci_multiplied: np.ndarray       # (H, W, 3) XYZ
    w: float


def check_w(w: float) -> float:
    """The selectivity w as a float; ValueError outside [1, 4] (or not finite)."""
    w = float(w)
    if not np.isfinite(w) or not W_MIN <= w <= W_MAX:
        raise ValueError(f"w (1−Chroma selectivity) must be in [{W_MIN:g}, {W_MAX:g}] "
                         f"(Wilkie & Weidlich: 2 is best, about 4 the largest useful), got {w}")
    return w


def as_XYZ(image: Any, wavelength_nm: Any = None) -> np.ndarray:
    """XYZ (…, 3) of an image: spectral (…, B) with `wavelength_nm`, or already XYZ (…, 3)."""
    arr = np.asarray(image, dtype=np.float64)
    if wavelength_nm is not None:
        from normbox_lab.images.color import spectral_to_XYZ

        wl = np.asarray(wavelength_nm, dtype=np.float64)
        if arr.shape[-1] != wl.size:
            raise ValueError(f"spectral image has {arr.shape[-1]} bands, wavelength_nm "
                             f"{wl.size}")
        return spectral_to_XYZ(wl, arr)
    if arr.shape[-1] != 3:
        raise ValueError(f"an XYZ image needs 3 channels (or give wavelength_nm for a spectral "
                         f"image), got shape {arr.shape}")
    return arr


def _xy(XYZ: np.ndarray) -> np.ndarray:
    s = float(np.sum(XYZ))
    if not s > 0.0 or not np.isfinite(s):
        raise ValueError(f"no light to estimate a chromaticity from (XYZ = {XYZ})")
    return np.array([XYZ[0] / s, XYZ[1] / s])


def _xy_to_XYZ(xy: Any, Y: float = 1.0) -> np.ndarray:
    x, y = (float(v) for v in np.asarray(xy, dtype=np.float64).ravel()[:2])
    return np.array([x / y * Y, Y, (1.0 - x - y) / y * Y])


def display_white_xy(name: str = "D65") -> np.ndarray:
    """CIE 1931 2° chromaticity of a CIE illuminant (the display white: D65)."""
    import colour

    return np.asarray(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][name],
                      dtype=np.float64)


def one_minus_chroma(cwni_XYZ: Any, w: float = W_DEFAULT, *,
                     white_xy: Any = E_XY) -> np.ndarray:
    """The "1 − Chroma" image g (H, W) of a CWNI XYZ image (paper eq. 1; module doc, step 1).

    Non-finite or negative pixels count as black.  With Cmax = Cmin (all pixels equally
    chromatic) the chroma factor is 1; an all-black image gives g = 0 everywhere."""
    import colour

    w = check_w(w)
    XYZ = np.nan_to_num(as_XYZ(cwni_XYZ), nan=0.0, posinf=0.0, neginf=0.0)
    XYZ = np.clip(XYZ, 0.0, None)
    Y_max = float(np.max(XYZ[..., 1])) if XYZ.size else 0.0
    if not Y_max > 0.0:
        return np.zeros(XYZ.shape[:-1])
    lab = colour.XYZ_to_Lab(XYZ / Y_max, illuminant=np.asarray(white_xy, dtype=np.float64))
    lch = np.asarray(colour.Lab_to_LCHab(lab), dtype=np.float64)
    L, C = lch[..., 0], lch[..., 1]
    c_min, c_max, l_max = float(np.min(C)), float(np.max(C)), float(np.max(L))
    chroma = (C - c_min) / (c_max - c_min) if c_max > c_min else np.zeros_like(C)
    g = np.clip((1.0 - chroma) * L / l_max, 0.0, 1.0) ** w
    return g


def gray_world(XYZ: Any, weights: Any = None) -> np.ndarray:
    """Gray-world illuminant estimate: the (weighted) mean XYZ (3,) of an XYZ image."""
    arr = np.nan_to_num(as_XYZ(XYZ), nan=0.0, posinf=0.0, neginf=0.0).reshape(-1, 3)
    if weights is None:
        return arr.mean(axis=0)
    wts = np.asarray(weights, dtype=np.float64).reshape(-1)
    if wts.size != arr.shape[0]:
        raise ValueError(f"{wts.size} weights for {arr.shape[0]} pixels")
    total = float(wts.sum())
    if not total > 0.0:
        raise ValueError("gray_world: the weights sum to zero")
    return (arr * wts[:, None]).sum(axis=0) / total


def gray_world_xy(XYZ: Any, weights: Any = None) -> np.ndarray:
    """xy of `gray_world`."""
    return _xy(gray_world(XYZ, weights))


def estimate_illuminant(cwni_XYZ: Any, nwci_XYZ: Any, w: float = W_DEFAULT, *,
                        wavelength_nm: Any = None) -> WWEstimate:
    """Wilkie–Weidlich: 1−Chroma from CWNI, NWCI × 1−Chroma, gray world on that (module doc).

    XYZ images (H, W, 3), or spectral (H, W, B) with `wavelength_nm`."""
    w = check_w(w)
    cwni = as_XYZ(cwni_XYZ, wavelength_nm)
    nwci = as_XYZ(nwci_XYZ, wavelength_nm)
    if cwni.shape != nwci.shape:
        raise ValueError(f"CWNI {cwni.shape} and NWCI {nwci.shape} differ in shape")
    g = one_minus_chroma(cwni, w)
    multiplied = np.nan_to_num(nwci, nan=0.0, posinf=0.0, neginf=0.0) * g[..., None]
    XYZ = gray_world(multiplied)
    return WWEstimate(illuminant_XYZ=XYZ, illuminant_xy=_xy(XYZ), one_minus_chroma=g,
                      nwci_multiplied=multiplied, w=w)


def bradford_matrix(illuminant_XYZ: Any, display_xy: Any = None) -> np.ndarray:
    """The 3×3 Bradford (von Kries) matrix M with XYZ_display = M @ XYZ that takes the
    illuminant's white (its chromaticity, Y kept) to the display white (default D65)."""
    from colour.adaptation import matrix_chromatic_adaptation_VonKries

    src = _xy_to_XYZ(_xy(np.asarray(illuminant_XYZ, dtype=np.float64)))
    dst = _xy_to_XYZ(display_white_xy() if display_xy is None else display_xy)
    return np.asarray(matrix_chromatic_adaptation_VonKries(src, dst, transform="Bradford"),
                      dtype=np.float64)


def adapt_to_display(XYZ: Any, illuminant_XYZ: Any, display_xy: Any = None) -> np.ndarray:
    """Bradford chromatic adaptation of an XYZ image (…, 3) from the illuminant's white to the
    display white (default D65); luminance of the white is kept."""
    arr = np.asarray(XYZ, dtype=np.float64)
    M = bradford_matrix(illuminant_XYZ, display_xy)
    return arr @ M.T


def white_balanced_srgb(image: Any, *, cwni: Any = None, nwci: Any = None,
                        wavelength_nm: Any = None, w: float = W_DEFAULT,
                        white_Y: float | None = None) -> np.ndarray:
    """Display sRGB (H, W, 3) in [0, 1] of a rendered image, white-balanced by Wilkie–Weidlich.

    `image`: a spectral image object with `.radiance`, `.cwni`, `.nwci` (H, W, B) and
    `.wavelength_nm` (`normbox_lab.images.camera.SpectralImage`), or an array — spectral with
    `wavelength_nm`, or XYZ — with `cwni` and `nwci` arrays of the same kind.  Without
    auxiliary images the illuminant is plain gray world on the image (the fallback, weaker)."""
    from normbox_lab.images.color import XYZ_to_srgb

    if hasattr(image, "radiance"):
        wavelength_nm = getattr(image, "wavelength_nm", wavelength_nm)
        cwni = getattr(image, "cwni", None) if cwni is None else cwni
        nwci = getattr(image, "nwci", None) if nwci is None else nwci
        image = image.radiance
    raw = as_XYZ(image, wavelength_nm)
    if cwni is not None and nwci is not None:
        illuminant = estimate_illuminant(cwni, nwci, w, wavelength_nm=wavelength_nm) \
            .illuminant_XYZ
    else:
        illuminant = gray_world(raw)
    return XYZ_to_srgb(adapt_to_display(raw, illuminant), white_Y)


def coloured_room_materials() -> dict[str, Any]:
    """The acceptance scene's materials for `images.cornell.render_cornell`: every wall, the
    floor and the ceiling strongly coloured (greens and teal), one flat white cube (ρ = 0.85).
    Lit by a 1800 K Planckian lamp this is the case W&W is built for (docs/images.md)."""
    from normbox_lab.predict.materials import MATERIAL_WAVELENGTHS_NM, Material

    wl = MATERIAL_WAVELENGTHS_NM

    def band(centre_nm: float, width_nm: float, base: float, peak: float) -> np.ndarray:
        return base + peak * np.exp(-0.5 * ((wl - centre_nm) / width_nm) ** 2)

    green = Material.diffuse("green", band(530.0, 35.0, 0.04, 0.6), wl)
    teal = Material.diffuse("teal", band(495.0, 40.0, 0.03, 0.6), wl)
    return {"back": green, "right": green, "floor": green, "left": teal, "ceiling": teal,
            "box": Material.diffuse("white", np.full(wl.shape, 0.85), wl)}
