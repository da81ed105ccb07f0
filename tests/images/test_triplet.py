"""MIST wavelength-triplet rendering (Mitsuba RGB variant) against the spectral renderers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from normbox_lab.images.triplet import (
    bsdf_dict,
    check_representable,
    render_triplets,
)
from normbox_lab.predict.materials import truth_patch, truth_wall
from normbox_lab.predict.mitsuba_setup import in_variant, jit_variant

#: every third band of the spectral renderer's 380…780 nm grid (9 RGB renders per batch pair)
TEST_WAVELENGTHS_NM = np.arange(380.0, 781.0, 15.0)


def _z(triplet, spectral) -> np.ndarray:
    idx = np.searchsorted(spectral.wavelength_nm, triplet.wavelength_nm)
    assert np.allclose(spectral.wavelength_nm[idx], triplet.wavelength_nm)
    se = np.hypot(triplet.std_error, spectral.std_error[idx])
    return (triplet.radiance - spectral.radiance[idx]) / se


def _assert_agree(z: np.ndarray, *, chi2: bool = True) -> None:
    """|z| ≤ 4 in ≥ 99 % of the bands (here: all 27), and — when the bands' errors are nearly
    independent — mean z² like χ²/n of unit variance (SEs from 10 batches, and the three bands
    of one RGB render share paths, so the bounds are wide: [0.2, 3])."""
    assert np.mean(np.abs(z) <= 4.0) >= 0.99, np.round(z, 2)
    if chi2:
        assert 0.2 <= float(np.mean(z ** 2)) <= 3.0, np.round(z, 2)


def test_rgb_values_are_used_as_is():
    """In Mitsuba's RGB variant an `srgb` texture with unbounded=True (reflectance > 1) and an
    `rgb` emitter radiance (> 1) are plain channel values: no upsampling, no clamping."""
    import mitsuba as mi

    with in_variant(jit_variant("rgb")):
        T = mi.ScalarTransform4f
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": "path", "max_depth": 2},
            "sensor": {"type": "perspective", "fov": 1.0,
                       "to_world": T().look_at(origin=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 4, "height": 4, "pixel_format": "rgb",
                                "component_format": "float32", "rfilter": {"type": "box"}}},
            "plane": {"type": "rectangle",
                      "bsdf": {"type": "diffuse",
                               "reflectance": {"type": "srgb", "color": [1.2, 0.5, 2.0],
                                               "unbounded": True}}},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [3.0, 0.2, 7.5]}}})
        rgb = np.asarray(mi.render(scene, spp=256), dtype=np.float64).reshape(-1, 3)
    # a diffuse plane under a uniform sky: L = ρ · L_sky.  Every path carries the three channels
    # with one scalar weight, so the per-pixel ratio to ρ·L is the same in R, G and B (to float
    # rounding) and ≈ 1 on average (MC noise of the MIS estimate)
    ratio = rgb / np.array([1.2 * 3.0, 0.5 * 0.2, 2.0 * 7.5])
    np.testing.assert_allclose(ratio, ratio[:, :1].repeat(3, axis=1), rtol=1e-5)
    assert ratio.mean() == pytest.approx(1.0, abs=0.03)


def test_builtin_bsdf_is_the_model_family():
    """twosided(blendbsdf(diffuse 2kd, roughconductor 2ks)) evaluates the fit model, channel by
    channel, on both sides."""
    import mitsuba as mi

    from normbox_lab.predict.brdf_model import ct_ggx_brdf
    m = truth_patch(18, "model")                 # the smooth one: α = 0.15
    wl = np.array([450.0, 550.0, 650.0])
    kd, ks, _ = m.spectra_at(wl)
    with in_variant(jit_variant("rgb")):
        bsdf = mi.load_dict(bsdf_dict(m, wl))
        for theta_i, theta_o, phi in ((10, 20, 180), (40, 35, 180), (60, 10, 90), (25, 70, 200)):
            ti, to, ph = np.radians([theta_i, theta_o, phi])
            wi = np.array([np.sin(ti), 0.0, np.cos(ti)])
            wo = np.array([np.sin(to) * np.cos(ph), np.sin(to) * np.sin(ph), np.cos(to)])
            expected = ct_ggx_brdf(wi, wo, kd, ks, m.alpha, m.eta, 0.0) * wo[2]
            for side in (1.0, -1.0):              # front, and the back (twosided)
                si = mi.SurfaceInteraction3f()
                si.wi = mi.Vector3f(float(wi[0]), float(wi[1]), float(side * wi[2]))
                si.n = mi.Normal3f(0, 0, 1)
                si.sh_frame = mi.Frame3f(si.n)
                ctx = mi.BSDFContext()
                got = bsdf.eval(ctx, si, mi.Vector3f(float(wo[0]), float(wo[1]),
                                                     float(side * wo[2])))
                np.testing.assert_allclose(np.asarray(got).ravel(), expected, rtol=2e-4)


def test_refuses_what_builtins_cannot_represent():
    with pytest.raises(ValueError, match="c = "):
        check_representable(replace(truth_patch(1, "model"), c=0.01))
    with pytest.raises(ValueError, match="backscatter"):
        check_representable(truth_patch(1, "default"))
    with pytest.raises(ValueError, match="batches"):
        render_triplets(truth_patch(1, "model"), truth_wall("model"), 30.0, batches=1)


@pytest.fixture(scope="module")
def red_patch_30():
    """The red patch at 30° (direct light dominates): triplets, 27 bands, 10 batches."""
    patch, wall = truth_patch(15, "model"), truth_wall("model")
    trip = render_triplets(patch, wall, 30.0, wavelengths_nm=TEST_WAVELENGTHS_NM, spp=64,
                           batches=10, seed=1)
    return patch, wall, trip


def _spectral(patch, wall, angle_deg):
    from normbox_lab.predict.render import Quality, render_view

    return render_view(patch=patch, wall=wall, angle_deg=angle_deg, cache=False, seed=5,
                       quality=Quality("triplet-test", spp=1024, batches=30))


def test_triplets_agree_with_stock_spectral_render(red_patch_30):
    """Wavelength triplets in llvm_ad_rgb vs Mitsuba's spectral renderer with the project's
    NormboxBSDF, per 5 nm band, within Monte-Carlo error."""
    patch, wall, trip = red_patch_30
    spectral = _spectral(patch, wall, 30.0)
    assert trip.renders == 10 * 2 * 9
    assert np.all(trip.relative_std_error < 0.01)
    _assert_agree(_z(trip, spectral))
    # the comparison has power: a 1 % error on the spectral side is caught
    assert np.mean(_z(trip, spectral.scaled(1.01)) ** 2) > 10.0


def test_triplets_agree_with_band_vector_renderer(red_patch_30):
    """The same triplets against `fastrender` (its own BSDF code, wavelength jitter per path).
    fastrender feeds every band from the same paths, so its error is common to all bands: no
    χ² over bands, but every band within 4 σ, and a 1 % offset is caught."""
    from normbox_lab.predict.fastrender import FastNormbox

    patch, wall, trip = red_patch_30
    fast = FastNormbox().render_view(patch=patch, wall=wall, angle_deg=30.0, target_rel_se=0.002,
                                     seed=3)
    fast = _at(fast, TEST_WAVELENGTHS_NM)
    _assert_agree(trip.z_scores(fast), chi2=False)
    fast.radiance = fast.radiance * 1.01
    assert np.median(np.abs(trip.z_scores(fast))) > 3.0


def test_triplets_agree_indirect_light():
    """The smooth cyan patch at 75°: indirect light and long paths matter."""
    patch, wall = truth_patch(18, "model"), truth_wall("model")
    spectral = _spectral(patch, wall, 75.0)
    trip = render_triplets(patch, wall, 75.0, wavelengths_nm=TEST_WAVELENGTHS_NM, spp=64,
                           batches=10, seed=2)
    _assert_agree(_z(trip, spectral))


def _at(result, wavelength_nm):
    """A result restricted to some of its bands (same attribute names)."""
    from types import SimpleNamespace

    idx = np.searchsorted(result.wavelength_nm, wavelength_nm)
    return SimpleNamespace(wavelength_nm=result.wavelength_nm[idx],
                           radiance=result.radiance[idx], std_error=result.std_error[idx])
