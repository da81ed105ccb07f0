"""Comparison metrics and the error model: known inputs give known numbers."""

import colour
import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.analyze.compare import (
    ComparisonResult,
    compare,
    delta_e00,
    direct_light_geometry,
    direct_share,
    error_model,
    rate_delta_e,
    rating_index,
)

WL = np.arange(380.0, 781.0, 1.0)
ANG = np.arange(30.0, 91.0, 5.0)


def _reference():
    shape = colour.SpectralShape(380, 780, 1)
    refl = np.array([sd.copy().interpolate(shape).values for sd in
                     colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values()])
    lamp = 0.02 * (0.6 + 0.4 * (WL - 380.0) / 400.0)               # W sr⁻¹ m⁻² nm⁻¹
    falloff = np.cos(np.deg2rad(ANG - 30.0)) ** 2 + 0.05
    return refl[:, None, :] * falloff[None, :, None] * lamp[None, None, :]


def test_identical_spectra_give_zero_errors():
    ref = _reference()
    r = compare(ref, ref.copy(), WL, ANG)
    assert r.nse.shape == ref.shape and r.delta_e00.shape == (24, 13)
    assert np.all(r.nse == 0) and np.all(r.rmse == 0) and np.all(r.nrmse == 0)
    np.testing.assert_allclose(r.delta_e00, 0.0, atol=1e-9)
    assert r.rating_counts()["below JND"] == 24 * 13


def test_known_perturbations():
    ref = _reference()
    r = compare(ref, ref * 1.03, WL, ANG)
    np.testing.assert_allclose(r.nse, 0.03, rtol=1e-12)
    rms_over_mean = np.sqrt(np.mean(ref ** 2, -1)) / np.mean(ref, -1)
    np.testing.assert_allclose(r.nrmse, 0.03 * rms_over_mean, rtol=1e-12)
    flat = np.full((20, 13, WL.size), 0.01)
    flat[18] = 0.02                                           # brighter "white"
    r2 = compare(flat, flat + 0.0005, WL, ANG)
    np.testing.assert_allclose(r2.rmse, 0.0005, rtol=1e-9)
    np.testing.assert_allclose(r2.nrmse[0], 0.05, rtol=1e-9)
    np.testing.assert_allclose(r2.nrmse[18], 0.025, rtol=1e-9)
    # a uniform scale changes lightness only: ΔE00 > 0 and grows with the scale
    assert np.all(r.delta_e00 > 0)
    r3 = compare(ref, ref * 1.06, WL, ANG)
    assert np.all(r3.delta_e00 > r.delta_e00)


def test_delta_e00_against_colour_by_hand():
    ref = _reference()
    pred = ref.copy()
    pred[3, 4] *= 1.0 + 0.1 * np.sin(WL / 30.0)               # a spectral distortion
    r = compare(ref, pred, WL, ANG)
    # by hand, one spectrum at a time through colour's documented API
    # (the radiometer's 380–780 nm range: CMFs trimmed to it, no extrapolation of the data)
    shape = colour.SpectralShape(380, 780, 1)
    ill = colour.sd_ones(shape)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().trim(shape)

    def xyz(spec):
        return colour.sd_to_XYZ(colour.SpectralDistribution(spec, WL), cmfs, ill, k=1)

    y_white = xyz(ref[18, 0])[1]
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    lab_a = colour.XYZ_to_Lab(xyz(ref[3, 4]) / y_white, d65)
    lab_b = colour.XYZ_to_Lab(xyz(pred[3, 4]) / y_white, d65)
    expected = colour.delta_E(lab_a, lab_b, method="CIE 2000")
    assert expected > 0.5
    assert r.delta_e00[3, 4] == pytest.approx(expected, rel=1e-9)
    np.testing.assert_allclose(r.lab_reference[3, 4], lab_a, rtol=1e-9)
    assert r.delta_e00[3, 5] == pytest.approx(0.0, abs=1e-9)
    # white patch at 30° normalised to Y = 1 → L* = 100
    assert r.lab_reference[18, 0, 0] == pytest.approx(100.0, abs=1e-9)
    # Sharma, Wu & Dalal (2005) test pair 1: ΔE00 = 2.0425
    assert delta_e00(np.array([50.0, 2.6772, -79.7751]),
                     np.array([50.0, 0.0, -82.7485])) == pytest.approx(2.0425, abs=1e-4)


def test_rating_scale():
    assert rate_delta_e(0.5) == "below JND"
    assert rate_delta_e(1.0) == "below JND"
    assert rate_delta_e(1.5) == "just noticeable"
    assert rate_delta_e(3.0) == "discernible side by side"
    assert rate_delta_e(7.0) == "easily perceived"
    np.testing.assert_array_equal(rating_index([0.2, 1.2, 2.5, 9.0]), [0, 1, 2, 3])


def test_radiance_rmse_correlation():
    ref = _reference()
    pred = ref * 1.02                                          # RMSE ∝ radiance level
    r = compare(ref, pred, WL, ANG)
    assert r.correlations["radiance_rmse_small"] > 0.95
    assert r.correlations["radiance_rmse_large"] > 0.95
    # a constant absolute offset: RMSE flat, NRMSE ∝ 1/radiance → negative correlation
    r2 = compare(ref, ref + 1e-4, WL, ANG)
    assert r2.correlations["radiance_nrmse_large"] < -0.5


def test_error_model_arithmetic():
    d = np.array([1.0, 0.5, 0.0])
    em = error_model(d, 0.02, 0.10, [30.0, 60.0, 90.0])
    np.testing.assert_allclose(em.simulated_nrmse[0], [0.02, 0.06, 0.10])
    np.testing.assert_allclose(em.contribution_d[0], [0.02, 0.01, 0.0])
    np.testing.assert_allclose(em.contribution_i[0], [0.0, 0.05, 0.10])
    # spectral errors and a reference spectrum: NRMSE analogue weights by the radiance
    ref = np.ones((1, 3, 4)) * np.array([1.0, 1.0, 3.0, 3.0])
    err_i = np.array([0.0, 0.0, 0.1, 0.1])
    em2 = error_model(d, 0.0, err_i[None, None, :], [30.0, 60.0, 90.0], reference=ref,
                      observed_nrmse=np.array([[0.0, 0.1, 0.2]]))
    np.testing.assert_allclose(em2.simulated_nse[0, 1], [0.0, 0.0, 0.05, 0.05])
    expected = np.sqrt(np.mean((ref[0, 2] * err_i) ** 2)) / np.mean(ref[0, 2])
    assert em2.simulated_nrmse[0, 2] == pytest.approx(expected)
    assert em2.observed_nrmse.shape == (1, 3)


def test_direct_share_and_geometry():
    full = np.ones((2, 3, 5))
    share = direct_share(0.3 * full, full)
    np.testing.assert_allclose(share, 0.3)
    ti, to = direct_light_geometry([30.0, 45.0, 90.0])
    np.testing.assert_allclose(ti, [-30.0, -45.0, -90.0])
    np.testing.assert_allclose(to, [60.0, 45.0, 0.0])


def test_comparison_store_roundtrip(tmp_path):
    ref = _reference()
    r = compare(ref, ref * 1.01, WL, ANG, [f"p{k}" for k in range(24)])
    with Store(tmp_path / "s.sqlite") as st:
        r.store(st, "demo")
        back = ComparisonResult.from_artifact(st.latest_artifact("comparison", "demo"))
    np.testing.assert_array_equal(back.delta_e00, r.delta_e00)
    assert back.patch_names == r.patch_names
    assert back.correlations == pytest.approx(r.correlations)
