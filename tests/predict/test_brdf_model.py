"""The fit model: reciprocity, energy, Fresnel, GGX normalisation, geometry convention, storage."""

import numpy as np
import pytest
from scipy import integrate

from normbox_lab.acquire.store import Store
from normbox_lab.predict.brdf_model import (
    MaterialFit,
    ct_ggx_brdf,
    fresnel_cook_torrance,
    ggx_d,
    gonio_geometry,
    inplane_directions,
    smith_g1,
    specular_basis,
)


def _random_upper(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _hemisphere_grid(n_theta=400, n_phi=400):
    th = (np.arange(n_theta) + 0.5) * (np.pi / 2) / n_theta
    ph = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    T, P = np.meshgrid(th, ph, indexing="ij")
    w = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1)
    dw = np.sin(T) * (np.pi / 2 / n_theta) * (2 * np.pi / n_phi)
    return w, dw


def test_reciprocity():
    rng = np.random.default_rng(1)
    wi, wo = _random_upper(rng, 500), _random_upper(rng, 500)
    kd, ks = np.array([0.2, 0.7]), np.array([0.5, 0.1])
    f1 = ct_ggx_brdf(wi, wo, kd, ks, 0.3, 1.6, 0.01)
    f2 = ct_ggx_brdf(wo, wi, kd, ks, 0.3, 1.6, 0.01)
    assert f1.shape == (500, 2)
    np.testing.assert_allclose(f1, f2, rtol=1e-12, atol=1e-14)


def test_fresnel_normal_incidence_and_grazing():
    for eta in (1.2, 1.5, 2.4):
        assert fresnel_cook_torrance(1.0, eta) == pytest.approx(((eta - 1) / (eta + 1)) ** 2,
                                                                rel=1e-12)
        assert fresnel_cook_torrance(0.0, eta) == pytest.approx(1.0, abs=1e-12)
    # monotone rise towards grazing for a dielectric
    f = fresnel_cook_torrance(np.cos(np.deg2rad(np.arange(0, 90, 5))), 1.5)
    assert np.all(np.diff(f) > -1e-12)
    # Brewster-free unpolarised value at 60° for η = 1.5 (textbook: 0.0892)
    assert fresnel_cook_torrance(0.5, 1.5) == pytest.approx(0.0892, abs=2e-4)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.6, 1.0])
def test_ggx_normalisation(alpha):
    val, _ = integrate.quad(lambda th: ggx_d(np.cos(th), alpha) * np.cos(th) * np.sin(th),
                            0.0, np.pi / 2, limit=400, points=[alpha / 4, alpha])
    assert 2 * np.pi * val == pytest.approx(1.0, rel=1e-6)


def test_smith_g1_limits():
    assert smith_g1(1.0, 0.5) == pytest.approx(1.0)
    assert smith_g1(np.cos(np.deg2rad(85.0)), 0.5) < smith_g1(np.cos(np.deg2rad(45.0)), 0.5) < 1
    assert smith_g1(-0.2, 0.5) == 0.0


def test_energy():
    w, dw = _hemisphere_grid()
    for ti in (0.0, 40.0, 70.0):
        wi, _ = inplane_directions(ti, 0.0, 0.0)
        wi = np.broadcast_to(wi, w.shape)
        # Lambertian part alone integrates to kd exactly
        lam = ct_ggx_brdf(wi, w, [1.0], [0.0], 0.3, 1.5, 0.0)[..., 0]
        assert np.sum(lam * w[..., 2] * dw) == pytest.approx(1.0, rel=1e-4)
        # the specular part with ks = 1 reflects at most everything (F <= 1, G <= 1)
        for alpha in (0.2, 0.5):
            spec = ct_ggx_brdf(wi, w, [0.0], [1.0], alpha, 1.5, 0.0)[..., 0]
            albedo = np.sum(spec * w[..., 2] * dw)
            assert 0.02 < albedo < 1.0
    # with η → large the Fresnel → 1 and the albedo of a smooth surface approaches 1 (near normal)
    wi, _ = inplane_directions(0.0, 0.0, 0.0)
    # (separable Smith G loses a little energy even then: ~0.3 % at α = 0.05)
    spec = ct_ggx_brdf(np.broadcast_to(wi, w.shape), w, [0.0], [1.0], 0.05, 1e4, 0.0)[..., 0]
    albedo = np.sum(spec * w[..., 2] * dw)
    assert 0.99 < albedo <= 1.0


def test_inplane_convention_specular_at_minus_theta_i():
    th_o = np.arange(-80.0, 81.0, 1.0)
    wi, wo = inplane_directions(-30.0, th_o, 0.0)
    s = specular_basis(wi, wo, 0.1, 1.5)
    assert th_o[np.argmax(s)] == 30.0
    wi, wo = inplane_directions(-30.0, -30.0, 4.0)
    assert np.linalg.norm(wi, axis=-1) == pytest.approx(1.0)
    assert wi[1] > 0 > wo[1]
    assert np.degrees(np.arccos(np.dot(wi, wo))) == pytest.approx(8.0, abs=1e-9)
    ti, to = gonio_geometry()
    assert ti.shape == to.shape == (153,)


def test_material_fit_store_roundtrip(tmp_path):
    fit = MaterialFit("patch01", np.arange(380.0, 781.0, 1.0), np.full(401, 0.3),
                      np.linspace(0.0, 0.1, 401), 0.25, 1.55, 0.002, 6.5, 2.0, cost=0.1)
    with Store(tmp_path / "s.sqlite") as st:
        fit.store(st)
        back = MaterialFit.from_artifact(st.latest_artifact("fit", "patch01"))
    assert back.alpha == 0.25 and back.eta == 1.55 and back.c == 0.002 and back.w == 2.0
    np.testing.assert_array_equal(back.ks, fit.ks)
    wi, wo = inplane_directions(-20.0, 50.0)
    np.testing.assert_allclose(back.brdf(wi, wo), fit.brdf(wi, wo))
