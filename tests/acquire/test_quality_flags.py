"""Quality gates: each condition injected through an emulator, found as a flag in the store,
in `normbox_lab.analyze.qa` and on the `normbox-lab qa` command line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.quality import LAMP_SAMPLES, QualityLimits, brdf_flags
from normbox_lab.acquire.store import Store
from normbox_lab.analyze import qa
from normbox_lab.cli import main
from normbox_lab.core.errors import ConfigError, DataError
from normbox_lab.demo import run_protocol
from normbox_lab.sim.labsim import build_lab


def lab_with(*, qepro: str = "", sphere: str = "", radiometer: str = "", quality: str = "",
             world: str = "normbox", seed: int | None = None):
    """The simulated lab with faults on its emulators (radiometer without its random
    per-measurement gain, so repeatability is the lamp's); `seed`: the sphere emulator's."""
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://cs1000a"', 'port = "sim://cs1000a?noise=off"')
    if qepro:
        text = text.replace('port = "sim://qepro"', f'port = "sim://qepro?faults={qepro}"')
    if sphere or seed is not None:
        query = "&".join(q for q in (f"seed={seed}" if seed is not None else "",
                                     f"faults={sphere}" if sphere else "") if q)
        text = text.replace('port = "sim://sphere"', f'port = "sim://sphere?{query}"')
    if radiometer:
        text = text.replace('sim://cs1000a?noise=off', f'sim://cs1000a?noise=off&faults={radiometer}')
    if quality:
        text += quality + "\n"             # the template ends with its [quality] table
    return build_lab(parse_config(text, "lab.toml"), world=world)


def brdf_run(tmp_path, lab, *, materials=(1,), theta_i=(-30, 0), name="s.sqlite"):
    store = Store(tmp_path / name)
    run = run_protocol(lab, store, "brdf-inplane",
                       {"materials": list(materials), "theta_i_deg": list(theta_i)},
                       lambda *a: None)
    return store, run.run_id


def gates_of(store, run_id) -> dict[str, list[qa.Flag]]:
    out: dict[str, list[qa.Flag]] = {}
    for f in qa.flags(store, run_id):
        out.setdefault(f.gate, []).append(f)
    return out


def qa_cli(store, run_id, capsys) -> tuple[int, list[str]]:
    rc = main(["qa", str(run_id), "--store", str(store.path)])
    return rc, capsys.readouterr().out.strip().splitlines()


def test_clean_gonio_run_has_no_flags(tmp_path, capsys):
    store, run = brdf_run(tmp_path, lab_with())
    assert qa.flags(store, run) == []
    assert qa.run_status(store, run) == "done"
    rc, lines = qa_cli(store, run, capsys)
    assert rc == 0 and lines[-1] == "0 flags: 0 errors, 0 warnings"


# acquisitions: calibration takes ~4 spectra, so "@8" latches a condition in the sweep; the
# white slide moved only at calibration (slide=manual), so no per-reading lamp check re-takes
# the references (drivers/gonio.py) and each condition reaches its own gate
@pytest.mark.parametrize(("fault", "gate", "severity"), [
    ("saturation@8", "saturation", "error"),   # beyond the linearity correction
    ("tec-drift@8:2", "tec-off-setpoint", "error"),
    ("dark-drift@8:1000", "dark-drift", "warning"),      # seen when the next dark is taken
    # a dark current that jumps (even between a reading's spectrum and its own dark) is
    # measured and subtracted (drivers/gonio.py retakes both): reported, the reading right
    ("dark-drift@9:30000&slide=manual", "dark-drift", "warning"),
    ("lamp-dim@8:0.0001&slide=manual", "noise-floor", "warning"),
])
def test_qepro_condition_is_flagged(tmp_path, capsys, fault, gate, severity):
    store, run = brdf_run(tmp_path, lab_with(qepro=fault), theta_i=(-30, -60))
    found = gates_of(store, run)
    assert gate in found, (fault, {g: len(v) for g, v in found.items()})
    f = found[gate][0]
    assert f.severity == severity and f.run_id == run and f.key.startswith("p01/")
    assert f.value is not None and f.limit is not None
    # the first readings (before the condition) are clean
    assert all(not f.key.startswith("p01/i-30/o-80") for f in qa.flags(store, run))
    rc, lines = qa_cli(store, run, capsys)
    assert any(gate in line and f.key in line for line in lines)
    s = qa.summary(store, run)
    assert lines[-1] == f"{s.flags} flags: {s.errors} errors, {s.warnings} warnings"
    assert rc == (1 if s.errors else 0)
    assert qa.run_status(store, run) == "completed with flags"


def test_error_flags_refuse_the_fit_unless_accepted(tmp_path, capsys):
    from normbox_lab.analyze.pipeline import fit_run

    store, run = brdf_run(tmp_path, lab_with(qepro="tec-drift@11:2"), theta_i=(-60, -30, 0))
    with pytest.raises(DataError, match="error flag.*accept-flagged"):
        fit_run(store, run)
    assert store.artifacts("fit") == []
    assert main(["fit", str(run), "--store", str(store.path)]) == 1
    err = capsys.readouterr().err
    assert "tec-off-setpoint" in err and "--accept-flagged" in err
    fits = fit_run(store, run, accept_flagged=True)
    art = store.latest_artifact("fit", "p01")
    accepted = art.metadata["accepted_flags"]
    assert accepted and {a["gate"] for a in accepted} == {"tec-off-setpoint"}
    assert fits["p01"].fit_error_pct > 0


def test_fit_outlier_is_an_error_flag_on_the_fit(tmp_path):
    """The gonio lamp loses half its output in the middle of patch 1 (after its white
    reference): patch 1's fit is an outlier against the other materials, flagged as an error
    on the fit artifact, and predict refuses it."""
    from normbox_lab.analyze.pipeline import fit_run

    # (slide=manual: the white standard only at calibration, no per-reading lamp check)
    store, run = brdf_run(tmp_path, lab_with(qepro="lamp-dim@40:0.5&slide=manual"),
                          materials=(1, 2, 3), theta_i=(-60, -30, 0))
    fits = fit_run(store, run)
    found = gates_of(store, run)
    assert [f.key for f in found["fit-outlier"]] == ["p01"], {
        n: f.fit_error_pct for n, f in fits.items()}
    f = found["fit-outlier"][0]
    assert f.artifact_id == store.latest_artifact("fit", "p01").id
    assert f.severity == "error" and f.value > 2.5 and f.limit == 2.5
    with pytest.raises(DataError, match="predict: 1 error flag.*p01 fit-outlier"):
        qa.require_clean(store, artifacts=[f.artifact_id], step="predict")


def test_lamp_drift_seen_by_the_sphere_monitor(tmp_path, capsys):
    store = Store(tmp_path / "s.sqlite")
    lab = lab_with(sphere="lamp-drift@6:-100", world="analytic")
    run = run_protocol(lab, store, "repeatability", {"repeats": 6}, lambda *a: None).run_id
    found = gates_of(store, run)
    assert "lamp-drift" in found, {g: len(v) for g, v in found.items()}
    f = found["lamp-drift"][-1]
    assert f.value < -0.5 and f.limit == 0.5 and f.severity == "error"   # may be wrong
    monitor = [r.metadata["lamp_monitor_cd_m2"] for r in store.readings(run)]
    assert monitor[-1] < monitor[0]
    rc, lines = qa_cli(store, run, capsys)
    assert rc == 1 and any("lamp-drift" in line for line in lines)


SWEEP = {"angles_deg": [30, 60], "patches": [1, 2, 3, 4, 5, 6]}


def _sweep(tmp_path, name, sphere="", seed=None, sweep=SWEEP):
    store = Store(tmp_path / f"{name}.sqlite")
    run = run_protocol(lab_with(sphere=sphere, world="analytic", seed=seed), store,
                       "reference-sweep", sweep, lambda *a: None).run_id
    radiance = {r.key: r.arrays["radiance_W_sr_m2_nm"] for r in store.readings(run)}
    errors = {f.key for f in qa.flags(store, run) if f.severity == "error"}
    return radiance, errors, store, run


@pytest.mark.parametrize("sphere", ["lamp-drift@1:-10", "flicker:2", "flicker:5"])
def test_a_sphere_reading_off_by_the_lamp_carries_an_error_flag(tmp_path, sphere):
    """The world as oracle: each reading against a fault-free run of the same seed.  Drift
    −10 %/h from the first command left 9/12 readings 1.0–1.4 % low unflagged (the gate only
    compared with the run's first reading, itself taken after the warm-up drifted); flicker
    2 % / 5 % rms left readings off by up to 2.2 % / 8.5 % unflagged."""
    truth, _, _, _ = _sweep(tmp_path, "clean")
    radiance, errors, store, run = _sweep(tmp_path, "faulty", sphere)
    off = {k: abs(float(np.median(radiance[k] / truth[k])) - 1.0) for k in truth}
    wrong = {k for k, v in off.items() if v > 0.005}
    assert len(wrong) >= 8, off                          # the fault is real
    assert wrong <= errors, {k: off[k] for k in wrong - errors}
    gate = "lamp-drift" if "drift" in sphere else "lamp-unstable"
    assert gate in gates_of(store, run)
    with pytest.raises(DataError, match="error flag"):
        qa.require_clean(store, run=run, step="predict")


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_a_steady_sphere_raises_no_lamp_flag(tmp_path, seed):
    """The null case over several seeds: no fault, no flag (the monitor's own noise, 0.02 %
    rms on the simulated sphere, is 12× below the 0.25 % limit)."""
    _, errors, store, run = _sweep(tmp_path, "clean", seed=seed)
    assert errors == set() and qa.flags(store, run) == []
    meta = next(iter(store.readings(run))).metadata
    assert meta["lamp_monitor_before_cd_m2"] > 0 and meta["lamp_monitor_cd_m2"] > 0
    samples = meta["lamp_monitor_samples_cd_m2"]
    assert len(samples) == 2 * LAMP_SAMPLES
    assert samples[LAMP_SAMPLES - 1] == meta["lamp_monitor_before_cd_m2"]
    assert samples[LAMP_SAMPLES] == meta["lamp_monitor_cd_m2"]


def test_flicker_is_flagged_on_a_run_of_one_reading_over_many_seeds(tmp_path):
    """Sphere flicker 2 % rms (sim campaign seed 7 scenario 900: one reading 2.3 % low over 106
    bands without a flag).  A single before/after pair of monitor samples estimates the noise
    with one degree of freedom: over sphere seeds 1-200, 20 one-reading runs had no
    `lamp-unstable` and 4 (42, 59, 68, 77) no error flag at all.  The reading's own samples,
    three before and three after, give four degrees of freedom: 0 and 0 of 200."""
    missed = []
    for seed in range(40, 80):
        _, errors, store, run = _sweep(tmp_path, f"flicker{seed}", "flicker:2", seed=seed,
                                       sweep={"angles_deg": [50], "patches": [3]})
        if "lamp-unstable" not in gates_of(store, run) or errors != {"a50/p03"}:
            missed.append(seed)
        store.close()
    assert missed == []


def test_lamp_unstable_from_the_reading_s_own_monitor_samples(tmp_path):
    """Before and after agree (the old pair estimate reads 0 %), but the samples scatter by
    1 %: an error; the same samples steady to 0.01 %: nothing."""
    from normbox_lab.acquire.quality import RunGates

    store = Store(tmp_path / "s.sqlite")
    run = store.create_run("reference-sweep")
    gates = RunGates(store, run.id, QualityLimits(lamp_reference_cd_m2=2000.0))
    rad = {"radiance_W_sr_m2_nm": np.ones(401)}
    noisy = [2000.0, 1980.0, 2020.0, 2000.0, 2020.0, 1980.0]
    (f,) = gates.reading("a", "spectral", {"lamp_monitor_before_cd_m2": 2000.0,
                                           "lamp_monitor_cd_m2": 2000.0,
                                           "lamp_monitor_samples_cd_m2": noisy}, rad)
    assert (f.gate, f.severity, f.limit) == ("lamp-unstable", "error", 0.25)
    assert f.value == pytest.approx(100.0 * np.sqrt(4 * 20.0 ** 2 / 4) / 2000.0)   # 1.0 %
    assert "6 monitor samples" in f.message
    steady = [2000.0, 2000.2, 1999.8, 2000.0, 1999.8, 2000.2]
    other = {"radiance_W_sr_m2_nm": np.full(401, 1.0001)}   # (the same bytes: a repeated block)
    assert gates.reading("b", "spectral", {"lamp_monitor_before_cd_m2": 2000.0,
                                           "lamp_monitor_cd_m2": 2000.0,
                                           "lamp_monitor_samples_cd_m2": steady}, other) == []


def test_data_refused_on_the_wire_is_an_error_an_instrument_code_a_warning(tmp_path):
    from normbox_lab.acquire.quality import RunGates

    store = Store(tmp_path / "s.sqlite")
    run = store.create_run("reference-sweep")
    gates = RunGates(store, run.id)
    (bad,) = gates.device_error("a30/p01", "radiometer", "implausible-data", "band 0.01x")
    (code,) = gates.device_error("a30/p02", "radiometer", "ER10", "over range")
    assert (bad.gate, bad.severity) == ("instrument-error:implausible-data", "error")
    assert code.severity == "warning"


def test_repeatability_cv_above_threshold(tmp_path):
    store = Store(tmp_path / "s.sqlite")
    run = run_protocol(lab_with(sphere="flicker:3", world="analytic"), store, "repeatability", {"repeats": 8},
                       lambda *a: None).run_id
    (f,) = gates_of(store, run)["repeatability-cv"]
    assert f.key == "" and f.value > 0.5 and f.severity == "warning"


def test_repeatability_steady_lamp_has_no_cv_flag(tmp_path):
    store = Store(tmp_path / "s.sqlite")
    run = run_protocol(lab_with(world="analytic"), store, "repeatability", {"repeats": 8},
                       lambda *a: None).run_id
    assert "repeatability-cv" not in gates_of(store, run)


def test_radiometer_range_and_error_codes(tmp_path, capsys):
    store = Store(tmp_path / "s.sqlite")
    lab = lab_with(radiometer="over-range@1",
                   quality="radiometer_max_luminance_cd_m2 = 1.0", world="analytic")
    run = run_protocol(lab, store, "repeatability", {"repeats": 3}, lambda *a: None).run_id
    found = gates_of(store, run)
    assert len(found["radiometer-range"]) == 3
    f = found["radiometer-range"][0]
    assert f.severity == "error" and f.value > 1.0 and f.limit == 1.0
    (er,) = found["instrument-error:ER10"]
    assert er.key == "rep01" and "over measurement range" in er.message
    rc, lines = qa_cli(store, run, capsys)
    assert rc == 1 and lines[-1] == "4 flags: 3 errors, 1 warnings"


def test_nonfinite_brdf_gate():
    wl = np.arange(380.0, 781.0)
    b = np.full(wl.size, 0.1)
    b[3] = np.nan
    (f,) = brdf_flags("k", {"blocked": False}, {"brdf_per_sr": b}, QualityLimits())
    assert (f.gate, f.severity, f.value) == ("brdf-nonfinite", "error", 1.0)


def test_fit_not_converged_and_at_bounds(tmp_path):
    from normbox_lab.predict.brdf_model import MaterialFit

    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("brdf-inplane", status="done").id
        wl = np.arange(380.0, 781.0, 10.0)
        fits = {}
        for k, name in enumerate(["p01", "p02", "p03"]):
            fit = MaterialFit(name, wl, np.full(wl.size, 0.5), np.full(wl.size, 0.1),
                              1.5 if name == "p02" else 0.3, 1.5, 0.0, 4.0 + k, 2.0,
                              metadata={"converged": name != "p03", "status_message": "max nfev",
                                        "bounds": {"alpha": [1e-3, 1.5], "eta": [1.01, 3.0],
                                                   "c": [0.0, 0.1]}})
            fits[name] = (fit.store(store, run_ref=run), fit)
        qa.check_fits(store, run, fits)
        found = gates_of(store, run)
        assert [f.key for f in found["fit-at-bounds"]] == ["p02"]
        assert [f.key for f in found["fit-not-converged"]] == ["p03"]
        assert found["fit-not-converged"][0].severity == "error"
        assert "fit-outlier" not in found            # 4–6 %: no outlier
        # closure-like fits (all tiny): 3 × the median is no outlier below 2 %
        tiny = {n: (aid, dataclasses.replace(f, fit_error_pct=e)) for (n, (aid, f)), e in
                zip(fits.items(), (0.01, 0.01, 0.03), strict=True)}
        qa.check_fits(store, run, tiny)
        assert "fit-outlier" not in gates_of(store, run)


def test_prediction_standard_error_above_target(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("reference-sweep", status="done").id
        rad = np.ones((2, 1, 5))
        se = np.array([[[0.001] * 5], [[0.05] * 5]])
        aid = store.add_artifact("prediction", f"ref-run-{run}", {"radiance": rad},
                                 run_ref=run)
        qa.check_prediction(store, run, aid, [7, 19], [45.0], rad, se)
        (f,) = qa.flags(store, artifact=aid)
        assert (f.gate, f.key, f.value) == ("prediction-se", "p19@45", pytest.approx(0.05))
        assert qa.require_clean(store, run=run, artifacts=[aid]) == []   # warnings pass


def test_bad_limit_names_file_line_field(tmp_path):
    text = SIM_CONFIG_TEMPLATE + "fit_outlier_factor = 0.5\n"    # in the [quality] table
    with pytest.raises(ConfigError) as exc:
        parse_config(text, "lab.toml")
    line = text.splitlines().index("fit_outlier_factor = 0.5") + 1
    assert (exc.value.file, exc.value.line, exc.value.field) == \
        ("lab.toml", line, "quality.fit_outlier_factor")
    with pytest.raises(ConfigError, match="unknown limit"):
        parse_config(SIM_CONFIG_TEMPLATE + "foo = 1\n", "l.toml")


def test_qa_of_an_unknown_run_names_it(tmp_path, capsys):
    with Store(tmp_path / "s.sqlite") as store:
        store.create_run("x")
    rc = main(["qa", "nope", "--store", str(tmp_path / "s.sqlite")])
    assert rc == 2                       # a refusal of what was typed; 1 is for error flags
    assert "no run matches 'nope'" in capsys.readouterr().err


def test_runs_shows_flag_counts_and_completed_with_flags(tmp_path, capsys):
    store, run = brdf_run(tmp_path, lab_with(qepro="tec-drift@8:2"), theta_i=(-30,))
    clean = run_protocol(lab_with(), store, "brdf-inplane",
                         {"materials": [2], "theta_i_deg": [-30]}, lambda *a: None).run_id
    s = qa.summary(store, run)
    assert s.errors > 0 and qa.summaries_by_run(store)[run] == s and clean not in \
        qa.summaries_by_run(store)
    assert main(["runs", "--store", str(store.path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    flagged = next(line for line in lines if line.split()[0] == str(run))
    assert "completed with flags" in flagged and f"{s.flags} flags ({s.errors} errors)" in flagged
    plain = next(line for line in lines if line.split()[0] == str(clean))
    assert " done " in plain and "flags" not in plain


def test_report_opens_with_the_qa_summary(tmp_path):
    from normbox_lab.analyze.report import ReportData, build_html

    store, run = brdf_run(tmp_path, lab_with(qepro="tec-drift@8:2"), theta_i=(-30,))
    found = qa.flags(store, run)
    html, _, tables = build_html(ReportData(flags=found))
    s = qa.summary(store, run)
    # the report opens with its summary, whose first line is the QA count
    first_h2 = html.index("<h2>")
    assert html[first_h2:].startswith(f"<h2>Summary</h2><p class=\"qa-summary\">{s.line()}</p>")
    assert "tab-qa" in tables and "tec-off-setpoint" in html and found[0].key in html
    html, _, tables = build_html(ReportData())
    assert "0 flags: 0 errors, 0 warnings" in html and "tab-qa" not in tables


def test_gates_on_the_committed_record_equal_gates_on_the_reading_read_back(tmp_path):
    """The engine gates the record it committed instead of reading it back: every field a
    gate reads must be what the store returns (NaN, out-of-range Lv, negative BRDF, numpy
    scalars in the metadata, the lamp monitor)."""
    import numpy as np

    from normbox_lab.acquire.quality import QualityLimits, RunGates
    from normbox_lab.acquire.store import Store, brdf_record, spectral_record
    from normbox_lab.core.types import BrdfReading, Colorimetry, SpectralReading

    wl = np.arange(380.0, 781.0)
    rad = np.full(401, 1e-3)
    rad[5] = np.nan
    colo = Colorimetry(1.0, 1e6, 70.0, 80.0, 60.0, 0.33, 0.35, 0.2, 0.47, 5000.0, 0.001)
    spectral = SpectralReading(wl, rad, colo, 1.5, 1_800_000_000.0, "CS-1000A#1", {})
    brdf_values = np.full(401, 0.2)
    brdf_values[:3] = -0.5
    brdf = BrdfReading(-30.0, 40.0, 4.0, wl, brdf_values, raw_counts=np.arange(1044.0),
                       instrument_id="QEP01234",
                       metadata={"full_scale_counts": np.int64(200_000),
                                 "peak_counts": np.float64(199_000.0),
                                 "peak_signal_counts": 1500.0, "tec_temperature_c": -8.0,
                                 "tec_setpoint_c": -10.0})
    records = {"a30/p01": spectral_record(spectral, {"lamp_monitor_cd_m2": 500.0}),
               "a30/p02": spectral_record(spectral, {"lamp_monitor_cd_m2": np.float64(510.0)}),
               "g/1": brdf_record(brdf, {"segment": 1})}
    with Store(tmp_path / "s.sqlite") as store:
        in_memory, read_back = (RunGates(store, store.create_run("x").id, QualityLimits())
                                for _ in range(2))
        found_memory, found_back = [], []
        for key, rec in records.items():
            store.add_record(in_memory.run_id, key, rec)
            stored = store.reading(in_memory.run_id, key)
            assert stored.kind == rec.kind and stored.instrument == rec.instrument
            assert set(stored.arrays) == set(rec.arrays)
            found_memory += in_memory.reading(key, rec.kind, rec.metadata, rec.arrays)
            found_back += read_back.reading(key, stored.kind, stored.metadata, stored.arrays)
    gates = {f.gate for f in found_memory}
    assert {"radiance-nonfinite", "radiometer-range", "lamp-drift", "brdf-negative",
            "saturation", "noise-floor", "tec-off-setpoint"} <= gates
    assert found_memory == found_back
