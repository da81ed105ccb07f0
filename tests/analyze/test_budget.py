"""The error budget's propagation on synthetic inputs (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.analyze.budget import BudgetInputs, compute_budget, errors_for_run
from normbox_lab.core.error_sources import PAPER_FIGURES, parse_error_spec
from normbox_lab.core.errors import ConfigError

WL = np.arange(380.0, 781.0, 1.0)
ANGLES = np.arange(30.0, 91.0, 15.0)


def inputs(n_patches=5):
    rng = np.random.default_rng(1)
    shape = 1.0 + 0.3 * np.sin(WL / 60.0)
    level = rng.uniform(0.5, 2.0, (n_patches, 1, 1)) * np.cos(np.radians(ANGLES))[None, :, None]
    R = level * shape + 0.05
    P = R * 1.01
    D = -0.02 * R                       # 2 % per degree
    return BudgetInputs(WL, ANGLES, list(range(1, n_patches + 1)), R, P, R * 1e-4, D,
                        {}, None, np.full(R.shape, 0.03), 0)


def test_gain_sources_contribute_their_rms():
    x = inputs()
    b = compute_budget(x, parse_error_spec("cs1000=0.02,lamp=+0.01"), n_draws=100)
    # a gain u gives NRMSE = u · RMS(R) / mean(R)
    shape = np.sqrt(np.mean(x.reference ** 2, axis=-1)) / np.mean(x.reference, axis=-1)
    cs = b.nrmse[b.sources.index("cs1000")]
    assert np.allclose(cs, 0.02 / np.sqrt(3) * shape, rtol=0.15)
    assert np.allclose(b.nrmse[b.sources.index("lamp")], 0.01 * shape, rtol=1e-9)
    assert np.allclose(b.nrmse[b.sources.index("fit")], 0.03 * shape, rtol=1e-9)
    assert "angle" not in b.sources and "geometry" not in b.sources      # off or no inputs


def b_ref(_b):
    return inputs().reference


def test_angle_offset_through_the_derivative():
    b = compute_budget(inputs(), parse_error_spec("angle-offset=60:+0.5"), n_draws=8)
    c = b.nrmse[b.sources.index("angle-offset")]
    shape = np.sqrt(np.mean(b_ref(b) ** 2, axis=-1)) / np.mean(b_ref(b), axis=-1)
    assert np.allclose(c[:, 2], 0.5 * 0.02 * shape[:, 2], rtol=1e-9)
    assert np.all(c[:, [0, 1, 3, 4]] == 0)


def test_total_intervals_significance():
    x = inputs()
    b = compute_budget(x, parse_error_spec("cs1000=0.02,lamp=+0.01"), n_draws=100)
    # fixed sources add coherently with the fit error (+1 % lamp and +3 % fit: ~4 %)
    assert np.all(b.total_nrmse > 0.035)
    lo, hi = b.observed_nrmse_ci
    assert np.all(lo <= b.observed_nrmse) and np.all(b.observed_nrmse <= hi)
    assert not b.significant_nrmse.any()      # a 1 % difference is within the instruments
    x.prediction = x.reference * 1.10
    b = compute_budget(x, parse_error_spec("cs1000=0.02"), n_draws=100)
    assert b.significant_nrmse.all() and b.significant_delta_e00.any()
    assert "total" in b.table() and "observed" in b.table()
    assert np.allclose(b.share_by_angle().sum(axis=0), 1.0)


def test_distributions_for_a_run():
    assert errors_for_run("", None) == parse_error_spec(PAPER_FIGURES)
    run_cfg = '[render]\nerrors = "cs1000=0.01"\n'
    assert errors_for_run(run_cfg, None).on_names() == ["cs1000"]
    only = errors_for_run("", "angle-sweep,cs1000")
    assert only.on_names() == ["angle-sweep", "cs1000"]
    assert only.cs1000_gain == parse_error_spec(PAPER_FIGURES).cs1000_gain
    assert errors_for_run("", "lamp=+0.02").on_names() == ["lamp"]
    with pytest.raises(ConfigError, match="errors.bogus"):
        errors_for_run("", "bogus,cs1000")


def test_budget_section_of_the_report(tmp_path):
    from normbox_lab.analyze.angles import estimate_angle_offsets
    from normbox_lab.analyze.report import ReportData, write_report

    x = inputs()
    off = estimate_angle_offsets(x.reference, x.prediction, x.d_angle, x.angle_deg)
    b = compute_budget(x, parse_error_spec("cs1000=0.02,angle-offset=60:+0.5"), n_draws=16,
                       angle_offsets=off)
    html = write_report(tmp_path / "r.html",
                        ReportData(budget=(b.to_arrays(), b.sources))).read_text()
    assert "id='fig-budget'" in html or 'id="fig-budget"' in html
    assert "tab-budget" in html and "angle-offset" in html and "cs1000" in html


def test_render_term_takes_the_truths_achieved_noise():
    """The truth rendered to a stated 1 % that it beat (0.3 % achieved): with `truth_se` the
    render term is the achieved noise with the prediction's, not the stated 1 %."""
    x = inputs()
    x.prediction_se = 0.001 * x.reference
    x.truth_rel_se = 0.01
    x.render_noise_correlated = True
    shape = np.sqrt(np.mean(x.reference ** 2, axis=-1)) / np.mean(x.reference, axis=-1)
    stated = compute_budget(x, parse_error_spec("off"), sources=("render",), n_draws=2000,
                            significance_draws=64)
    x.truth_se = 0.003 * x.reference
    achieved = compute_budget(x, parse_error_spec("off"), sources=("render",), n_draws=2000,
                              significance_draws=64)
    # one normal draw per configuration for all bands: the RMS over draws is the SE's RMS
    assert np.allclose(achieved.nrmse[0], np.hypot(0.003, 0.001) * shape, rtol=0.08)
    assert np.all(stated.nrmse[0] > 2.5 * achieved.nrmse[0])


def test_significance_marks_a_model_the_sources_explain_5_percent_of_the_time():
    """The observed difference drawn from the very sources the budget propagates (±2 %
    radiometer gain per reading): the marks must come at the nominal 5 % — the 95th
    percentile of 1024 draws, not of 64 (6-7 %)."""
    from scipy.stats import binomtest

    errors = parse_error_spec("cs1000=0.02")
    marks, n = 0, 0
    for c in range(8):
        x = inputs(n_patches=10)
        rng = np.random.default_rng(100 + c)
        gain = rng.uniform(-0.02, 0.02, x.reference.shape[:2])[..., None]
        x.prediction = x.reference * (1.0 + gain)
        b = compute_budget(x, errors, n_draws=8, seed=c)
        marks += int(b.significant_nrmse.sum())
        n += b.significant_nrmse.size
    ci = binomtest(marks, n).proportion_ci(0.95)
    assert ci.low <= 0.05 <= ci.high, (marks, n, ci)


def test_every_fast_renderer_label_is_the_fast_renderer():
    """The demo's predictions are labelled by the estimator that made them ("fastrender-qmc"
    since one configuration is rendered by randomised QMC): each is band-correlated noise at
    the fast renderer's target.  Matching "fastrender" alone left the render term independent
    per band and scaled to the stated target (36 of 264 null configurations marked)."""
    from normbox_lab.analyze.budget_store import _prediction_target, is_fast_renderer

    for label in ("fastrender", "fastrender-qmc", "fastrender-patchset"):
        assert is_fast_renderer({"renderer": label})
        assert _prediction_target({"renderer": label, "quality": "default"}) == 0.0015
    for label in ("mitsuba", "stock", "imported"):
        assert not is_fast_renderer({"renderer": label})
        assert _prediction_target({"renderer": label, "quality": "default"}) == 0.0
    assert not is_fast_renderer({})
