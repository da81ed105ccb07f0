"""One spectral grid and one list of ColorChecker names, identical to colour-science's."""

import colour
import numpy as np

from normbox_lab.core import spectral


def test_grids_are_the_visible_range_inclusive():
    assert spectral.RADIOMETER_WAVELENGTHS_NM.size == 401
    assert spectral.BAND_WAVELENGTHS_NM.size == 81
    assert spectral.RADIOMETER_WAVELENGTHS_NM[[0, -1]].tolist() == [380.0, 780.0]
    np.testing.assert_array_equal(spectral.spectral_shape(5.0).wavelengths,
                                  spectral.BAND_WAVELENGTHS_NM)


def test_patch_names_are_colour_sciences():
    sds = colour.SDS_COLOURCHECKERS[spectral.COLORCHECKER_DATASET]
    assert tuple(sds.keys()) == spectral.PATCH_NAMES
    assert spectral.patch_name(spectral.WHITE_PATCH).startswith("white")


def test_material_grid_is_the_colorchecker_tabulation():
    sd = next(iter(colour.SDS_COLOURCHECKERS[spectral.COLORCHECKER_DATASET].values()))
    np.testing.assert_array_equal(sd.wavelengths, spectral.BAND_WAVELENGTHS_NM)
