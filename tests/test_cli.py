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
    assert main(["init", "lab.toml", "--sim"]) == 1          # refuses to overwrite
    assert "exists already" in capsys.readouterr().err
    assert main(["runs"]) == 0
    assert "no store" in capsys.readouterr().out
    (tmp_path / "m.json").write_text(
        '[{"wavelengths": [400, 500]}, {"thetaIn": 0, "phiIn": 0, "thetaOut": 30, '
        '"phiOut": 0, "spectrum": [0.1, 0.2]}]')
    assert main(["import", "brdf-json", "m.json", "--material", "wall"]) == 0
    assert "as run 1" in capsys.readouterr().out
    assert main(["runs"]) == 0
    line = capsys.readouterr().out.splitlines()[0].split()
    assert line[0] == "1" and line[2] == "import-brdf-json" and line[3] == "done"
    assert line[4] == "1/1"
    assert main(["export", "1", "--format", "csv", "-o", "o.csv"]) == 0
    assert (tmp_path / "o.csv").read_text().count("\n") == 3
    assert main(["export", "7", "--format", "json"]) == 1
    assert "no run matches" in capsys.readouterr().err


def test_bad_import_reports_place(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.json").write_text('[{"wavelengths": [400]}, {"thetaIn": 0}]')
    assert main(["import", "brdf-json", "bad.json"]) == 1
    assert "bad.json: element 1: missing field 'phiIn'" in capsys.readouterr().err
