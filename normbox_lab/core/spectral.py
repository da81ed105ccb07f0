"""The one spectral grid of the Normbox and the ColorChecker's patch names.

Every module takes its wavelengths from here: the radiometers' 380–780 nm output at 1 nm, and
the 5 nm grid of the materials and the renderer's bands (the grid of colour-science's
ColorChecker N Ohta reflectances).  `spectral_shape()` gives the same grid as a
`colour.SpectralShape` for colour-science calls.

The patch names are those of colour-science's ``SDS_COLOURCHECKERS["ColorChecker N Ohta"]``
(a test checks they are identical).  They are written out here, not read from colour-science,
so that the CLI, the TUI and the protocols can name a patch without importing colour-science
(about a second at start-up).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: the visible range every instrument and the renderer cover, in nm (both ends included)
VISIBLE_RANGE_NM: tuple[float, float] = (380.0, 780.0)


def wavelengths_nm(step_nm: float) -> np.ndarray:
    """380 … 780 nm inclusive at `step_nm`."""
    start, end = VISIBLE_RANGE_NM
    return np.arange(start, end + 0.5 * float(step_nm), float(step_nm))


def spectral_shape(step_nm: float = 1.0) -> Any:
    """The same grid as a `colour.SpectralShape` (colour-science is imported here, lazily)."""
    import colour

    return colour.SpectralShape(*VISIBLE_RANGE_NM, float(step_nm))


#: the spectroradiometers' output grid: 380–780 nm at 1 nm (401 values)
RADIOMETER_WAVELENGTHS_NM = wavelengths_nm(1.0)
#: the materials' tabulation and the renderer's band centres: 380–780 nm at 5 nm (81 values)
BAND_WAVELENGTHS_NM = wavelengths_nm(5.0)

#: the ColorChecker data set of colour-science that the virtual patches are made of
COLORCHECKER_DATASET = "ColorChecker N Ohta"
#: ColorChecker Classic patch names, patch number N at index N − 1 (colour-science's names)
PATCH_NAMES: tuple[str, ...] = (
    "dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green",
    "orange", "purplish blue", "moderate red", "purple", "yellow green", "orange yellow",
    "blue", "green", "red", "yellow", "magenta", "cyan",
    "white 9.5 (.05 D)", "neutral 8 (.23 D)", "neutral 6.5 (.44 D)", "neutral 5 (.70 D)",
    "neutral 3.5 (1.05 D)", "black 2 (1.5 D)",
)
#: the white patch, whose Y at 30° normalises the comparison's colorimetry
WHITE_PATCH = 19


def patch_name(n: int) -> str:
    """ColorChecker patch name of patch 1 … 24."""
    if not 1 <= int(n) <= 24:
        raise ValueError(f"ColorChecker patches are numbered 1…24, got {n}")
    return PATCH_NAMES[int(n) - 1]
