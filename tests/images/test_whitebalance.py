"""Wilkie & Weidlich 2009 white balance: the image math on synthetic images."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.images import whitebalance as wb

WL = np.arange(380.0, 781.0, 5.0)


def _XYZ(xy, Y=1.0):
    x, y = xy
    return np.array([x / y * Y, Y, (1 - x - y) / y * Y])


def _xy(XYZ):
    return np.asarray(XYZ)[..., :2] / np.sum(XYZ, axis=-1, keepdims=True)


E = _XYZ((1 / 3, 1 / 3))
RED_LIGHT_XY = (0.55, 0.38)


@pytest.mark.parametrize("w", [0.0, 0.99, 4.01, 6.0, float("nan"), float("inf")])
def test_w_outside_1_to_4_is_refused(w):
    img = np.ones((2, 2, 3))
    with pytest.raises(ValueError, match="w"):
        wb.one_minus_chroma(img, w)
    with pytest.raises(ValueError, match="w"):
        wb.estimate_illuminant(img, img, w)


@pytest.mark.parametrize("w", [1, 1.0, 2.5, 4])
def test_w_inside_1_to_4_is_accepted(w):
    assert wb.one_minus_chroma(np.ones((2, 2, 3)), w).shape == (2, 2)


def test_one_minus_chroma_extremes_and_w():
    """Brightest neutral pixel → 1; most chromatic pixel → 0; a dark neutral pixel → (L/Lmax)^w;
    black → 0; larger w only lowers the weights below 1."""
    cwni = np.zeros((2, 3, 3))
    cwni[0, 0] = E                              # bright, neutral (the white object)
    cwni[0, 1] = _XYZ((0.64, 0.33), 0.2)        # saturated red
    cwni[0, 2] = _XYZ((0.30, 0.60), 0.5)        # saturated green
    cwni[1, 0] = 0.2 * E                        # dark neutral
    cwni[1, 1] = 0.0                            # black
    cwni[1, 2] = _XYZ((0.36, 0.35), 0.8)        # slightly warm, bright
    g1 = wb.one_minus_chroma(cwni, 1.0)
    g2 = wb.one_minus_chroma(cwni, 2.0)
    g4 = wb.one_minus_chroma(cwni, 4.0)
    assert g2[0, 0] == pytest.approx(1.0, abs=1e-9)
    most_chromatic = np.unravel_index(np.argmin(g1 + (cwni[..., 1] == 0)), g1.shape)
    assert g1[most_chromatic] == pytest.approx(0.0, abs=1e-12)
    assert g1[1, 1] == 0.0
    # dark neutral: chroma term 1 (C = Cmin = 0), L*(Y=0.2)/L*(Y=1) = 51.84/100
    L_dark = 116 * 0.2 ** (1 / 3) - 16
    assert g1[1, 0] == pytest.approx(L_dark / 100.0, rel=1e-6)
    np.testing.assert_allclose(g2, g1 ** 2, rtol=1e-12)
    assert np.all(g4 <= g2 + 1e-15) and np.all((g1 >= 0) & (g1 <= 1))
    # the slightly warm bright pixel keeps a high weight, the saturated ones do not
    assert g2[1, 2] > 0.5 > max(g2[0, 1], g2[0, 2])


def test_one_minus_chroma_degenerate_images():
    assert np.all(wb.one_minus_chroma(np.zeros((3, 3, 3))) == 0.0)
    flat = np.ones((3, 3, 3)) * _XYZ((0.5, 0.4))            # all equally chromatic
    np.testing.assert_allclose(wb.one_minus_chroma(flat), 1.0)


def test_bradford_maps_the_estimated_white_exactly_to_D65():
    d65 = wb.display_white_xy()
    for xy in (RED_LIGHT_XY, (0.25, 0.30), (0.31, 0.45)):
        src = _XYZ(xy, 7.0)
        out = wb.adapt_to_display(src, src)
        np.testing.assert_allclose(_xy(out), d65, atol=1e-12)
        assert out[1] == pytest.approx(7.0, rel=1e-12)
        # the same as colour-science's own entry point
        import colour

        ref = colour.chromatic_adaptation(src, _XYZ(xy), _XYZ(d65), method="Von Kries",
                                          transform="Bradford")
        np.testing.assert_allclose(out, ref, rtol=1e-12)
    # an image: per pixel the same matrix
    img = np.random.default_rng(1).uniform(0.1, 1.0, (4, 5, 3))
    out = wb.adapt_to_display(img, _XYZ(RED_LIGHT_XY))
    np.testing.assert_allclose(out[2, 3], wb.adapt_to_display(img[2, 3], _XYZ(RED_LIGHT_XY)))
    # D65 light: identity
    np.testing.assert_allclose(wb.adapt_to_display(img, _XYZ(d65)), img, rtol=1e-12)


def test_gray_world_means():
    img = np.zeros((2, 2, 3))
    img[0, 0] = [1, 2, 3]
    img[1, 1] = [3, 2, 1]
    np.testing.assert_allclose(wb.gray_world(img), [1.0, 1.0, 1.0])
    np.testing.assert_allclose(wb.gray_world(img, weights=[[1, 0], [0, 0]]), [1, 2, 3])
    with pytest.raises(ValueError, match="no light"):
        wb.gray_world_xy(np.zeros((2, 2, 3)))


def _mondrian():
    """A synthetic render: strongly coloured light, saturated green/blue walls, one white object.
    raw = reflectance colour × light; CWNI = reflectance under flat light; NWCI = neutral
    reflector under the light incident there (the white object gets the light's own colour,
    the walls also some green/blue bounce light)."""
    H, W = 20, 30
    light = _XYZ(RED_LIGHT_XY)
    green_refl, blue_refl = _XYZ((0.28, 0.55), 0.3), _XYZ((0.17, 0.10), 0.15)
    cwni = np.empty((H, W, 3))
    nwci = np.empty((H, W, 3))
    cwni[:, :15] = green_refl
    cwni[:, 15:] = blue_refl
    cwni[8:12, 12:18] = 0.8 * E                             # the white object
    bounce_green = 0.85 * light + 0.15 * _XYZ((0.30, 0.55))
    bounce_blue = 0.85 * light + 0.15 * _XYZ((0.22, 0.20))
    nwci[:, :15] = 0.5 * bounce_green
    nwci[:, 15:] = 0.5 * bounce_blue
    nwci[8:12, 12:18] = 0.8 * light
    # raw ≈ per-channel product in a von Kries sense (enough for a synthetic check)
    raw = cwni * nwci / E
    return raw, cwni, nwci, light


def test_ww_finds_the_light_on_the_white_object_gray_world_does_not():
    raw, cwni, nwci, _light = _mondrian()
    est = wb.estimate_illuminant(cwni, nwci, w=2.0)
    err_ww = np.linalg.norm(est.illuminant_xy - RED_LIGHT_XY)
    err_gw = np.linalg.norm(wb.gray_world_xy(raw) - RED_LIGHT_XY)
    assert err_ww < 0.01 < err_gw
    # NWCI alone (no 1−Chroma weights) is pulled by the bounce light on the walls
    assert np.linalg.norm(wb.gray_world_xy(nwci) - RED_LIGHT_XY) > 0.03
    assert est.one_minus_chroma.shape == (20, 30)
    np.testing.assert_allclose(est.nwci_multiplied, nwci * est.one_minus_chroma[..., None])
    # higher w is more selective: closer to the white object's light
    err_w1 = np.linalg.norm(wb.estimate_illuminant(cwni, nwci, w=1.0).illuminant_xy
                            - RED_LIGHT_XY)
    err_w4 = np.linalg.norm(wb.estimate_illuminant(cwni, nwci, w=4.0).illuminant_xy
                            - RED_LIGHT_XY)
    assert err_w4 < err_ww < err_w1


def test_spectral_inputs_and_white_balanced_preview():
    """Spectral images go through colour-science's CMFs: a flat light on a flat white is at E;
    the white-balanced preview of a white object under a coloured light is neutral."""
    from types import SimpleNamespace

    from normbox_lab.predict.render import planck_W_sr_m2_nm

    H, W = 4, 6
    light = planck_W_sr_m2_nm(WL, 2000.0)
    light = light / light.max() * 0.01                  # a warm (orange) light
    refl = np.full((H, W, WL.size), 0.8)
    refl[:, :3] *= np.where(WL > 600, 1.0, 0.1)         # a red wall on the left
    cwni = refl * float(np.mean(light))
    nwci = np.broadcast_to(0.8 * light, (H, W, WL.size)).copy()
    raw = refl * light
    xy_flat = wb.gray_world_xy(wb.as_XYZ(np.full((2, 2, WL.size), 0.01), WL))
    np.testing.assert_allclose(xy_flat, [1 / 3, 1 / 3], atol=2e-4)
    est = wb.estimate_illuminant(cwni, nwci, 2.0, wavelength_nm=WL)
    light_xy = _xy(wb.as_XYZ(light, WL))
    np.testing.assert_allclose(est.illuminant_xy, light_xy, atol=1e-9)
    img = SimpleNamespace(radiance=raw, cwni=cwni, nwci=nwci, wavelength_nm=WL)
    srgb = wb.white_balanced_srgb(img, white_Y=float(wb.as_XYZ(raw, WL)[..., 1].max()))
    assert srgb.shape == (H, W, 3)
    white_px = srgb[0, -1]
    assert np.ptp(white_px) < 0.01 and white_px.mean() > 0.9   # neutral and bright
    red_px = srgb[0, 0]
    assert red_px[0] > red_px[1] + 0.2                          # the red wall stays red
    with pytest.raises(ValueError, match="bands"):
        wb.as_XYZ(raw, WL[:-1])


def test_ww_on_a_rendered_box_lit_by_a_strongly_coloured_light():
    """The acceptance test, on the virtual camera's Cornell-like box: a 1800 K lamp
    (xy ≈ 0.549, 0.408: strongly orange), every wall, the floor and the ceiling strongly
    coloured (greens and teal), one flat white cube (ρ = 0.85).

    "The light on the white object" = the chromaticity of the raw radiance on the cube's lit
    face (its pixels whose surface faces the ceiling lamp, normal·z > 0.9): for a spectrally
    flat white that is the chromaticity of the light arriving there, lamp plus the green bounce
    light (≈ 0.02 from the lamp's own xy).  W&W (w = 2) lands within 0.01 of it; gray world on
    the raw image, pulled by the green walls, misses by more than 0.01."""
    from normbox_lab.images import cornell
    from normbox_lab.predict.render import planck_W_sr_m2_nm

    materials = wb.coloured_room_materials()
    lamp_wl = np.arange(360.0, 831.0, 5.0)
    lamp = planck_W_sr_m2_nm(lamp_wl, 1800.0)
    lamp = lamp / lamp.max() * 10.0
    img = cornell.render_cornell(materials, lamp_wl, lamp, width=96, height=72, spp=64, seed=1)

    raw = img.XYZ()
    lit = img.mask("box") & (img.normal[..., 2] > 0.9)
    assert lit.sum() >= 10
    target_xy = wb.gray_world_xy(raw[lit])
    lamp_xy = wb.gray_world_xy(wb.as_XYZ(lamp, lamp_wl))
    assert 0.005 < np.linalg.norm(target_xy - lamp_xy) < 0.04     # bounce light is there

    est = wb.estimate_illuminant(img.XYZ("cwni"), img.XYZ("nwci"), w=2.0)
    err_ww = float(np.linalg.norm(est.illuminant_xy - target_xy))
    err_gw = float(np.linalg.norm(wb.gray_world_xy(raw) - target_xy))
    assert err_ww < 0.01 < err_gw, (err_ww, err_gw)
    # the spectral path gives the same estimate
    est_s = wb.estimate_illuminant(img.cwni, img.nwci, 2.0, wavelength_nm=img.wavelength_nm)
    np.testing.assert_allclose(est_s.illuminant_xy, est.illuminant_xy, atol=1e-6)
    # after the Bradford transform the white object's lit face is (nearly) D65
    adapted = wb.adapt_to_display(raw, est.illuminant_XYZ)
    assert np.linalg.norm(wb.gray_world_xy(adapted[lit]) - wb.display_white_xy()) < 0.01
    srgb = wb.white_balanced_srgb(img)
    assert srgb.shape == (72, 96, 3) and np.all((srgb >= 0) & (srgb <= 1))
