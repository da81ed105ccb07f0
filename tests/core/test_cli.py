import subprocess
import sys

import pytest

from normbox_lab import __version__
from normbox_lab.cli import main


def test_help_lists_commands_and_imports_nothing_heavy():
    code = ("import sys\n"
            "from normbox_lab.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('mitsuba', 'matplotlib', 'xarray', 'textual', 'scipy', "
            "'colour', 'numpy') if m in sys.modules]\n"
            "print('HEAVY', heavy)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "init" in out and "runs" in out and "export" in out
    assert "HEAVY []" in out


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"normbox-lab {__version__}"


def test_module_entry_point():
    out = subprocess.run([sys.executable, "-m", "normbox_lab", "--version"], capture_output=True,
                         text=True, check=True).stdout
    assert __version__ in out


def test_init_runs_export_import(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "lab.toml", "--sim"]) == 0
    assert main(["init", "lab.toml", "--sim"]) == 2          # refuses to overwrite
    assert "exists already" in capsys.readouterr().err
    assert main(["runs"]) == 0
    assert "no store" in capsys.readouterr().out
    (tmp_path / "m.json").write_text(
        '[{"wavelengths": [400, 500]}, {"thetaIn": 0, "phiIn": 0, "thetaOut": 30, '
        '"phiOut": 0, "spectrum": [0.1, 0.2]}]')
    assert main(["import", "brdf-json", "m.json", "--material", "wall"]) == 0
    assert "as run 1" in capsys.readouterr().out
    assert main(["runs"]) == 0
    header, first = capsys.readouterr().out.splitlines()[:2]
    assert header.split()[:4] == ["id", "uuid", "protocol", "status"]
    line = first.split()
    assert line[0] == "1" and line[2] == "import-brdf-json" and line[3] == "done"
    assert line[4] == "1/1"
    assert main(["export", "1", "--format", "csv", "-o", "o.csv"]) == 0
    assert (tmp_path / "o.csv").read_text().count("\n") == 2      # header + one reading
    assert main(["export", "7", "--format", "json"]) == 2
    assert "no run matches" in capsys.readouterr().err


def test_bad_import_reports_place(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.json").write_text('[{"wavelengths": [400]}, {"thetaIn": 0}]')
    assert main(["import", "brdf-json", "bad.json"]) == 2      # a refusal of the file named
    err = capsys.readouterr().err
    assert "bad.json: element 1: missing field 'phiIn'" in err and err.count("\n") == 1


@pytest.mark.parametrize("params, expect", [
    (["angles_deg=[30,Infinity]", "patches=[7]"], "angles_deg: Infinity is not a finite number"),
    (["angles_deg=[1e400]"], "angles_deg: 1e400 is not a finite number"),
    # reported: each of these crashed, exited 1, or failed only at planning
    (["angles_deg=[" + "9" * 309 + "]"], "angles_deg: a 309-character number is too long"),
    (["patches=" + "9" * 5000], "patches: 5000 characters is too long"),
    (["lamp_timeout_s=" + "9" * 400], "lamp_timeout_s: a 400-character number is too long"),
    (["angles_deg=[30,,60]"], "angles_deg: '[30,,60]' has an empty item"),
    (["angles_deg=30,,60"], "angles_deg: '30,,60' has an empty item"),
    (["angles_deg=[٣٠]"], "angles_deg: '٣٠' has digits of another script; use the digits 0-9"),
    (["angles_deg=[30,30]"], "angles_deg: 30 is given twice"),
    (["angles_deg=[30,30.0000001]"],
     "angles_deg: 30.0000001 is given next to 30 (both are reading key a30)"),
    (["patches=[7,7]"], "patches: 7 is given twice"),
    (["lamp_timeout_s=NaN"], "lamp_timeout_s: NaN is not a finite number"),
    (["bogus=1"], "unknown parameter 'bogus'; known: angles_deg"),
    (["angles_deg"], "--param expects K=V, got 'angles_deg'"),
    (["patches=[7]", "patches=[8]"], "--param patches is given twice"),
    (["angles_deg=[-30,60]"], ("angles_deg: -30° is outside 0…95° (the rotator's range, "
                               "lab config)")),
    (["angles_deg=[30,400]"], "angles_deg: 400° is outside 0…95°"),
    (["patches=[]"], "patches: the list is empty; give at least one value"),
    (["patches=[25]"], "patches: 25 is not a patch number (1–24)"),
])
def test_a_bad_parameter_value_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, params,
                                                      expect):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "lab.toml", "--sim"]) == 0
    capsys.readouterr()
    argv = ["run", "reference-sweep", "--dry-run", "--world", "analytic"]
    for p in params:
        argv += ["--param", p]
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.err == f"normbox-lab: error: {expect}\n" or out.err.startswith(
        f"normbox-lab: error: {expect}"), out.err
    assert out.err.count("\n") == 1 and "Traceback" not in out.err and out.out == ""


@pytest.mark.parametrize("params, expect", [
    (["repeats=NaN"], "repeats: NaN is not a finite number"),
    (["repeats=" + "9" * 309], "repeats: a 309-character number is too long"),
    (["repeats=1e6"], "repeats: 1000000 is outside 1…100000"),
    (["repeats=2.5"], "repeats: 2.5 is not a whole number"),
    (["patch=٧"], "patch: '٧' has digits of another script"),
])
def test_repeatability_bad_values_are_exit_2(tmp_path, capsys, monkeypatch, params, expect):
    monkeypatch.chdir(tmp_path)
    main(["init", "lab.toml", "--sim"])
    capsys.readouterr()
    argv = ["run", "repeatability", "--dry-run", "--world", "analytic"]
    for p in params:
        argv += ["--param", p]
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.err.startswith(f"normbox-lab: error: {expect}"), out.err
    assert out.err.count("\n") == 1 and out.out == ""


@pytest.mark.parametrize("argv, expect", [
    (["run", "reference-sweep", "--time-scale", "-1"],
     "run: argument --time-scale: -1 must be ≥ 0"),
    (["run", "reference-sweep", "--time-scale", "1e400"],
     "run: argument --time-scale: 1e400 is not a finite number"),
    (["run", "reference-sweep", "--time-scale", "NaN"],
     "run: argument --time-scale: NaN is not a finite number"),
    (["tui", "--time-scale", "٢"],
     "tui: argument --time-scale: '٢' has digits of another script"),
    (["sim", "campaign", "--max-faults", "99999999999999999999"],
     "sim campaign: argument --max-faults: 99999999999999999999 is above 100"),
    (["sim", "campaign", "--scenarios", "9" * 5000],
     "sim campaign: argument --scenarios: a 5000-character number is too long"),
    (["sim", "campaign", "--normbox-share", "1.5"],
     "sim campaign: argument --normbox-share: 1.5 is above 1"),
    (["fit", "1", "-w", "inf"], "fit: argument -w/--weight-exponent: Infinity is not a finite"),
    (["image", "camera", "--patch", "25"], "image camera: argument --patch: 25 is above 24"),
    (["image", "whitebalance", "--size", "9" * 400 + "x10"], (
        "image whitebalance: argument --size: size must be WIDTHxHEIGHT (e.g. 320x240): a "
        "400-character number is too long")),
])
def test_every_numeric_option_goes_through_the_one_parser(capsys, argv, expect):
    """Reported: options that bypassed the checks (traceback, OverflowError, accepted NaN,
    accepted 1e20 fault rules) are one line and exit 2, before anything runs."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    out = capsys.readouterr()
    assert out.err.startswith(f"normbox-lab: error: {expect}"), out.err
    assert out.err.count("\n") == 1 and out.out == ""


@pytest.mark.parametrize("spec, expect", [
    ("garble@-1", "--faults 'garble@-1': N: -1 must be ≥ 1"),
    ("garble=NaN", "--faults 'garble=NaN': P: NaN is not a finite number"),
    ("no-reply=2", "--faults 'no-reply=2': P: 2 is above 1"),
    ("late-reply=0.2:1e999", "--faults 'late-reply=0.2:1e999': X: 1e999 is not a finite number"),
    ("garble@٣", "--faults 'garble@٣': N: '٣' has digits of another script"),
])
def test_sim_serve_fault_numbers_go_through_the_one_parser(capsys, spec, expect):
    assert main(["sim", "serve", "cs1000a", "--tcp", "127.0.0.1:0", "--faults", spec]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"normbox-lab: {expect}"), err
    assert err.count("\n") == 1


def test_repeatability_with_negative_repeats_is_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main(["init", "lab.toml", "--sim"])
    capsys.readouterr()
    assert main(["run", "repeatability", "--dry-run", "--world", "analytic",
                 "--param", "repeats=-5"]) == 2
    assert capsys.readouterr().err == ("normbox-lab: error: repeats: -5 is not a positive "
                                       "count (≥ 1)\n")


def test_a_huge_lab_time_is_one_short_word():
    from normbox_lab.acquire.estimate import format_duration

    assert format_duration(float("inf")) == "∞"
    assert format_duration(float("nan")) == "?"
    assert format_duration(1e308) == "1.16e+303 days"
    assert format_duration(10 ** 400) == "∞"
    assert format_duration(3725) == "1:02:05" and format_duration(-4) == "0:00"


# --- untyped failures become one typed line; state that agrees with the data ---------------------

def _store_with_a_run(path, **kw):
    import numpy as np

    from normbox_lab.acquire.store import Store

    with Store(path) as s:
        run = s.create_run("reference-sweep", planned=1, **kw)
        s.add_reading(run.id, "a30/p01", "spectral",
                      {"wavelength_nm": np.arange(380.0, 781.0),
                       "radiance_W_sr_m2_nm": np.ones(401)})
    return run


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.parametrize("ref", ["99999999999999999999999", "١", "-5"])
def test_export_and_qa_of_an_impossible_run_id_are_one_typed_line(tmp_path, capsys, ref):
    """`export 99999999999999999999999` raised OverflowError; a run id of Arabic-Indic digits
    ("١") selected run 1 (str.isdigit)."""
    store = tmp_path / "s.sqlite"
    _store_with_a_run(store)
    out = tmp_path / "o.json"
    assert main(["export", ref, "--format", "json", "-o", str(out), "--store", str(store)]) == 2
    assert "no run matches" in _one_error_line(capsys) and not out.exists()
    assert main(["qa", ref, "--store", str(store)]) == 2
    assert "no run matches" in _one_error_line(capsys)


def test_netcdf_export_onto_a_full_disk_is_a_typed_error_and_leaves_no_file(tmp_path, capsys,
                                                                             monkeypatch):
    import xarray

    store = tmp_path / "s.sqlite"
    _store_with_a_run(store)

    def full_disk(self, path, *a, **k):
        with open(path, "wb") as fh:           # what HDF5 manages before the disk is full
            fh.write(b"\x89HDF\r\n\x1a\n" + b"\0" * 512)
        raise RuntimeError("NetCDF: HDF error")

    monkeypatch.setattr(xarray.Dataset, "to_netcdf", full_disk)
    out = tmp_path / "run.nc"
    assert main(["export", "1", "--format", "netcdf", "-o", str(out), "--store", str(store)]) == 1
    err = _one_error_line(capsys)
    assert "HDF error" in err and "disk full" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.sqlite"]


def test_runs_shows_a_run_whose_process_died_as_interrupted(tmp_path, capsys):
    """A run whose process died (e.g. during the lamp warm-up) stays stored as `running`;
    `runs` and `qa` show it interrupted: "running" means a live owner holds the run lock."""
    from normbox_lab.acquire.store import Store

    store = tmp_path / "s.sqlite"
    run = _store_with_a_run(store, status="running")
    assert main(["runs", "--store", str(store)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert " interrupted " in line and "running" not in line, line
    with Store(store) as s:
        lock = s.lock_run(run.id)             # a live owner: this process
        try:
            assert main(["runs", "--store", str(store)]) == 0
            assert " running " in capsys.readouterr().out
            assert main(["qa", "1", "--store", str(store)]) == 0
            assert ": running" in capsys.readouterr().out
        finally:
            lock.release()


def test_report_gives_no_verdict_on_error_flagged_data_unless_accepted(tmp_path, capsys):
    from normbox_lab.acquire.store import Store

    store = tmp_path / "s.sqlite"
    run = _store_with_a_run(store, status="done")
    with Store(store) as s:
        s.add_flag(run_id=run.id, artifact_id=None, key="a30/p01", gate="lamp-drift",
                   severity="error", value=-1.2, limit=0.5, message="lamp monitor low")
    assert main(["report", "1", "--store", str(store)]) == 1
    err = _one_error_line(capsys)
    assert "report: 1 error flag(s)" in err and "--accept-flagged" in err
    # accepted, it goes on (and stops later here: this store holds no comparison)
    main(["report", "1", "--accept-flagged", "--store", str(store)])
    assert "error flag" not in capsys.readouterr().err


def test_help_texts_say_percent_once_and_name_the_run_arguments(capsys):
    for argv, expect in ((["budget", "--help"], "95 % intervals"),
                         (["report", "--help"], "the reference sweep (id or uuid prefix)"),
                         (["export", "--help"], "its id or a prefix of its uuid")):
        with pytest.raises(SystemExit):
            main(argv)
        out = " ".join(capsys.readouterr().out.split())
        assert expect in out and "%%" not in out, out


def test_a_directory_given_as_the_store_or_the_output_is_refused_with_exit_2(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    _store_with_a_run(store)
    assert main(["qa", "1", "--store", str(tmp_path)]) == 2
    assert "not a file" in _one_error_line(capsys)
    assert main(["export", "1", "--format", "json", "-o", str(tmp_path), "--store",
                 str(store)]) == 2
    assert "it is a directory" in _one_error_line(capsys)


RANGE_REFUSAL = "angles_deg: 100° is outside 0…95° (the rotator's range, lab config)"


def test_a_refusal_is_one_line_even_where_the_run_would_print_notes(tmp_path, capsys,
                                                                    monkeypatch):
    """A protocol file and no lab config: the run prints two notes (the file is Python code
    run with your rights; the simulated template is used), but a refused --param is its one
    error line, exit 2, with no note before it; the notes come once the run is accepted."""
    import shutil
    from pathlib import Path

    from normbox_lab import protocols

    monkeypatch.chdir(tmp_path)
    mine = tmp_path / "mine.py"
    shutil.copy(Path(protocols.__file__).parent / "reference_sweep.py", mine)
    common = ["--dry-run", "--world", "analytic", "--store", str(tmp_path / "s.sqlite")]
    capsys.readouterr()
    assert main(["run", "mine.py", *common, "--param", "angles_deg=[100]"]) == 2
    out = capsys.readouterr()
    assert out.err == f"normbox-lab: error: protocol file {mine}: {RANGE_REFUSAL}\n", out.err
    assert out.out == ""
    assert main(["run", "reference-sweep", *common, "--param", "angles_deg=[100]"]) == 2
    out = capsys.readouterr()
    assert out.err == f"normbox-lab: error: {RANGE_REFUSAL}\n" and out.out == "", out.err
    # accepted: both notes, then the plan
    assert main(["run", "mine.py", *common, "--param", "angles_deg=[30]"]) == 0
    out = capsys.readouterr()
    template = ("no --lab and no ./lab.toml: using the simulated lab template (normbox-lab "
                "init lab.toml --sim writes it)")
    python = ("protocol file mine.py: Python code, run with your rights because you named it "
              "here (shipped protocols and files named on the command line are the only "
              "protocols normbox-lab runs)")
    assert out.err.splitlines() == [template, python], out.err
    assert out.out.startswith(f"protocol {mine}: ")
