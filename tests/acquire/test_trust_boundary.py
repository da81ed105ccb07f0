"""`run --resume` executes only shipped protocols or a protocol file named on the command line
now — never a path a store (perhaps received from someone else) recorded."""

from __future__ import annotations

from normbox_lab.acquire.store import Store
from normbox_lab.cli import main

PROTOCOL = '''
from pathlib import Path
Path(__file__).with_suffix(".ran").write_text("imported")
from normbox_lab.acquire.engine import measure
PARAMETERS = {"n": 1}
def steps(params, lab=None):
    return [measure(f"m{i}", "radiometer") for i in range(int(params["n"]))]
'''


def test_resume_never_imports_the_stored_protocol_path(tmp_path, capsys):
    evil = tmp_path / "evil.py"
    evil.write_text(PROTOCOL)
    store = tmp_path / "s.sqlite"
    with Store(store) as s:
        run = s.create_run(str(evil.resolve()), parameters={"n": 1}, planned=1,
                           status="paused")
    rc = main(["run", "--resume", run.uuid, "--store", str(store)])
    err = capsys.readouterr().err
    assert rc != 0 and "Traceback" not in err
    assert "only when you name it on the command line" in err
    assert not evil.with_suffix(".ran").exists()             # the file was never executed
    other = tmp_path / "other.py"
    other.write_text(PROTOCOL)
    rc = main(["run", str(other), "--resume", run.uuid, "--store", str(store), "--dry-run"])
    err = capsys.readouterr().err
    assert rc != 0 and "not" in err and not evil.with_suffix(".ran").exists()


def test_naming_the_file_now_runs_it_and_says_so(tmp_path, capsys):
    proto = tmp_path / "mine.py"
    proto.write_text(PROTOCOL)
    store = tmp_path / "s.sqlite"
    with Store(store) as s:
        run = s.create_run(str(proto.resolve()), parameters={"n": 1}, planned=1,
                           status="paused")
    main(["run", str(proto), "--resume", run.uuid, "--store", str(store), "--dry-run",
          "--world", "none"])
    err = capsys.readouterr().err
    assert "Python code, run with your rights because you named it here" in err
    assert proto.with_suffix(".ran").exists()
