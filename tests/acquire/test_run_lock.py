"""One process per run: a second `--resume` of a run that is executing is refused at once,
and a `kill -9` of the owner never leaves the lock stuck."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import StoreError


def test_second_lock_is_refused_at_once_with_the_owner(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("x")
        lock = store.lock_run(run.id)
        with Store(tmp_path / "s.sqlite") as other, \
                pytest.raises(StoreError, match=f"another normbox-lab process \\(pid {os.getpid()}"):
            other.lock_run(run.uuid)
        lock.release()
        store.lock_run(run.id).release()             # free again
        assert not lock.path.exists()


def test_a_status_probe_at_the_moment_of_locking_is_not_an_owner(tmp_path, monkeypatch):
    """`RunLock.held` probes with a momentary shared lock; an engine that locks its run at
    that moment (the console polls run status from another thread) tries again instead of
    reporting another process.  The probe here lets go at the acquirer's first retry."""
    import fcntl

    from normbox_lab.acquire import store_file

    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("x")
        path = tmp_path / f"s.sqlite.{run.uuid}.lock"
        probe = open(path, "a+", encoding="utf-8")  # noqa: SIM115 - closed at the retry
        fcntl.flock(probe.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        retries = []

        def retry(_s: float) -> None:               # the probe closes instead of time passing
            retries.append(_s)
            probe.close()

        monkeypatch.setattr(store_file.time, "sleep", retry)
        lock = store.lock_run(run.id)
        assert len(retries) == 1 and lock.path.exists()
        lock.release()


def test_resume_while_another_process_executes_the_run_is_refused(tmp_path):
    from engine_fakes import FakeLab

    from normbox_lab.acquire import engine as eng

    path = tmp_path / "s.sqlite"
    params = {"angles_deg": [30, 60], "patches": [1, 2]}
    with Store(path) as store:
        e = eng.Engine(FakeLab(), store, eng.build_plan("reference-sweep", params))
        e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" else None)
        res = e.run()
        assert res.status == "paused"
        holder = store.lock_run(res.run_id)           # "the other process"
        with pytest.raises(StoreError, match="being executed by another"):
            eng.Engine(FakeLab(), store, eng.build_plan("reference-sweep", params)).run(
                resume=res.run_id)
        assert store.get_run(res.run_id).status == "paused"      # nothing was written
        holder.release()
        res2 = eng.Engine(FakeLab(), store, eng.build_plan("reference-sweep", params)).run(
            resume=res.run_id)
        assert res2.status == "done" and res2.done == 4


def test_kill_9_of_the_owner_frees_the_lock(tmp_path):
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        run = store.create_run("x")
    child = subprocess.Popen(
        [sys.executable, "-c",
         ("import sys; from normbox_lab.acquire.store import Store; "
          f"lock = Store({str(path)!r}).lock_run({run.id}); print('locked', flush=True); "
          "sys.stdin.read()")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "locked"
        with Store(path) as store:
            with pytest.raises(StoreError, match=f"pid {child.pid}"):
                store.lock_run(run.id)
            os.kill(child.pid, signal.SIGKILL)
            child.wait(timeout=30)
            store.lock_run(run.id).release()          # not stuck
    finally:
        if child.poll() is None:
            child.kill()


KILLED_IN_WARM_UP = r"""
import os, signal, sys
sys.path.insert(0, sys.argv[2])
from engine_fakes import FakeLab
from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.store import Store

lab = FakeLab()                                   # lamp off: the run starts with its warm-up
engine = eng.Engine(lab, Store(sys.argv[1]), eng.build_plan(
    "reference-sweep", {"angles_deg": [30], "patches": [1, 2]}, lab))
engine.subscribe(lambda ev: os.kill(os.getpid(), signal.SIGKILL)
                 if ev.kind == "step-started" and ev.data.get("kind") == "wait-stable" else None)
engine.run()
"""


def test_a_run_whose_process_died_in_the_warm_up_is_never_shown_running(tmp_path, capsys):
    """The process is killed while the lamp warms up: the store still says `running`, but no
    live process holds the run's lock, so `runs` and `qa` show it interrupted, and it resumes."""
    from pathlib import Path

    from engine_fakes import FakeLab

    from normbox_lab.acquire import engine as eng
    from normbox_lab.cli import main

    path = tmp_path / "s.sqlite"
    child = subprocess.run([sys.executable, "-c", KILLED_IN_WARM_UP, str(path),
                            str(Path(__file__).resolve().parents[1])], capture_output=True, text=True,
                           timeout=120, check=False)
    assert child.returncode == -signal.SIGKILL, child.stderr
    with Store(path) as store:
        (run,) = store.runs()
        assert run.status == "running" and run.done == 0       # as the dead process left it
    assert main(["runs", "--store", str(path)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert " interrupted " in line and "running" not in line, line
    assert main(["qa", str(run.id), "--store", str(path)]) == 0
    assert ": interrupted" in capsys.readouterr().out
    with Store(path) as store:
        lab = FakeLab()
        result = eng.Engine(lab, store, eng.build_plan(
            "reference-sweep", {"angles_deg": [30], "patches": [1, 2]}, lab)).run(resume=run.id)
        assert result.status == "done" and result.done == 2
