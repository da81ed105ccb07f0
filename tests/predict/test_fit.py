"""Fit closure: data from the model itself on the tilted 153-geometry gonio set are recovered."""

import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.analyze.fit import (
    BrdfData,
    FitProblem,
    _nnls2,
    fit_cost,
    fit_error_pct,
    fit_material,
    polar_plot,
    relative_error,
)
from normbox_lab.analyze.pipeline import fit_run
from normbox_lab.core.types import BrdfReading
from normbox_lab.predict.brdf_model import (
    MaterialFit,
    ct_ggx_brdf,
    gonio_geometry,
    inplane_directions,
)

WL = np.arange(380.0, 781.0, 5.0)          # 81 bands keep the tests quick
TI, TO = gonio_geometry()
WI, WO = inplane_directions(TI, TO, 4.0)


def _spectra():
    kd = 0.05 + 0.6 * np.exp(-((WL - 560.0) / 50.0) ** 2)
    ks = 0.04 + 0.02 * np.cos(WL / 40.0)
    return kd, ks


def _data(y, name="m"):
    return BrdfData(name, TI, TO, WL, y, 4.0)


def test_nnls2_matches_bruteforce():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(50, 2, 2))
    m = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(2)
    v = rng.normal(size=(50, 2))
    x0, x1 = _nnls2(m[:, 0, 0], m[:, 0, 1], m[:, 1, 1], v[:, 0], v[:, 1])
    g = np.linspace(0, 5, 501)
    G0, G1 = np.meshgrid(g, g, indexing="ij")
    for k in range(50):
        obj = 0.5 * (m[k, 0, 0] * G0**2 + 2 * m[k, 0, 1] * G0 * G1 + m[k, 1, 1] * G1**2) \
            - v[k, 0] * G0 - v[k, 1] * G1
        ours = 0.5 * (m[k, 0, 0] * x0[k]**2 + 2 * m[k, 0, 1] * x0[k] * x1[k]
                      + m[k, 1, 1] * x1[k]**2) - v[k, 0] * x0[k] - v[k, 1] * x1[k]
        assert x0[k] >= 0 and x1[k] >= 0
        assert ours <= obj.min() + 1e-9


def test_closure_exact_recovers_all_parameters():
    kd, ks = _spectra()
    kd = np.where(WL > 680.0, 0.0, kd)          # a zero band makes c identifiable
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.22, 1.62, 0.004)
    fit = fit_material(_data(y), w=2.0)
    assert fit.alpha == pytest.approx(0.22, rel=1e-6)
    assert fit.eta == pytest.approx(1.62, rel=1e-6)
    assert fit.c == pytest.approx(0.004, abs=1e-8)
    np.testing.assert_allclose(fit.kd, kd, atol=1e-7)
    np.testing.assert_allclose(fit.ks, ks, atol=1e-7)
    assert fit.fit_error_pct < 1e-5
    assert fit.cost < 1e-20


def test_c_is_made_canonical_when_kd_can_absorb_it():
    kd, ks = _spectra()                          # min kd > 0: only kd/π − c is determined
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.4, 1.5, 0.005)
    fit = fit_material(_data(y))
    assert fit.c == 0.0
    np.testing.assert_allclose(fit.kd, kd - np.pi * 0.005, atol=1e-7)
    assert fit.fit_error_pct < 1e-5


def test_noise_gives_error_at_noise_level_and_nans_are_skipped():
    kd, ks = _spectra()
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.3, 1.5, 0.0)
    rng = np.random.default_rng(7)
    noisy = y * (1.0 + 0.02 * rng.normal(size=y.shape))
    noisy[[0, 40, 100], :] = np.nan               # blocked geometries
    noisy[5, 10] = np.nan
    fit = fit_material(_data(noisy))
    assert 1.8 < fit.fit_error_pct < 2.2
    assert fit.alpha == pytest.approx(0.3, rel=0.03)
    assert np.isfinite(fit.kd).all() and np.isfinite(fit.ks).all()
    assert np.isnan(relative_error(fit, _data(noisy))[40]).all()


def test_w_changes_the_weighting():
    # truth outside the family (a backscatter lobe near θo = θi): the fit must compromise
    kd, ks = _spectra()
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.3, 1.5, 0.0)
    back = 0.08 * np.exp(-((TO - TI) / 15.0) ** 2)[:, None] * (kd / kd.max())
    data = _data(y + back)
    p4 = FitProblem(data, 4.0)
    np.testing.assert_allclose(p4.mu[:, 0], np.clip(WI[:, 2], 0, 1) ** 4)
    f1, f4 = fit_material(data, w=1.0), fit_material(data, w=4.0)
    assert (f1.alpha, f1.eta) != pytest.approx((f4.alpha, f4.eta), rel=1e-3)
    near = np.abs(TI) <= 20.0
    grazing = np.abs(TI) >= 60.0
    assert fit_error_pct(f4, data, near) < fit_error_pct(f1, data, near)
    assert fit_error_pct(f1, data, grazing) < fit_error_pct(f4, data, grazing)
    # each fit is optimal for its own cost
    assert fit_cost(f4, data, 4.0) <= fit_cost(f1, data, 4.0)
    assert fit_cost(f1, data, 1.0) <= fit_cost(f4, data, 1.0)


def test_polar_plot_figure():
    kd, ks = _spectra()
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.3, 1.5, 0.0)
    fit = MaterialFit("m", WL, kd, ks, 0.3, 1.5, 0.0, 0.0, 2.0)
    fig = polar_plot(_data(y), {"ours": fit}, 730.0)
    assert len(fig.axes) == 9
    assert len(fig.axes[0].lines) >= 3          # measured, fit, light marker


def test_fit_store_run_writes_artifacts(tmp_path):
    kd, ks = _spectra()
    wl = WL[::4]
    y = ct_ggx_brdf(WI, WO, kd[::4], ks[::4], 0.3, 1.5, 0.0)
    with Store(tmp_path / "s.sqlite") as st:
        run = st.create_run("brdf-inplane")
        for g in range(TI.size):
            st.add_brdf(run.id, f"wall/{g}", BrdfReading(TI[g], TO[g], 4.0, wl, y[g],
                                                         blocked=(g == 3)))
        fits = fit_run(st, run.id, w=2.0)
        back = MaterialFit.from_artifact(st.latest_artifact("fit", "wall"))
    assert list(fits) == ["wall"]
    assert back.alpha == pytest.approx(0.3, rel=1e-5)
    assert back.w == 2.0 and back.fit_error_pct < 1e-4


def test_fit_error_at_does_not_alternate_between_on_grid_and_between_grid_angles():
    """The error model's fit term at the direct-light geometry (θi = −s, θo = 90 − s): at
    s = 30°, 40°… that is a gonio grid point, at 35°, 45°… the middle of four.  Nearest samples
    only (kernel 0) give one noisy sample against the mean of four, so the term alternates by
    about 2× between adjacent angles; the Gaussian kernel weighs both alike."""
    from normbox_lab.analyze.compare import direct_light_geometry
    from normbox_lab.analyze.fit import BrdfData, fit_error_at, fit_material
    from normbox_lab.core.error_sources import parse_error_spec
    from normbox_lab.predict.brdf_model import gonio_geometry
    from normbox_lab.predict.materials import truth_brdf_inplane, truth_material

    noise = parse_error_spec("qepro-snr=1000")
    ti, to = gonio_geometry()
    angles = np.arange(30.0, 91.0, 5.0)
    a_i, a_o = direct_light_geometry(angles)
    terms = {0.0: [], 7.0: []}
    for p in (7, 19):
        f = truth_brdf_inplane(truth_material(p, "model"), ti, to, WL, 4.0)
        f = np.array([noise.gonio(f[k], (p, k)) for k in range(ti.size)])
        data = BrdfData.from_readings(f"p{p:02d}", [
            BrdfReading(float(ti[k]), float(to[k]), 4.0, WL, f[k]) for k in range(ti.size)])
        fit = fit_material(data, 2.0)
        for kernel, rows in terms.items():
            rows.append([np.sqrt(np.nanmean(fit_error_at(
                fit, data, float(i), float(o), kernel_deg=kernel) ** 2))
                for i, o in zip(a_i, a_o)])
    nearest, smooth = (np.mean(terms[k], axis=0)[:8] for k in (0.0, 7.0))   # 30…65°
    on_grid, between = slice(0, None, 2), slice(1, None, 2)
    assert np.mean(nearest[on_grid]) > 1.6 * np.mean(nearest[between]), nearest
    ratio = np.mean(smooth[on_grid]) / np.mean(smooth[between])
    assert 0.8 < ratio < 1.25, smooth
