"""The colour maths every room shares: emissive CIE 1931 2° XYZ of spectra, Lab with the D65
white point and CIE 2000 ΔE, all through colour-science (imported lazily).

It lives in `core` so that the comparison (`normbox_lab.analyze.compare`) and the images
(`normbox_lab.images.color`) take it from below instead of one reaching into the other.

- `spectra_to_XYZ`: emissive XYZ (illuminant E, k = 1, colour-science's division by 100) of
  spectra [..., λ] on a regular grid; the scale cancels wherever XYZ is normalised by a white.
- `XYZ_to_Lab_D65`: CIE L*a*b* of XYZ whose white has Y = 1, D65 white point.
- `delta_e00`: CIE 2000 colour difference with kL = kC = kH = 1.
"""

from __future__ import annotations

import numpy as np

from normbox_lab.core.errors import DataError


def spectra_to_XYZ(radiance: np.ndarray, wavelength_nm: np.ndarray) -> np.ndarray:
    """Emissive CIE 1931 2° XYZ (relative scale, k = 1) of spectra [..., λ] on a regular grid."""
    import colour
    from colour.colorimetry.tristimulus_values import msds_to_XYZ_integration

    wl = np.asarray(wavelength_nm, dtype=float)
    step = np.diff(wl)
    if wl.size < 2 or not np.allclose(step, step[0]):
        raise DataError("spectra", "wavelength_nm", "needs a regular wavelength grid")
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(step[0]))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    return msds_to_XYZ_integration(np.asarray(radiance, dtype=float), cmfs,
                                   colour.sd_ones(shape), k=1, shape=shape)


def XYZ_to_Lab_D65(XYZ: np.ndarray) -> np.ndarray:
    """CIE L*a*b* (D65 white point) of XYZ normalised so that the white has Y = 1."""
    import colour

    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(XYZ, illuminant=d65)


def delta_e00(lab_a: np.ndarray, lab_b: np.ndarray) -> np.ndarray:
    """CIE 2000 ΔE between two Lab arrays (kL = kC = kH = 1)."""
    import colour

    return colour.delta_E(lab_a, lab_b, method="CIE 2000", textiles=False)


__all__ = ["XYZ_to_Lab_D65", "delta_e00", "spectra_to_XYZ"]
