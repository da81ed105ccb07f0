"""Angle-misadjustment detection (one offset per sweep angle, shared by all patches)."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.analyze.angles import estimate_angle_offsets, finite_difference_derivative
from normbox_lab.sim.analytic_world import AnalyticWorld

ANGLES = np.arange(30.0, 91.0, 5.0)
INJECTED = {65.0: 0.7, 80.0: -0.7}


def sweep(offsets, *, gain=0.0, noise=0.002, seed=0):
    """The analytic world's reference sweep with misadjusted angles, its prediction at the
    nominal angles, and the prediction's angle derivative (central differences)."""
    world = AnalyticWorld()
    rng = np.random.default_rng(seed)

    def radiance(angle):
        return np.array([world.radiance_at(p, angle) for p in range(1, 25)])
    P = np.stack([radiance(a) for a in ANGLES], axis=1)
    D = finite_difference_derivative(radiance, ANGLES)
    R = np.stack([radiance(a + offsets.get(a, 0.0)) for a in ANGLES], axis=1)
    R = R * (1 + rng.normal(0, noise, R.shape))
    R = R * (1 + rng.uniform(-gain, gain, R.shape[:2]))[..., None]
    return R, P, D


def test_recovers_the_65_and_80_degree_misadjustment():
    est = estimate_angle_offsets(*sweep(INJECTED), ANGLES)
    for a, o, ci, _ in est.rows():
        expect = INJECTED.get(a, 0.0)
        assert abs(o - expect) <= 0.2, (a, o)
        if a not in INJECTED:
            assert abs(o) <= 0.2
    sig = dict(zip(est.angle_deg, est.significant()))
    assert sig[65.0] and sig[80.0]


def test_no_misadjustment_no_offset():
    est = estimate_angle_offsets(*sweep({}), ANGLES)
    assert np.max(np.abs(est.offset_deg)) < 0.05


def test_intervals_carry_the_radiometer_gain_noise():
    """±2 % gain per reading: the jackknife intervals grow where ∂L/∂s is small (30°) and still
    cover the truth; the two misadjusted angles stay significant."""
    quiet = estimate_angle_offsets(*sweep(INJECTED), ANGLES)
    noisy = estimate_angle_offsets(*sweep(INJECTED, gain=0.02, seed=3), ANGLES)
    assert np.all(noisy.ci95_deg > 5 * quiet.ci95_deg)
    assert noisy.ci95_deg[0] > noisy.ci95_deg[-2]
    truth = np.array([INJECTED.get(a, 0.0) for a in ANGLES])
    assert np.mean(np.abs(noisy.offset_deg - truth) <= noisy.ci95_deg) >= 0.8
    assert noisy.significant()[list(ANGLES).index(65.0)]
    assert noisy.significant()[list(ANGLES).index(80.0)]


def test_shapes_are_checked():
    R, P, D = sweep({})
    with pytest.raises(ValueError, match="patch"):
        estimate_angle_offsets(R, P, D[:, :-1], ANGLES)


def test_the_paper_spec_gives_the_papers_nse_pattern():
    """The paper (§6.3.5): its NSE, (reference − prediction) / reference, is slightly higher at
    65° and slightly lower at 80° than at the neighbouring angles, for every patch.  The paper
    spec's offsets must produce exactly that sign in the paper's convention."""
    from normbox_lab.core.error_sources import PAPER_SPEC, parse_error_spec

    offsets = parse_error_spec(PAPER_SPEC).angle_offset_deg
    R, P, _ = sweep(offsets, noise=0.0)
    nse_paper = ((R - P) / R).mean(axis=-1)                      # [patch, angle]
    for a, sign in ((65.0, +1), (80.0, -1)):
        i = list(ANGLES).index(a)
        dev = nse_paper[:, i] - 0.5 * (nse_paper[:, i - 1] + nse_paper[:, i + 1])
        assert np.all(sign * dev > 0), (a, dev)
        assert np.all(np.abs(dev) < 0.03), (a, dev)            # "slightly"


# --- the null test: no misadjustment, errors common to all patches at one angle ---------------
#: a relative error pattern over (angle, λ) that every patch shares and that is not smooth in
#: the angle (as a panel map that is off, or a box length, leaves it): per campaign, u times it
COMMON_PATTERN_REL = 0.004 * np.sin(1.7 * ANGLES[:, None] ** 1.3 / 10.0) * np.ones((1, 401))


_NOMINAL: dict = {}


def nominal():
    """The analytic world's prediction and its angle derivative, computed once."""
    if not _NOMINAL:
        world = AnalyticWorld()

        def radiance(angle):
            return np.array([world.radiance_at(p, angle) for p in range(1, 25)])
        _NOMINAL["P"] = np.stack([radiance(a) for a in ANGLES], axis=1)
        _NOMINAL["D"] = finite_difference_derivative(radiance, ANGLES)
    return _NOMINAL["P"], _NOMINAL["D"]


def null_campaign(rng, *, noise=0.002, gain=0.01):
    """One campaign without any misadjustment: the common error drawn, per-reading radiometer
    gain and band noise; and draws of the common error for the interval."""
    P, D = nominal()
    u = rng.uniform(-1.0, 1.0)
    R = P * (1 + u * COMMON_PATTERN_REL[None])
    R = R * (1 + rng.uniform(-gain, gain, R.shape[:2]))[..., None]
    R = R * (1 + rng.normal(0, noise, R.shape))
    draws = rng.uniform(-1.0, 1.0, (32, 1, 1, 1)) * COMMON_PATTERN_REL[None, None] * P[None]
    return R, P, D, draws


def test_null_campaigns_raise_at_most_5_percent_false_alarms_per_angle():
    """100 independent campaigns, no misadjustment: with the common errors' draws in the
    interval, the false-alarm rate is at most 5 % pooled over the angles, and at every angle
    within the binomial scatter of 5 % (99 % quantile); the jackknife over patches alone (the
    interval before) flags the common pattern as offsets in a third of the cases and more."""
    from scipy.stats import binom

    rng = np.random.default_rng(2026)
    n, n_alone = 100, 20
    with_common = np.zeros(ANGLES.size)
    jackknife_only = np.zeros(ANGLES.size)
    for k in range(n):
        R, P, D, draws = null_campaign(rng)
        with_common += estimate_angle_offsets(R, P, D, ANGLES, common=draws).significant()
        if k < n_alone:
            jackknife_only += estimate_angle_offsets(R, P, D, ANGLES).significant()
    assert np.sum(with_common) / (n * ANGLES.size) <= 0.05, with_common / n
    assert np.max(with_common) <= binom.ppf(0.99, n, 0.05), with_common / n
    assert np.mean(jackknife_only / n_alone) > 0.25, jackknife_only / n_alone


def test_common_errors_widen_the_interval_by_their_projection():
    rng = np.random.default_rng(5)
    R, P, D, draws = null_campaign(rng)
    plain = estimate_angle_offsets(R, P, D, ANGLES)
    wide = estimate_angle_offsets(R, P, D, ANGLES, common=draws)
    np.testing.assert_allclose(wide.offset_deg, plain.offset_deg)     # the estimate is the same
    np.testing.assert_allclose(wide.jackknife_sd_deg, plain.jackknife_sd_deg)
    assert np.all(wide.ci95_deg >= 1.96 * np.hypot(wide.jackknife_sd_deg, wide.common_rms_deg))
    assert np.all(wide.ci95_deg > plain.ci95_deg)
    # the common error's draws, pushed through the estimator one by one, give that RMS
    one = [estimate_angle_offsets(P + d, P, D, ANGLES).offset_deg for d in draws[:8]]
    direct = estimate_angle_offsets(P, P, D, ANGLES, common=draws[:8]).common_rms_deg
    np.testing.assert_allclose(direct, np.sqrt(np.mean(np.square(one), axis=0)), rtol=1e-9)
    with pytest.raises(ValueError, match="common draws"):
        estimate_angle_offsets(R, P, D, ANGLES, common=draws[:, :, :-1])
