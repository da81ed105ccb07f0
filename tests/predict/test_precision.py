"""One word for precision: the target relative standard error per band, one
statistic (the worst band), the quality names as its presets, the renderer chosen by name.

`normbox-lab predict --target-se 0.5%` under ``--renderer fast`` and ``--renderer mitsuba``:
both store the same target and the same statistic, and every configuration of both reaches it.
"""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.cli import main
from normbox_lab.core.types import BrdfReading, SpectralReading
from normbox_lab.predict import precision
from normbox_lab.predict.brdf_model import gonio_geometry
from normbox_lab.predict.materials import truth_brdf_inplane, truth_material

TARGET = 0.005


def test_the_target_parses_as_a_fraction_or_a_percentage():
    assert precision.parse_target_se("0.15%") == pytest.approx(0.0015)
    assert precision.parse_target_se(" 0.0015 ") == pytest.approx(0.0015)
    for bad in ("0", "100%", "-1%", "abc", "nan", "0.15 %%"):
        with pytest.raises(ValueError):
            precision.parse_target_se(bad)
    # the quality names are presets of the one quantity, defined once
    from normbox_lab.predict.fastrender import FAST_TARGET_REL_SE
    from normbox_lab.predict.render import QUALITIES
    from normbox_lab.sim.fast_world import TRUTH_REL_SE

    assert FAST_TARGET_REL_SE is precision.PRESETS and TRUTH_REL_SE is precision.PRESETS
    assert QUALITIES["default"].target_rel_se == precision.PRESETS["default"] == 0.0015
    assert precision.target_se("quick") == 0.02 and precision.target_se("high", 0.003) == 0.003


def test_the_statistic_is_the_worst_band():
    mean = np.array([1.0, 2.0, 1e-9, 4.0])
    se = np.array([0.01, 0.01, 1.0, 0.2])          # the third band has no signal
    assert precision.rel_se(mean, se) == pytest.approx(0.05)


def _store(path) -> int:
    """A store with the fits of patch 19 and the wall and a one-configuration reference run
    (patch 19 at 45°); returns the reference run's id."""
    from normbox_lab.analyze.pipeline import fit_run

    with Store(path) as store:
        run = store.create_run("brdf-inplane", status="running")
        wl = np.arange(380.0, 781.0, 5.0)
        ti, to = gonio_geometry()
        for name, which in (("p19", 19), ("wall", "wall")):
            f = truth_brdf_inplane(truth_material(which, "model"), ti, to, wl, 4.0)
            for k in range(ti.size):
                store.add_brdf(run.id, f"{name}/i{ti[k]:+.0f}/o{to[k]:+.0f}",
                               BrdfReading(float(ti[k]), float(to[k]), 4.0, wl, f[k]))
        store.set_run_status(run.id, "done")
        fit_run(store, run.id)
        ref = store.create_run("reference-sweep", status="running")
        wl1 = np.arange(380.0, 781.0, 1.0)
        store.add_spectral(ref.id, "a45/p19",
                           SpectralReading(wl1, np.full(wl1.size, 0.01), None, 1.0, 0.0, "x"),
                           {"patch": 19, "angle_deg": 45.0, "patch_name": "white"})
        store.set_run_status(ref.id, "done")
        return ref.id


@pytest.mark.parametrize("renderer", ["fast", "mitsuba"])
def test_target_se_gives_the_same_statistic_under_both_renderers(tmp_path, renderer, capsys):
    path = tmp_path / "s.sqlite"
    ref = _store(path)
    assert main(["predict", str(ref), "--store", str(path), "--target-se", "0.5%",
                 "--renderer", renderer, "--accept-flagged"]) == 0
    with Store(path) as store:
        pred = store.latest_artifact("prediction", f"ref-run-{ref}")
    md = pred.metadata
    assert md["target_rel_se"] == TARGET
    assert md["rel_se_statistic"] == precision.STATISTIC
    assert md["renderer"] == {"fast": "fastrender", "mitsuba": "mitsuba"}[renderer]
    reached = precision.rel_se(pred.arrays["radiance"][0, 0], pred.arrays["std_error"][0, 0])
    print(f"{renderer}: worst band relative SE {100 * reached:.3f} % (target 0.5 %)")
    assert 0.0 < reached <= TARGET


def test_the_executor_does_not_choose_the_renderer(tmp_path, capsys):
    path = tmp_path / "s.sqlite"
    ref = _store(path)
    assert main(["predict", str(ref), "--store", str(path), "--renderer", "mitsuba",
                 "--executor", "inprocess"]) == 2
    assert "--executor runs the fast renderer's jobs" in capsys.readouterr().err
    with Store(path) as store:
        assert store.artifacts("prediction") == []
