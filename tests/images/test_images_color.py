"""images.color: absolute XYZ closes on the luminance, white maps to white, ΔE00 maps."""

import numpy as np
import pytest

from normbox_lab.images import color
from normbox_lab.predict.render import Lamp, luminance_cd_m2

WL = np.arange(380.0, 781.0, 5.0)


def test_spectral_to_XYZ_Y_is_the_luminance_in_cd_m2():
    lamp = Lamp().radiance(WL)
    Y = color.spectral_to_XYZ(WL, lamp)[1]
    # ȳ of CIE 1931 is V(λ) of CIE 1924: the same luminance within the integration rule
    assert Y == pytest.approx(luminance_cd_m2(WL, lamp), rel=2e-3)


def test_spectral_to_XYZ_is_vectorised_over_pixels():
    rng = np.random.default_rng(3)
    img = rng.uniform(0.0, 0.02, size=(4, 5, WL.size))
    XYZ = color.spectral_to_XYZ(WL, img)
    assert XYZ.shape == (4, 5, 3)
    np.testing.assert_allclose(XYZ[2, 3], color.spectral_to_XYZ(WL, img[2, 3]), rtol=1e-12)


def test_perfect_white_reflector_under_D65_is_Y_1_at_the_D65_white_point():
    XYZ = color.reflectance_to_XYZ(WL, np.ones(WL.size))
    assert XYZ[1] == pytest.approx(1.0, rel=1e-9)
    np.testing.assert_allclose(color.XYZ_to_xy(XYZ), color.D65_xy(), atol=2e-4)


def test_srgb_white_grey_and_clipping():
    white = color.reflectance_to_XYZ(WL, np.ones(WL.size))
    np.testing.assert_allclose(color.XYZ_to_srgb(white, white_Y=1.0), 1.0, atol=2e-3)
    grey = color.XYZ_to_srgb(0.18 * white, white_Y=1.0)
    # sRGB encoding of linear 0.18: 1.055·0.18^(1/2.4) − 0.055
    np.testing.assert_allclose(grey, 1.055 * 0.18 ** (1 / 2.4) - 0.055, atol=2e-3)
    over = color.XYZ_to_srgb(5.0 * white, white_Y=1.0)
    assert np.all(over <= 1.0) and np.all(over >= 0.0)
    with pytest.raises(ValueError):
        color.XYZ_to_srgb(white, white_Y=0.0)


def test_delta_e00_map_zero_on_identity_and_matches_colour_science():
    import colour

    rng = np.random.default_rng(5)
    a = rng.uniform(0.05, 0.9, size=(3, 4, 3))
    b = a * rng.uniform(0.9, 1.1, size=a.shape)
    white = np.array([0.95047, 1.0, 1.08883])
    assert np.all(color.delta_e00_map(a, a, white) == 0.0)
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    want = colour.delta_E(colour.XYZ_to_Lab(a, d65), colour.XYZ_to_Lab(b, d65), method="CIE 2000")
    np.testing.assert_allclose(color.delta_e00_map(a, b, white), want, rtol=1e-12)
    # scaling both images and the white together changes nothing
    np.testing.assert_allclose(color.delta_e00_map(7 * a, 7 * b, 7 * white), want, rtol=1e-9)


def test_png_round_trip(tmp_path):
    from matplotlib.image import imread

    img = np.linspace(0, 1, 2 * 3 * 3).reshape(2, 3, 3)
    path = color.write_png(tmp_path / "sub" / "x.png", img)
    back = imread(path)[..., :3]
    np.testing.assert_array_equal(np.round(back * 255).astype(np.uint8), color.to_uint8(img))
