"""The fit's inner (kd, ks) solve: the batched step halving is the one-at-a-time halving, and
the inner optimum is the per-wavelength log-cost optimum (no feasible point nearby is lower)."""

import numpy as np

from normbox_lab.analyze.fit import BrdfData, FitProblem
from normbox_lab.predict.brdf_model import ct_ggx_brdf, gonio_geometry, inplane_directions

WL = np.arange(380.0, 781.0, 5.0)
TI, TO = gonio_geometry()
WI, WO = inplane_directions(TI, TO, 4.0)


def _noisy_problem(seed: int = 5) -> FitProblem:
    rng = np.random.default_rng(seed)
    kd = 0.05 + 0.6 * np.exp(-((WL - 560.0) / 50.0) ** 2)
    ks = 0.04 + 0.02 * np.cos(WL / 40.0)
    y = ct_ggx_brdf(WI, WO, kd, ks, 0.3, 1.5, 0.0)
    y = y * (1.0 + 0.02 * rng.standard_normal(y.shape))
    y[TI == TO] = np.nan                            # blocked geometries
    return FitProblem(BrdfData("m", TI, TO, WL, y, 4.0), 2.0)


def _halved_one_at_a_time(p, kd, ks, n_kd, n_ks, new_cost, cost, b, c):
    """The halving as the fit did it before: all wavelengths, one halving after another."""
    for _ in range(8):
        worse = new_cost > cost
        if not worse.any():
            break
        n_kd = np.where(worse, 0.5 * (kd + n_kd), n_kd)
        n_ks = np.where(worse, 0.5 * (ks + n_ks), n_ks)
        new_cost = p._cost_per_wl(n_kd, n_ks, b, c)
    return n_kd, n_ks, new_cost


def test_batched_halving_is_the_one_at_a_time_halving_bit_for_bit():
    p = _noisy_problem()
    b = p.basis(0.3, 1.5)
    kd, ks = p.inner(0.3, 1.5, 0.0)
    cost = p._cost_per_wl(kd, ks, b, 0.0)
    rng = np.random.default_rng(11)
    for scale in (1e-9, 1e-3, 0.3, 3.0):            # rounding-level steps to far overshoots
        n_kd = np.maximum(kd + scale * rng.standard_normal(kd.size), 0.0)
        n_ks = np.maximum(ks + scale * rng.standard_normal(ks.size), 0.0)
        new_cost = p._cost_per_wl(n_kd, n_ks, b, 0.0)
        want = _halved_one_at_a_time(p, kd, ks, n_kd, n_ks, new_cost, cost, b, 0.0)
        worse = np.flatnonzero(new_cost > cost)
        assert worse.size > 0
        got_kd, got_ks, got_cost = n_kd.copy(), n_ks.copy(), new_cost.copy()
        p._halve(kd, ks, got_kd, got_ks, got_cost, cost, worse, b, 0.0)
        np.testing.assert_array_equal(got_kd, want[0])
        np.testing.assert_array_equal(got_ks, want[1])
        np.testing.assert_array_equal(got_cost, want[2])


def test_inner_optimum_is_not_beaten_by_any_nearby_feasible_point():
    p = _noisy_problem()
    b = p.basis(0.3, 1.5)
    kd, ks = p.inner(0.3, 1.5, 0.0)
    assert np.all(kd >= 0) and np.all(ks >= 0)
    best = p._cost_per_wl(kd, ks, b, 0.0)
    for dkd, dks in [(1e-5, 0), (-1e-5, 0), (0, 1e-5), (0, -1e-5), (1e-5, -1e-5),
                     (-1e-5, 1e-5)]:
        other = p._cost_per_wl(np.maximum(kd + dkd, 0.0), np.maximum(ks + dks, 0.0), b, 0.0)
        assert np.all(other >= best * (1.0 - 1e-12))
    # the cost kept with q and the residuals is the cost computed afresh
    cost, _q, r = p._cost_q_r(kd, ks, b, 0.0)
    np.testing.assert_array_equal(cost, best)
    np.testing.assert_array_equal(r, p.residuals(kd, ks, 0.3, 1.5, 0.0))
