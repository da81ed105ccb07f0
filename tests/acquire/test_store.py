import sqlite3
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.acquire.store import SCHEMA_VERSION, Store
from normbox_lab.core.errors import StoreError
from normbox_lab.core.types import BrdfReading, Colorimetry, SpectralReading


@pytest.fixture
def store(tmp_path):
    with Store(tmp_path / "s.sqlite") as s:
        yield s


def test_pragmas_and_schema(store):
    store.create_run("light-map")          # the file is opened for writing at the first write
    assert store._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert store.schema_version() == SCHEMA_VERSION
    assert store.integrity_check() == "ok"


def test_a_store_for_crashes_only_commits_without_an_fsync_each(tmp_path):
    with Store(tmp_path / "s.sqlite", durable="crash") as s:
        s.create_run("light-map")
        assert s._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert s._db.execute("PRAGMA synchronous").fetchone()[0] == 1     # NORMAL
    with pytest.raises(ValueError, match="durable='fast'"):
        Store(tmp_path / "t.sqlite", durable="fast")


def test_spectral_round_trip_is_exact(store):
    run = store.create_run("reference-sweep", parameters={"angles_deg": [30, 35]},
                           lab_config="[lab]\n", seeds={"noise": 3}, planned=2)
    wl = np.arange(380.0, 781.0)
    rad = np.random.default_rng(1).random(401) * 1e-3
    colo = Colorimetry(1.0, 80.0, 70.0, 80.0, 60.0, 0.33, 0.35, 0.2, 0.47, 5000.0, 0.001)
    reading = SpectralReading(wl, rad, colo, 1.5, 1_800_000_000.0, "CS-1000A#123",
                              {"patch": 7, "angle_deg": 30.0})
    store.add_spectral(run.id, "a30/p07", reading)
    back = Store.as_spectral(store.reading(run.id, "a30/p07"))
    assert np.array_equal(back.radiance_W_sr_m2_nm, rad)
    assert np.array_equal(back.wavelength_nm, wl)
    assert back.colorimetry == colo
    assert back.metadata == {"patch": 7, "angle_deg": 30.0}
    assert back.integration_time_s == 1.5 and back.instrument_id == "CS-1000A#123"
    assert store.get_run(run.id).done == 1


def test_brdf_round_trip(store):
    run = store.create_run("brdf-inplane")
    r = BrdfReading(-30.0, 40.0, 4.0, np.arange(380.0, 781.0), np.full(401, 0.2),
                    raw_counts=np.arange(1044.0), blocked=False, instrument_id="QEP01234")
    store.add_brdf(run.id, "wall/ti-30/to+40", r)
    back = Store.as_brdf(store.reading(run.id, "wall/ti-30/to+40"))
    assert (back.theta_i_deg, back.theta_o_deg, back.tilt_deg) == (-30.0, 40.0, 4.0)
    assert np.array_equal(back.raw_counts, np.arange(1044.0))


def test_duplicate_key_is_refused_and_nothing_half_written(store):
    run = store.create_run("x")
    store.add_reading(run.id, "k", "spectral", {"a": np.ones(3)})
    with pytest.raises(StoreError, match="already has a reading 'k'"):
        store.add_reading(run.id, "k", "spectral", {"a": np.zeros(3)})
    assert [r.arrays["a"].tolist() for r in store.readings(run.id)] == [[1.0, 1.0, 1.0]]
    n_arrays = store._db.execute("SELECT COUNT(*) FROM arrays").fetchone()[0]
    assert n_arrays == 1


def test_run_lookup_by_id_and_uuid_prefix(store):
    a = store.create_run("a")
    b = store.create_run("b")
    assert store.get_run(str(b.id)).protocol == "b"
    assert store.get_run(a.uuid[:8]).id == a.id
    with pytest.raises(StoreError, match="no run"):
        store.get_run(999)
    with pytest.raises(StoreError):
        store.get_run("ab")  # too short to be a uuid prefix


def test_all_digit_uuid_prefix_is_found_or_refused_as_ambiguous(store):
    runs = [store.create_run("x") for _ in range(3)]
    store._db.execute("UPDATE runs SET uuid='12345678-aaaa' WHERE id=?", (runs[0].id,))
    store._db.execute("UPDATE runs SET uuid='00000002-bbbb' WHERE id=?", (runs[1].id,))
    assert store.get_run("12345678").id == runs[0].id      # no run 12345678: the uuid
    assert store.get_run("00000002").id == runs[1].id      # id 2 and its own uuid: one run
    store._db.execute("UPDATE runs SET uuid='00000002-cccc' WHERE id=?", (runs[2].id,))
    with pytest.raises(StoreError, match="more than one"):
        store.get_run("00000002")                           # id 2 and run 3's uuid


def test_status_events_instruments_artifacts(store):
    run = store.create_run("x", planned=5)
    store.set_run_status(run.id, "running")
    store.add_event(run.id, "fault", {"code": "ER10"})
    store.set_run_status(run.id, "done")
    kinds = [k for _, k, _ in store.events(run.id)]
    assert kinds == ["status:running", "fault", "status:done"]
    assert store.get_run(run.id).finished_s is not None
    with pytest.raises(StoreError):
        store.set_run_status(run.id, "exploded")
    store.add_instrument(run.id, "radiometer", {"model": "CS-1000A", "serial": "42"},
                         {"wavelength_shift_nm": 0.1})
    assert store.instruments(run.id)[0]["identity"]["model"] == "CS-1000A"
    aid = store.add_artifact("fit", "patch-7", {"kd": np.arange(4.0)}, metadata={"alpha": 0.4},
                             run_ref=run.id)
    art = store.latest_artifact("fit", "patch-7")
    assert art.id == aid and art.metadata == {"alpha": 0.4}
    assert np.array_equal(art.arrays["kd"], np.arange(4.0))
    with pytest.raises(StoreError):
        store.latest_artifact("fit", "nothing")


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "future.sqlite"
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version={SCHEMA_VERSION + 5}")
    db.close()
    with pytest.raises(StoreError, match="newer"):
        Store(path)


def test_not_a_database(tmp_path):
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="not a normbox-lab store"):
        Store(path)


def test_migration_from_empty_file_is_idempotent(tmp_path):
    path = tmp_path / "m.sqlite"
    Store(path).close()
    with Store(path) as s:
        assert s.schema_version() == SCHEMA_VERSION
        s.create_run("x")


# --- hostile and foreign files --------------------------------------------------------------------

def test_a_foreign_sqlite_file_is_refused_untouched(tmp_path):
    from normbox_lab.acquire.store import APPLICATION_ID

    for i, ddl in enumerate(["CREATE TABLE photos (id INTEGER, name TEXT)",
                             "CREATE TABLE runs (x TEXT)"]):          # a clashing `runs` table
        path = tmp_path / f"other{i}.sqlite"
        db = sqlite3.connect(path)
        db.execute(ddl)
        db.commit()
        db.close()
        before = path.read_bytes()
        with pytest.raises(StoreError, match="not a normbox-lab store"):
            Store(path)
        assert path.read_bytes() == before
    other = tmp_path / "app.sqlite"
    db = sqlite3.connect(other)
    db.execute("PRAGMA application_id=1234")
    db.close()
    with pytest.raises(StoreError, match="application id"):
        Store(other)
    with Store(tmp_path / "new.sqlite"):
        pass
    assert not (tmp_path / "new.sqlite").exists()      # nothing written: no file made
    with Store(tmp_path / "new.sqlite") as s:
        s.create_run("light-map")
    db = sqlite3.connect(tmp_path / "new.sqlite")
    assert db.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
    db.close()


def test_newer_schema_in_rollback_journal_mode_is_refused_before_any_change(tmp_path):
    path = tmp_path / "future.sqlite"
    Store(path).close()
    db = sqlite3.connect(path)
    db.execute("PRAGMA journal_mode=DELETE")
    db.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    db.close()
    before = path.read_bytes()
    with pytest.raises(StoreError, match="newer"):
        Store(path)
    assert path.read_bytes() == before            # header bytes 18/19 still say rollback
    assert not (tmp_path / "future.sqlite-wal").exists()


def test_store_without_application_id_is_adopted(tmp_path):
    path = tmp_path / "old.sqlite"
    with Store(path) as s:
        s.create_run("x")
    db = sqlite3.connect(path)
    db.execute("PRAGMA application_id=0")
    db.close()
    with Store(path) as s:
        assert [r.protocol for r in s.runs()] == ["x"]


def test_like_wildcards_in_a_run_id_match_nothing(tmp_path):
    with Store(tmp_path / "s.sqlite") as s:
        s.create_run("x")
        s.create_run("y")
        for ref in ("%%%%", "____", "%", "a%b_", "\\\\%%"):
            with pytest.raises(StoreError, match="no run"):
                s.get_run(ref)
        run = s.runs()[0]
        assert s.get_run(run.uuid[:6]).id == run.id


def test_a_damaged_store_is_a_store_error_in_every_command(tmp_path, capsys):
    from normbox_lab.cli import main

    path = tmp_path / "s.sqlite"
    with Store(path) as s:
        run = s.create_run("x", planned=40)
        for i in range(40):
            s.add_reading(run.id, f"k{i}", "spectral", {"v": np.arange(2000.0)})
    data = bytearray(path.read_bytes())
    for off in range(4096 * 3, len(data), 4096 * 2):          # wreck every other page
        data[off + 8: off + 200] = b"\xa5" * 192
    path.write_bytes(bytes(data))
    for command in (["runs"], ["qa", "1"]):         # never exit 0 showing "done 0/40"
        rc = main([*command, "--store", str(path)])
        out, err = capsys.readouterr()
        assert rc != 0 and "Traceback" not in err and "damaged" in err and out == "", (
            command, out, err)
        assert len(err.strip().splitlines()) == 1, err
    for fmt in ("json", "csv"):
        out = tmp_path / f"o.{fmt}"
        rc = main(["export", "1", "--format", fmt, "-o", str(out), "--store", str(path)])
        err = capsys.readouterr().err
        assert rc != 0 and "Traceback" not in err and "damaged" in err, (fmt, err)
        assert not out.exists()                         # nothing partial left behind


def test_export_to_an_unwritable_path_is_a_clear_error(tmp_path, capsys):
    from normbox_lab.cli import main

    path = tmp_path / "s.sqlite"
    with Store(path) as s:
        run = s.create_run("x", planned=1)
        s.add_reading(run.id, "k", "spectral", {"v": np.arange(3.0)})
    for target in (tmp_path / "no" / "such" / "dir" / "o.json", tmp_path):
        rc = main(["export", "1", "--format", "json", "-o", str(target), "--store", str(path)])
        err = capsys.readouterr().err
        assert rc != 0 and "Traceback" not in err and "cannot write" in err, err


# --- refused means unchanged, side files included; read-only commands never write ----------------

def _digests(folder: Path, stem: str) -> dict[str, str]:
    import hashlib

    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.glob(stem + "*"))}


def _with_hot_side_file(folder: Path, name: str, mode: str, setup: list[str]) -> Path:
    """A file whose writer died mid-way: copies of the file and its -wal/-shm (WAL) or
    -journal (rollback) taken while the writer still had them."""
    import shutil

    live = folder / "live" / name
    live.parent.mkdir()
    db = sqlite3.connect(live, isolation_level=None)
    db.execute(f"PRAGMA journal_mode={mode}")
    if mode == "WAL":
        db.execute("PRAGMA wal_autocheckpoint=0")
        for stmt in setup:
            db.execute(stmt)
    else:                                    # a transaction under way: the journal is hot
        db.execute("PRAGMA cache_size=1")
        for stmt in setup[:-1]:
            db.execute(stmt)
        db.execute("BEGIN")
        db.execute(setup[-1])
        db.execute("INSERT INTO t VALUES (randomblob(300000))")   # spills pages: journal hot
    for p in live.parent.glob(name + "*"):
        shutil.copy(p, folder / p.name)
    db.close()
    return folder / name


@pytest.mark.parametrize("mode", ["WAL", "DELETE"])
@pytest.mark.parametrize("kind", ["newer", "foreign"])
def test_a_refused_file_with_a_hot_journal_keeps_its_bytes_and_side_files(tmp_path, mode, kind):
    setup = (["CREATE TABLE t (x)", f"PRAGMA user_version={SCHEMA_VERSION + 3}",
              "INSERT INTO t VALUES (1)"] if kind == "newer" else
             ["CREATE TABLE t (x)", "PRAGMA application_id=1234", "INSERT INTO t VALUES (1)"])
    path = _with_hot_side_file(tmp_path, "f.sqlite", mode, setup)
    before = _digests(tmp_path, "f.sqlite")
    side = "f.sqlite-wal" if mode == "WAL" else "f.sqlite-journal"
    assert side in before, before
    for read_only in (False, True):
        with pytest.raises(StoreError, match="newer|not a normbox-lab store"):
            Store(path, read_only=read_only)
        after = _digests(tmp_path, "f.sqlite")
        after.pop("f.sqlite-shm", None), before.pop("f.sqlite-shm", None)   # SQLite's index
        assert after == before, (read_only, sorted(after))


def test_read_only_opens_never_write(tmp_path, capsys):
    from normbox_lab.cli import main

    empty = tmp_path / "empty.sqlite"
    empty.write_bytes(b"")
    assert main(["runs", "--store", str(empty)]) == 0
    assert "no runs" in capsys.readouterr().out
    assert empty.read_bytes() == b"" and sorted(p.name for p in tmp_path.iterdir()) == [
        "empty.sqlite"]
    path = tmp_path / "s.sqlite"
    with Store(path) as s:
        s.create_run("x", planned=2)
    before = _digests(tmp_path, "s.sqlite")
    with Store(path, read_only=True) as s:
        assert [r.protocol for r in s.runs()] == ["x"]
        with pytest.raises(StoreError):
            s.create_run("y")
    assert main(["qa", "1", "--store", str(path)]) == 0
    assert _digests(tmp_path, "s.sqlite") == before


def test_a_run_id_is_ascii_digits_or_a_uuid_prefix(tmp_path):
    """`str.isdigit()` is true for "١" (Arabic-Indic one) and int() reads it as 1; an id
    beyond SQLite's integers raised OverflowError."""
    with Store(tmp_path / "s.sqlite") as s:
        s.create_run("x")
        assert s.get_run("1").protocol == "x"
        for ref in ("١", "١١١١", "²", "99999999999999999999999", "-1"):
            with pytest.raises(StoreError, match="no run"):
                s.get_run(ref)


def test_running_means_a_live_process_holds_the_run_lock(tmp_path):
    with Store(tmp_path / "s.sqlite") as s:
        dead = s.create_run("x", status="running")     # its process died (no lock)
        alive = s.create_run("y", status="running")
        lock = s.lock_run(alive.id)
        try:
            assert s.shown_status(s.get_run(dead.id)) == "interrupted"
            assert s.shown_status(s.get_run(alive.id)) == "running"
            assert s.run_owned(alive.id) and not s.run_owned(dead.id)
        finally:
            lock.release()
        assert s.shown_status(s.get_run(alive.id)) == "interrupted"
        # a lock file left by a killed owner holds nothing
        stale = lock.path
        stale.write_text("12345")
        assert s.shown_status(s.get_run(alive.id)) == "interrupted"


@pytest.mark.skipif(not Path("/proc/version").exists(), reason="no procfs here")
def test_a_file_that_says_size_0_but_has_content_is_not_taken_for_a_new_store():
    """procfs files report a size of 0 and have content: a store is new only when reading
    finds nothing (`runs --store /proc/version` listed no runs, exit 0)."""
    from normbox_lab.core.errors import BadPath

    assert Path("/proc/version").stat().st_size == 0
    with pytest.raises(BadPath, match="not a normbox-lab store"):
        Store("/proc/version")
