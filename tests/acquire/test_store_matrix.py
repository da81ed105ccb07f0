"""A command that fails leaves the store and its side files as they were.

The matrix: store states (damaged pages, a hot WAL, a -wal of garbage, a hot rollback journal, a zero-byte file,
no file, a read-only file, a read-only folder) × every command that takes ``--store``, each made
to fail for a reason of its own (a run that does not exist, an artifact that is missing).  For
each: the exit status, one typed line (never a traceback), and the sha256 of the store, its
``-wal``, ``-shm`` and ``-journal`` (and which of them exist) unchanged.  A read-only store is
named read-only, at once, by every command that would write.

As root every file is writable, so the read-only cases deny write access through the one check
the store asks (`store_file.read_only_problem` → `os.access`); `test_read_only_for_real` runs
two commands as an unprivileged user when the tests run as root.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.cli import main

STATES = ("damaged", "hot-wal", "garbage-wal", "journal", "zero-byte", "missing",
          "read-only-file", "read-only-dir")

#: every command that takes --store, with arguments that make it fail on a sound store for a
#: reason of its own (run 2 does not exist; run 1 has no fit, prediction or comparison)
COMMANDS: dict[str, list[str]] = {
    "runs": ["runs"],
    "qa": ["qa", "2"],
    "qa --recheck": ["qa", "2", "--recheck"],
    "export": ["export", "2", "--format", "json", "-o", "{tmp}/out.json"],
    "fit": ["fit", "2"],
    "predict": ["predict", "1", "--quality", "quick"],
    "compare": ["compare", "1"],
    "report": ["report", "1", "-o", "{tmp}/r.html"],
    "scene export": ["scene", "export", "2", "--out", "{tmp}/scene"],
    "budget": ["budget", "2"],
    "image figure1": ["image", "figure1", "2"],
    "import prediction": ["import", "prediction", "{tmp}/missing.csv", "--ref-run", "2",
                          "--renderer", "x"],
    "run --resume": ["run", "--resume", "2", "--lab", "{tmp}/lab.toml"],
}
#: commands that only read: they succeed on a sound store (and change nothing)
READERS = {"runs"}


def _sound_store(path: Path) -> None:
    with Store(path) as s:
        run = s.create_run("light-map", planned=1)
        s.add_reading(run.id, "k", "spectral", {"wavelength_nm": np.arange(3.0),
                                                "radiance_W_sr_m2_nm": np.ones(3)})
        s.set_run_status(run.id, "done")


def _hot(path: Path, mode: str) -> None:
    """`path` as a writer that died mid-way leaves it: a hot -wal (with its -shm), or a hot
    rollback -journal, copied while the writer still held them."""
    live = path.parent / "live" / path.name
    live.parent.mkdir()
    _sound_store(live)
    db = sqlite3.connect(live, isolation_level=None)
    if mode == "wal":
        db.execute("PRAGMA wal_autocheckpoint=0")
        db.execute("UPDATE runs SET protocol='light-map' WHERE id=1")
        db.execute("INSERT INTO run_events (run_id, time_s, kind) VALUES (1, 0, 'x')")
    else:
        db.execute("PRAGMA journal_mode=DELETE")
        db.execute("PRAGMA cache_size=1")
        db.execute("BEGIN")
        db.execute("INSERT INTO run_events (run_id, time_s, kind, detail) VALUES "
                   "(1, 0, 'x', hex(randomblob(200000)))")
    for p in live.parent.glob(path.name + "*"):
        shutil.copy(p, path.parent / p.name)
    db.close()
    shutil.rmtree(live.parent)


def make_state(tmp: Path, state: str) -> Path:
    folder = tmp / "store"
    folder.mkdir()
    path = folder / "s.sqlite"
    if state == "damaged":
        _sound_store(path)
        data = bytearray(path.read_bytes())
        data[4096:4096 * 3] = b"\xa5" * (4096 * 2)          # pages, not the header
        path.write_bytes(bytes(data))
    elif state == "hot-wal":
        _hot(path, "wal")
        assert Path(str(path) + "-wal").exists()
    elif state == "garbage-wal":                         # a -wal that is no WAL at all
        _sound_store(path)
        Path(str(path) + "-wal").write_bytes(bytes(range(256)) * 64)
    elif state == "journal":
        _hot(path, "journal")
        assert Path(str(path) + "-journal").exists()
    elif state == "zero-byte":
        path.write_bytes(b"")
    elif state in ("read-only-file", "read-only-dir"):
        _sound_store(path)
    (tmp / "lab.toml").write_text(_lab_toml(), encoding="utf-8")
    return path


def _lab_toml() -> str:
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE

    return SIM_CONFIG_TEMPLATE


def digests(path: Path) -> dict[str, str]:
    """sha256 of the store and every side file beside it (their presence included)."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(path.parent.glob(path.name + "*"))}


def _deny_writes(monkeypatch, path: Path, state: str) -> None:
    from normbox_lab.acquire import store_file

    real = os.access
    denied = path.parent.resolve() if state == "read-only-dir" else path.resolve()

    def access(p, mode, *a, **k):
        if mode & os.W_OK and Path(p).resolve() == denied:
            return False
        return real(p, mode, *a, **k)

    monkeypatch.setattr(store_file.os, "access", access)


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_failing_command_leaves_the_store_and_its_side_files_unchanged(
        tmp_path, capsys, monkeypatch, state, command):
    path = make_state(tmp_path, state)
    if state.startswith("read-only"):
        _deny_writes(monkeypatch, path, state)
    before = digests(path)
    argv = [a.format(tmp=tmp_path) for a in COMMANDS[command]] + ["--store", str(path)]
    t0 = time.monotonic()
    rc = main(argv)
    took_s = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    if rc == 0:
        # only a reading command may succeed here, and then it wrote nothing either
        assert command in READERS, (command, state, out)
        assert digests(path) == before
        return
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("normbox-lab: "), err
    assert digests(path) == before, (command, state, lines[-1])
    if state.startswith("read-only") and command not in ("runs", "qa", "export"):
        assert "read-only" in lines[-1] and "damaged" not in lines[-1], lines[-1]
        assert took_s < 10.0, took_s                          # at once, not after a start-up
    if state == "damaged":
        assert "damaged" in lines[-1] or "unreadable" in lines[-1], lines[-1]
    if state in ("zero-byte", "missing") and command not in ("runs",):
        assert not path.exists() or path.read_bytes() == b""


def test_the_hot_wal_is_read_with_its_committed_transactions_and_left_alone(tmp_path):
    path = make_state(tmp_path, "hot-wal")
    before = digests(path)
    with Store(path, read_only=True) as s:
        assert [kind for _, kind, _ in s.events(1)][-1] == "x"   # the WAL's transaction
    with Store(path) as s:                                      # opened, nothing written
        assert s.get_run(1).status == "done"
    assert digests(path) == before


def test_a_write_opens_the_file_and_recovers_it(tmp_path):
    path = make_state(tmp_path, "journal")
    with Store(path) as s:
        s.add_event(1, "y")
        assert [kind for _, kind, _ in s.events(1)][-1] == "y"
    assert not Path(str(path) + "-journal").exists()            # rolled back, then written


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0,
                    reason="needs root to run a command as another user")
def test_read_only_for_real(tmp_path):
    """As an unprivileged user (nobody): a read-only store file and a read-only folder."""
    import tempfile

    try:
        subprocess.run([sys.executable, "-c", "import normbox_lab"], check=True, timeout=60,
                       user=65534, group=65534, capture_output=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("the interpreter or the package is not readable by an unprivileged user")
    base = Path(tempfile.mkdtemp(prefix="normbox-ro-"))
    try:
        os.chmod(base, 0o755)
        for state in ("read-only-file", "read-only-dir"):
            work = base / state
            work.mkdir()
            os.chmod(work, 0o755)
            path = make_state(work, state)
            os.chmod(path.parent, 0o555 if state == "read-only-dir" else 0o777)
            for p in path.parent.iterdir():
                os.chmod(p, 0o444)
            os.chmod(work / "lab.toml", 0o444)
            before = digests(path)
            for argv in (["qa", "1", "--recheck"],
                         ["run", "--resume", "1", "--lab", str(work / "lab.toml")]):
                t0 = time.monotonic()
                proc = subprocess.run(
                    [sys.executable, "-m", "normbox_lab", *argv, "--store", str(path)],
                    check=False, capture_output=True, text=True, timeout=120, cwd=base,
                    user=65534, group=65534, env={**os.environ, "HOME": str(base)})
                took_s = time.monotonic() - t0
                assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr
                assert "read-only" in proc.stderr and "damaged" not in proc.stderr, proc.stderr
                assert took_s < 30.0, took_s
                assert digests(path) == before, (state, argv)
    finally:
        for p in base.rglob("*"):
            os.chmod(p, 0o755)
        shutil.rmtree(base, ignore_errors=True)
