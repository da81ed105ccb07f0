import sqlite3

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
    assert store._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert store.schema_version() == SCHEMA_VERSION
    assert store.integrity_check() == "ok"


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
