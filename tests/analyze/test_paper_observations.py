"""The paper-scenario table (`normbox-lab budget`, the report): a quantity the runs did not
measure reads "not measured", never "nan"."""

import dataclasses

import numpy as np
from report_fixtures import synthetic_report_data

from normbox_lab.acquire.store import Store
from normbox_lab.analyze.budget_store import paper_observations


def _store(tmp_path, fit_names: dict[str, str]):
    data = synthetic_report_data(step_nm=20.0, seed=1)
    store = Store(tmp_path / "s.sqlite")
    run = store.create_run("reference-sweep", status="done")
    data.comparison.store(store, f"ref-run-{run.id}", run_ref=run.id)
    for stored, synthetic in fit_names.items():
        dataclasses.replace(data.fits[synthetic], name=stored).store(store)
    return store, run.id, data


def test_a_run_without_patch_18_or_the_wall_says_not_measured(tmp_path):
    # a gonio run of patches 1-3 only (no patch 18, no wall)
    store, run, data = _store(tmp_path, {"p01": "patch01", "p02": "patch02", "p03": "patch03"})
    rows = {name: ours for name, _, ours in paper_observations(store, run)}
    errs = [data.fits[f"patch0{k}"].fit_error_pct for k in (1, 2, 3)]
    assert rows["BRDF fit errors"] == (f"{min(errs):.1f}–{max(errs):.1f} %, patch 18 not "
                                       "measured, wall not measured")
    assert not [ours for ours in rows.values() if "nan" in ours.lower()], rows
    store.close()


def test_patch_18_and_the_wall_are_shown_when_measured(tmp_path):
    store, run, data = _store(tmp_path, {"p01": "patch01", "p18": "patch18", "wall": "wall"})
    rows = {name: ours for name, _, ours in paper_observations(store, run)}
    p18, wall = data.fits["patch18"].fit_error_pct, data.fits["wall"].fit_error_pct
    assert np.isfinite(p18) and np.isfinite(wall)
    assert rows["BRDF fit errors"] == (f"{data.fits['patch01'].fit_error_pct:.1f}–"
                                       f"{data.fits['patch01'].fit_error_pct:.1f} %, patch 18 "
                                       f"{p18:.1f} %, wall {wall:.1f} %")
    store.close()


def test_no_fits_and_no_correlations_say_not_measured(tmp_path):
    store, run, _ = _store(tmp_path, {})
    art = store.latest_artifact("comparison", f"ref-run-{run}")
    store.add_artifact(kind="comparison", name=f"ref-run-{run}", arrays=dict(art.arrays),
                       metadata={**art.metadata, "correlations": {}}, run_ref=run)
    rows = {name: ours for name, _, ours in paper_observations(store, run)}
    assert rows["BRDF fit errors"] == ("patches not measured, patch 18 not measured, wall not "
                                       "measured")
    assert rows["r(radiance, NRMSE) 65–90°"] == "not measured"
    assert rows["r(radiance, RMSE) 30–60° / 65–90°"] == "not measured / not measured"
    store.close()
