"""The measurement store: one SQLite file, WAL, synchronous=FULL (`Store(durable=...)`), one
transaction per reading.

Tables (schema version in ``PRAGMA user_version``; forward migrations in `MIGRATIONS`):

- ``runs``        uuid, protocol, parameters, lab-config snapshot, code version, seeds, status,
                  planned reading count, timestamps
- ``run_events``  what happened to a run: started, paused, resumed (a new segment), faults,
                  operator decisions, finished
- ``readings``    (run, key) unique; kind, instrument, time, metadata JSON
- ``arrays``      float64 blobs with their shape, owned by a reading or an artifact
- ``instruments`` identity and calibration snapshot per run and role
- ``artifacts``   fits, predictions, comparisons, reports (pipeline results are data too)
- ``flags``       quality flags: (run, reading key or artifact, gate, severity, value, limit,
                  message); one per (run, artifact, key, gate), a re-check replaces it.  The
                  public API is `normbox_lab.analyze.qa`.

Arrays are stored as little-endian float64 bytes with the shape as JSON: exact round trips,
no pickle.

A normbox-lab store is recognised by ``PRAGMA application_id`` (`APPLICATION_ID`, "NBOX");
a store written before the id existed is recognised by its tables and adopted.  Any other
SQLite file is refused without being touched (no tables added, no WAL conversion), and so is a
store with a newer schema.  A damaged file surfaces as `StoreError` from every method, never
as a raw sqlite3 traceback.

Refused means unchanged, side files included: SQLite recovers a hot rollback journal or WAL
when a file is opened for writing (and checkpoints and deletes the WAL when the connection
closes), so a file is checked before SQLite may do that — its 100-byte header is read with
plain file I/O, then it is opened ``immutable=1`` (no journal or WAL is looked at), then
read-only (``mode=ro``: the WAL's pages are read, nothing is recovered or checkpointed) — and
only a file that passes all three is opened for writing.  Pages SQLite cannot read (a
``PRAGMA quick_check`` that is not "ok") are a `StoreError` at open, not empty tables.

A command that fails leaves the store as it was, side files included: every store is opened
for reading first (`store_file.ReadView`: ``immutable=1``, or — when a ``-wal`` or
``-journal`` lies beside the file — a private copy of the file and its side files, read
there; a copy per open while another process writes, which costs the store's size in I/O),
and the file is opened for writing only at the first write.  So a command that refuses (no
such run, no such artifact, a damaged file) before it writes neither recovers, checkpoints
nor re-indexes anything, and a missing or zero-byte store is neither created nor given a
schema.  A store opened for writing is first checked for write access — the file, its side
files and its folder (`store_file.read_only_problem`) — and a read-only one is named
read-only at once, before a run's start-up.

``Store(path, read_only=True)`` (``runs``, ``qa``, ``export``) never writes: the file is
opened ``mode=ro``, a missing or empty file is an empty store in memory, and an older schema
is migrated in memory.
"""

from __future__ import annotations

import functools
import inspect
import json
import sqlite3
import threading
import uuid as uuidlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np

from normbox_lab import __version__
from normbox_lab.acquire.store_file import (
    APPLICATION_ID,
    ReadView,
    RunLock,
    damaged,
    describe,
    preflight,
    read_only_problem,
    refusal_error,
)
from normbox_lab.core.errors import StoreError, UnknownRun
from normbox_lab.core.types import BrdfReading, Colorimetry, SpectralReading

DEFAULT_STORE = "normbox.sqlite"

MIGRATIONS: list[str] = [
    # version 1
    """
    CREATE TABLE runs (
        id            INTEGER PRIMARY KEY,
        uuid          TEXT NOT NULL UNIQUE,
        protocol      TEXT NOT NULL,
        parameters    TEXT NOT NULL DEFAULT '{}',
        lab_config    TEXT NOT NULL DEFAULT '',
        code_version  TEXT NOT NULL,
        seeds         TEXT NOT NULL DEFAULT '{}',
        status        TEXT NOT NULL,
        planned       INTEGER NOT NULL DEFAULT 0,
        created_s     REAL NOT NULL,
        updated_s     REAL NOT NULL,
        finished_s    REAL
    );
    CREATE TABLE run_events (
        id      INTEGER PRIMARY KEY,
        run_id  INTEGER NOT NULL REFERENCES runs(id),
        time_s  REAL NOT NULL,
        kind    TEXT NOT NULL,
        detail  TEXT NOT NULL DEFAULT '{}'
    );
    CREATE TABLE readings (
        id          INTEGER PRIMARY KEY,
        run_id      INTEGER NOT NULL REFERENCES runs(id),
        key         TEXT NOT NULL,
        kind        TEXT NOT NULL,
        instrument  TEXT NOT NULL DEFAULT '',
        time_s      REAL NOT NULL,
        metadata    TEXT NOT NULL DEFAULT '{}',
        UNIQUE (run_id, key)
    );
    CREATE TABLE arrays (
        owner     TEXT NOT NULL CHECK (owner IN ('reading', 'artifact')),
        owner_id  INTEGER NOT NULL,
        name      TEXT NOT NULL,
        shape     TEXT NOT NULL,
        data      BLOB NOT NULL,
        PRIMARY KEY (owner, owner_id, name)
    );
    CREATE TABLE instruments (
        id           INTEGER PRIMARY KEY,
        run_id       INTEGER NOT NULL REFERENCES runs(id),
        role         TEXT NOT NULL,
        identity     TEXT NOT NULL,
        calibration  TEXT NOT NULL DEFAULT '{}',
        time_s       REAL NOT NULL
    );
    CREATE TABLE artifacts (
        id         INTEGER PRIMARY KEY,
        run_id     INTEGER REFERENCES runs(id),
        kind       TEXT NOT NULL,
        name       TEXT NOT NULL,
        created_s  REAL NOT NULL,
        metadata   TEXT NOT NULL DEFAULT '{}'
    );
    CREATE INDEX artifacts_kind ON artifacts(kind, name);
    CREATE INDEX run_events_run ON run_events(run_id);
    """,
    # version 2: quality flags (run_id / artifact_id 0 = none)
    """
    CREATE TABLE flags (
        id           INTEGER PRIMARY KEY,
        run_id       INTEGER NOT NULL DEFAULT 0,
        artifact_id  INTEGER NOT NULL DEFAULT 0,
        key          TEXT NOT NULL DEFAULT '',
        gate         TEXT NOT NULL,
        severity     TEXT NOT NULL CHECK (severity IN ('warning', 'error')),
        value        REAL,
        limit_value  REAL,
        message      TEXT NOT NULL,
        created_s    REAL NOT NULL,
        UNIQUE (run_id, artifact_id, key, gate)
    );
    CREATE INDEX flags_run ON flags(run_id);
    CREATE INDEX flags_artifact ON flags(artifact_id);
    """,
]
SCHEMA_VERSION = len(MIGRATIONS)

RUN_STATUSES = ("created", "running", "paused", "interrupted", "aborted", "failed", "done")


@dataclass(frozen=True)
class RunRecord:
    id: int
    uuid: str
    protocol: str
    parameters: dict[str, Any]
    lab_config: str
    code_version: str
    seeds: dict[str, Any]
    status: str
    planned: int
    done: int
    created_s: float
    updated_s: float
    finished_s: float | None


@dataclass(frozen=True)
class StoredReading:
    id: int
    run_id: int
    key: str
    kind: str
    instrument: str
    time_s: float
    metadata: dict[str, Any]
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class Artifact:
    id: int
    run_id: int | None
    kind: str
    name: str
    created_s: float
    metadata: dict[str, Any]
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class ReadingRecord:
    """A reading as the store keeps it (kind, arrays, metadata), before it is committed."""

    kind: str
    arrays: dict[str, Any]
    metadata: dict[str, Any]
    instrument: str
    time_s: float | None


def spectral_record(reading: SpectralReading,
                    metadata: Mapping[str, Any] | None = None) -> ReadingRecord:
    """A radiometer reading as stored: its metadata, `metadata`, integration time and
    colorimetry; arrays wavelength_nm, radiance_W_sr_m2_nm."""
    meta = dict(reading.metadata)
    meta.update(metadata or {})
    meta["integration_time_s"] = reading.integration_time_s
    if reading.colorimetry is not None:
        meta["colorimetry"] = reading.colorimetry.as_dict()
    return ReadingRecord("spectral", {"wavelength_nm": reading.wavelength_nm,
                                      "radiance_W_sr_m2_nm": reading.radiance_W_sr_m2_nm},
                         meta, reading.instrument_id, reading.timestamp_s)


def brdf_record(reading: BrdfReading,
                metadata: Mapping[str, Any] | None = None) -> ReadingRecord:
    """A gonio reading as stored: geometry in the metadata; arrays wavelength_nm,
    brdf_per_sr (and raw_counts when the instrument gives them)."""
    meta = dict(reading.metadata)
    meta.update(metadata or {})
    meta.update(theta_i_deg=reading.theta_i_deg, theta_o_deg=reading.theta_o_deg,
                tilt_deg=reading.tilt_deg, blocked=reading.blocked,
                integration_time_s=reading.integration_time_s)
    arrays = {"wavelength_nm": reading.wavelength_nm, "brdf_per_sr": reading.brdf_per_sr}
    if reading.raw_counts is not None:
        arrays["raw_counts"] = reading.raw_counts
    return ReadingRecord("brdf", arrays, meta, reading.instrument_id, reading.timestamp_s)


def _encode(arr: Any) -> tuple[str, bytes]:
    a = np.ascontiguousarray(np.asarray(arr, dtype="<f8"))
    return json.dumps(list(a.shape)), a.tobytes()


def _decode(shape: str, data: bytes) -> np.ndarray:
    try:
        return np.frombuffer(data, dtype="<f8").reshape(json.loads(shape)).copy()
    except (ValueError, TypeError) as exc:
        raise StoreError(f"a stored array is damaged (shape {str(shape)[:40]!r}, "
                         f"{len(data) if isinstance(data, bytes) else '?'} bytes): {exc}") from None


def _json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, default=_json_default)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _typed_store_errors(cls: type) -> type:
    """Every public method: a sqlite3 error (a damaged file) becomes `StoreError`."""
    for name, fn in list(vars(cls).items()):
        if name.startswith("_") or not inspect.isfunction(fn):
            continue
        if inspect.isgeneratorfunction(fn):
            def wrapped_gen(self, *a, __fn=fn, **k):
                try:
                    yield from __fn(self, *a, **k)
                except sqlite3.Error as exc:
                    raise damaged(self.path, exc) from exc
            setattr(cls, name, functools.wraps(fn)(wrapped_gen))
        else:
            def wrapped(self, *a, __fn=fn, **k):
                try:
                    return __fn(self, *a, **k)
                except sqlite3.Error as exc:
                    raise damaged(self.path, exc) from exc
            setattr(cls, name, functools.wraps(fn)(wrapped))
    return cls


#: largest integer SQLite stores (a run id beyond it names no run)
_SQLITE_MAX_INT = 2**63 - 1


class _Transaction:
    """``with store._tx() as db:`` — the store's lock held, BEGIN IMMEDIATE … COMMIT, or
    ROLLBACK when the block raises."""

    __slots__ = ("_db", "_lock")

    def __init__(self, db: sqlite3.Connection, lock: Any) -> None:
        self._db = db
        self._lock = lock

    def __enter__(self) -> sqlite3.Connection:
        self._lock.acquire()
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except BaseException:
            self._lock.release()
            raise
        return self._db

    def __exit__(self, exc_type: object, exc: object, tb: object) -> bool:
        try:
            self._db.execute("ROLLBACK" if exc_type else "COMMIT")
        finally:
            self._lock.release()
        return False


#: `Store(durable=...)`: SQLite's synchronous setting for each (WAL mode)
DURABILITY = {"power-loss": "FULL", "crash": "NORMAL"}


@_typed_store_errors
class Store:
    """The SQLite store.  Safe to share between threads (one connection behind a lock)."""

    def __init__(self, path: str | Path = DEFAULT_STORE, *, clock_wall_s=None,
                 read_only: bool = False, durable: str = "power-loss") -> None:
        """`durable`: what a committed reading survives.  "power-loss" (the default: SQLite's
        ``synchronous=FULL``, an fsync per transaction) or "crash" (``synchronous=NORMAL`` in
        WAL mode: a commit survives the process's death, kill -9 included, but the last ones
        may roll back on a power cut or an OS crash; for the simulated campaign, whose
        readings the seed reproduces: the fsync costs 1-5 ms per reading)."""
        import time

        if durable not in DURABILITY:
            raise ValueError(f"durable={durable!r}: one of {', '.join(DURABILITY)}")
        self.durable = durable
        self.path = Path(path)
        self.read_only = bool(read_only)
        self._wall_s = clock_wall_s or time.time
        self._lock = threading.RLock()
        self._view: ReadView | None = None
        self._writer = False
        if str(path) == ":memory:":
            self._open_writer(":memory:")
            return
        if not self.read_only:
            why = read_only_problem(self.path)   # named at once, before anything is opened
            if why:
                raise StoreError(why)
        exists = preflight(self.path, SCHEMA_VERSION)
        self._open_reader(exists)

    def _open_reader(self, exists: bool) -> None:
        """Every store is first opened for reading only (`ReadView`: the file and its side
        files keep their bytes); the file is opened for writing at the first write
        (`_ensure_writer`), so a command that fails before it writes leaves the store, its
        ``-wal``, ``-shm`` and ``-journal`` as they were, and a missing or empty file is
        neither created nor given a schema."""
        if not exists:                     # nothing there: an empty store, in memory
            self._db = sqlite3.connect(":memory:", isolation_level=None,
                                       check_same_thread=False)
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
            return
        try:
            self._view = ReadView(self.path)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"{self.path}: cannot open ({exc})") from exc
        self._db = self._view.db
        try:
            self._recognise()
            rows = [line for r in self._db.execute("PRAGMA quick_check").fetchall()
                    for line in str(r[0]).splitlines() if line.strip()]
            if rows != ["ok"]:
                first = rows[0].lstrip("* ")[:120]
                raise StoreError(f"{self.path}: the store is damaged ({len(rows)} problem(s), "
                                 f"first: {first}); restore a copy (`sqlite3 FILE 'PRAGMA "
                                 "integrity_check'` lists them)")
            self._in_memory_if_older()
            self._db.execute("PRAGMA foreign_keys=ON")
        except sqlite3.Error as exc:
            self._close_reader()
            raise damaged(self.path, exc) from exc
        except StoreError:
            self._close_reader()
            raise

    def _close_reader(self) -> None:
        self._db.close()
        if self._view is not None:
            self._view.close()
            self._view = None

    def _open_writer(self, target: str) -> None:
        try:
            self._db = sqlite3.connect(target, isolation_level=None, check_same_thread=False,
                                       timeout=30.0)
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot open ({exc})") from exc
        try:
            self._recognise()
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(f"PRAGMA synchronous={DURABILITY[self.durable]}")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
        except sqlite3.Error as exc:
            self._db.close()
            why = read_only_problem(self.path) if target != ":memory:" else ""
            raise StoreError(why or f"{self.path}: not a normbox-lab store, or unreadable "
                                    f"({exc})") from exc
        except StoreError:
            self._db.close()
            raise
        self._writer = True

    def _ensure_writer(self) -> None:
        """Open the file for writing, at the first write (see `_open_reader`)."""
        if self._writer:
            return
        if self.read_only:
            raise StoreError(f"{self.path}: opened read-only; nothing was written")
        with self._lock:
            if self._writer:
                return
            why = read_only_problem(self.path)
            if why:
                raise StoreError(why)
            self._close_reader()
            self._open_writer(str(self.path))

    def _in_memory_if_older(self) -> None:
        """A read-only store of an older schema: copied into memory and migrated there."""
        version = int(self._db.execute("PRAGMA user_version").fetchone()[0])
        if version >= SCHEMA_VERSION:
            return
        mem = sqlite3.connect(":memory:", isolation_level=None, check_same_thread=False)
        self._db.backup(mem)
        self._db.close()
        self._db = mem
        self._migrate()

    # --- lifecycle -------------------------------------------------------------------------
    def _recognise(self) -> None:
        """Refuse a file that is not a normbox-lab store, or one with a newer schema, before
        anything is written to it."""
        error = refusal_error(self.path, *describe(self._db), SCHEMA_VERSION)
        if error is not None:
            raise error

    def _migrate(self) -> None:
        with self._lock:
            version = self._db.execute("PRAGMA user_version").fetchone()[0]
            for v in range(version, SCHEMA_VERSION):
                self._db.execute("BEGIN IMMEDIATE")
                try:
                    for stmt in filter(str.strip, MIGRATIONS[v].split(";")):
                        self._db.execute(stmt)
                    self._db.execute(f"PRAGMA user_version={v + 1}")
                    self._db.execute("COMMIT")
                except sqlite3.DatabaseError:
                    self._db.execute("ROLLBACK")
                    raise
            if int(self._db.execute("PRAGMA application_id").fetchone()[0]) != APPLICATION_ID:
                self._db.execute(f"PRAGMA application_id={APPLICATION_ID}")

    def close(self) -> None:
        with self._lock:
            self._close_reader()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def schema_version(self) -> int:
        with self._lock:
            return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def lock_run(self, run_ref: int | str) -> RunLock:
        """Take the run's execution lock (`RunLock`) or raise `StoreError` at once when
        another process holds it.  Call `release()` (or use it as a context manager)."""
        return RunLock(self.path, self.get_run(run_ref).uuid).acquire()

    def run_owned(self, run_ref: int | str) -> bool:
        """Whether a live process holds the run's execution lock (`RunLock.held`)."""
        return RunLock.held(self.path, self.get_run(run_ref).uuid)

    def shown_status(self, run: RunRecord) -> str:
        """The status as people are shown it: a run stored as ``running`` whose execution lock
        no live process holds (its process died: a kill, a closed terminal, a crash during the
        lamp warm-up) is ``interrupted`` — resumable, never "running"."""
        if run.status == "running" and not RunLock.held(self.path, run.uuid):
            return "interrupted"
        return run.status

    def quick_check(self) -> list[str]:
        """SQLite's quick check: [] when the file is sound, else its complaints."""
        with self._lock:
            rows = [str(r[0]) for r in self._db.execute("PRAGMA quick_check").fetchall()]
        return [] if rows == ["ok"] else rows

    def integrity_check(self) -> str:
        with self._lock:
            return str(self._db.execute("PRAGMA integrity_check").fetchone()[0])

    def _tx(self) -> _Transaction:
        self._ensure_writer()
        return _Transaction(self._db, self._lock)

    # --- runs ----------------------------------------------------------------------------------
    def create_run(self, protocol: str, *, parameters: Mapping[str, Any] | None = None,
                   lab_config: str = "", seeds: Mapping[str, Any] | None = None,
                   planned: int = 0, status: str = "created") -> RunRecord:
        now = self._wall_s()
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO runs (uuid, protocol, parameters, lab_config, code_version, seeds,"
                " status, planned, created_s, updated_s) VALUES (?,?,?,?,?,?,?,?,?,?)",
                (str(uuidlib.uuid4()), protocol, _json(dict(parameters or {})), lab_config,
                 __version__, _json(dict(seeds or {})), status, int(planned), now, now))
            run_id = cur.lastrowid
        return self.get_run(run_id)

    def create_complete_run(self, protocol: str, *, parameters: Mapping[str, Any] | None = None,
                            readings: list[tuple[str, str, Mapping[str, Any],
                                                 Mapping[str, Any]]],
                            instrument: str = "") -> RunRecord:
        """A finished run (status ``done``) with all its readings (key, kind, arrays,
        metadata), written in one transaction: either all of it is stored or nothing."""
        now = self._wall_s()
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO runs (uuid, protocol, parameters, lab_config, code_version, seeds,"
                " status, planned, created_s, updated_s, finished_s)"
                " VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                (str(uuidlib.uuid4()), protocol, _json(dict(parameters or {})), "",
                 __version__, "{}", "done", len(readings), now, now, now))
            run_id = int(cur.lastrowid)
            for key, kind, arrays, metadata in readings:
                try:
                    rid = db.execute(
                        "INSERT INTO readings (run_id, key, kind, instrument, time_s, metadata)"
                        " VALUES (?,?,?,?,?,?)",
                        (run_id, key, kind, instrument, now, _json(dict(metadata)))).lastrowid
                except sqlite3.IntegrityError as exc:
                    raise StoreError(f"reading {key!r} twice in one import: {exc}") from exc
                db.executemany("INSERT INTO arrays (owner, owner_id, name, shape, data)"
                               " VALUES ('reading',?,?,?,?)",
                               [(rid, name, *_encode(arr)) for name, arr in arrays.items()])
            db.execute("INSERT INTO run_events (run_id, time_s, kind, detail) VALUES (?,?,?,?)",
                       (run_id, now, "status:done", _json({"readings": len(readings)})))
        return self.get_run(run_id)

    def set_run_status(self, run_ref: int | str, status: str, *, planned: int | None = None,
                       detail: Mapping[str, Any] | None = None) -> None:
        if status not in RUN_STATUSES:
            raise StoreError(f"unknown run status {status!r}")
        run_id = self.get_run(run_ref).id
        now = self._wall_s()
        with self._tx() as db:
            db.execute("UPDATE runs SET status=?, updated_s=?, finished_s=? WHERE id=?",
                       (status, now, now if status in ("done", "aborted", "failed") else None,
                        run_id))
            if planned is not None:
                db.execute("UPDATE runs SET planned=? WHERE id=?", (int(planned), run_id))
            db.execute("INSERT INTO run_events (run_id, time_s, kind, detail) VALUES (?,?,?,?)",
                       (run_id, now, f"status:{status}", _json(dict(detail or {}))))

    def add_event(self, run_ref: int | str, kind: str, detail: Mapping[str, Any] | None = None,
                  ) -> None:
        run_id = self.get_run(run_ref).id
        with self._tx() as db:
            db.execute("INSERT INTO run_events (run_id, time_s, kind, detail) VALUES (?,?,?,?)",
                       (run_id, self._wall_s(), kind, _json(dict(detail or {}))))

    def events(self, run_ref: int | str) -> list[tuple[float, str, dict[str, Any]]]:
        run_id = self.get_run(run_ref).id
        with self._lock:
            rows = self._db.execute("SELECT time_s, kind, detail FROM run_events WHERE run_id=?"
                                    " ORDER BY id", (run_id,)).fetchall()
        return [(t, k, json.loads(d)) for t, k, d in rows]

    _RUN_SELECT = ("SELECT r.id, r.uuid, r.protocol, r.parameters, r.lab_config, r.code_version,"
                   " r.seeds, r.status, r.planned,"
                   " (SELECT COUNT(*) FROM readings g WHERE g.run_id = r.id),"
                   " r.created_s, r.updated_s, r.finished_s FROM runs r")

    @staticmethod
    def _run_row(row: tuple) -> RunRecord:
        return RunRecord(row[0], row[1], row[2], json.loads(row[3]), row[4], row[5],
                         json.loads(row[6]), row[7], row[8], row[9], row[10], row[11], row[12])

    def get_run(self, run_ref: int | str) -> RunRecord:
        """A run by integer id, or by uuid (a unique prefix of at least 4 characters is enough).

        A string of digits may be either; if it names an id *and* prefixes a uuid of another
        run, it is refused as ambiguous (give more of the uuid)."""
        rows: list[tuple] = []
        with self._lock:
            # ASCII digits only: str.isdigit() is true for "١" (Arabic-Indic one), and int()
            # reads it as 1; an id beyond SQLite's integers names no run (more than 19 digits
            # are not converted: 5000 digits would hit Python's 4300-digit limit)
            digits = isinstance(run_ref, int) or (isinstance(run_ref, str) and run_ref.isascii()
                                                  and run_ref.isdigit() and len(run_ref) <= 19)
            if digits and 0 <= int(run_ref) <= _SQLITE_MAX_INT:
                rows += self._db.execute(self._RUN_SELECT + " WHERE r.id=?",
                                         (int(run_ref),)).fetchall()
            prefix = run_ref.lower() if isinstance(run_ref, str) else ""
            if len(prefix) >= 4 and all(c in "0123456789abcdef-" for c in prefix):
                # (uuids are hex and dashes: nothing else can match, and no LIKE wildcard
                # can reach the query)
                rows += [r for r in self._db.execute(
                    self._RUN_SELECT + " WHERE substr(r.uuid, 1, ?) = ?",
                    (len(prefix), prefix)).fetchall() if r not in rows]
        if len(rows) != 1:
            what = "no run" if not rows else "more than one run"
            raise UnknownRun(f"{what} matches {run_ref!r} in {self.path}")
        return self._run_row(rows[0])

    def runs(self) -> list[RunRecord]:
        with self._lock:
            rows = self._db.execute(self._RUN_SELECT + " ORDER BY r.id").fetchall()
        return [self._run_row(r) for r in rows]

    # --- readings --------------------------------------------------------------------------
    def add_reading(self, run_ref: int | str, key: str, kind: str,
                    arrays: Mapping[str, Any], *, instrument: str = "",
                    metadata: Mapping[str, Any] | None = None,
                    time_s: float | None = None) -> int:
        """Commit one reading and its arrays in one durable transaction.

        Raises `StoreError` if the run already has a reading with this key (nothing is taken
        twice).
        """
        run_id = run_ref if isinstance(run_ref, int) else self.get_run(run_ref).id
        encoded = [(name, *_encode(arr)) for name, arr in arrays.items()]
        with self._tx() as db:
            try:
                cur = db.execute(
                    "INSERT INTO readings (run_id, key, kind, instrument, time_s, metadata)"
                    " VALUES (?,?,?,?,?,?)",
                    (run_id, key, kind, instrument,
                     self._wall_s() if time_s is None else float(time_s),
                     _json(dict(metadata or {}))))
            except sqlite3.IntegrityError as exc:
                raise StoreError(f"run {run_id} already has a reading {key!r} "
                                 f"(or the run does not exist): {exc}") from exc
            rid = cur.lastrowid
            db.executemany("INSERT INTO arrays (owner, owner_id, name, shape, data)"
                           " VALUES ('reading',?,?,?,?)",
                           [(rid, name, shape, data) for name, shape, data in encoded])
            db.execute("UPDATE runs SET updated_s=? WHERE id=?", (self._wall_s(), run_id))
        return int(rid)

    def keys(self, run_ref: int | str) -> set[str]:
        run_id = self.get_run(run_ref).id
        with self._lock:
            return {k for (k,) in self._db.execute("SELECT key FROM readings WHERE run_id=?",
                                                    (run_id,))}

    def _arrays(self, owner: str, owner_id: int) -> dict[str, np.ndarray]:
        rows = self._db.execute("SELECT name, shape, data FROM arrays WHERE owner=? AND"
                                " owner_id=? ORDER BY name", (owner, owner_id)).fetchall()
        return {n: _decode(s, d) for n, s, d in rows}

    def readings(self, run_ref: int | str, kind: str | None = None) -> Iterator[StoredReading]:
        run_id = self.get_run(run_ref).id
        sql = "SELECT id, run_id, key, kind, instrument, time_s, metadata FROM readings" \
              " WHERE run_id=?" + (" AND kind=?" if kind else "") + " ORDER BY id"
        with self._lock:
            rows = self._db.execute(sql, (run_id, kind) if kind else (run_id,)).fetchall()
        for r in rows:
            with self._lock:
                arrays = self._arrays("reading", r[0])
            yield StoredReading(r[0], r[1], r[2], r[3], r[4], r[5], json.loads(r[6]), arrays)

    def reading(self, run_ref: int | str, key: str) -> StoredReading:
        run_id = self.get_run(run_ref).id
        with self._lock:
            r = self._db.execute("SELECT id, run_id, key, kind, instrument, time_s, metadata"
                                 " FROM readings WHERE run_id=? AND key=?",
                                 (run_id, key)).fetchone()
            if r is None:
                raise StoreError(f"run {run_id} has no reading {key!r}")
            arrays = self._arrays("reading", r[0])
        return StoredReading(r[0], r[1], r[2], r[3], r[4], r[5], json.loads(r[6]), arrays)

    def add_record(self, run_ref: int | str, key: str, record: ReadingRecord) -> int:
        """Commit a reading prepared by `spectral_record` / `brdf_record` (what the engine's
        quality gates then check, without reading it back)."""
        return self.add_reading(run_ref, key, record.kind, record.arrays,
                                instrument=record.instrument, metadata=record.metadata,
                                time_s=record.time_s)

    # typed helpers ------------------------------------------------------------------------------
    def add_spectral(self, run_ref: int | str, key: str, reading: SpectralReading,
                     metadata: Mapping[str, Any] | None = None) -> int:
        return self.add_record(run_ref, key, spectral_record(reading, metadata))

    def add_brdf(self, run_ref: int | str, key: str, reading: BrdfReading,
                 metadata: Mapping[str, Any] | None = None) -> int:
        return self.add_record(run_ref, key, brdf_record(reading, metadata))

    @staticmethod
    def as_spectral(r: StoredReading) -> SpectralReading:
        meta = dict(r.metadata)
        colo = meta.pop("colorimetry", None)
        return SpectralReading(r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"],
                               Colorimetry.from_dict(colo) if colo else None,
                               float(meta.pop("integration_time_s", 0.0)), r.time_s,
                               r.instrument, meta)

    @staticmethod
    def as_brdf(r: StoredReading) -> BrdfReading:
        m = dict(r.metadata)
        return BrdfReading(float(m.pop("theta_i_deg")), float(m.pop("theta_o_deg")),
                           float(m.pop("tilt_deg", 0.0)), r.arrays["wavelength_nm"],
                           r.arrays["brdf_per_sr"], r.arrays.get("raw_counts"),
                           float(m.pop("integration_time_s", 0.0)), r.time_s, r.instrument,
                           bool(m.pop("blocked", False)), m)

    # --- instruments -----------------------------------------------------------------------
    def add_instrument(self, run_ref: int | str, role: str, identity: Mapping[str, Any],
                       calibration: Mapping[str, Any] | None = None) -> None:
        run_id = self.get_run(run_ref).id
        with self._tx() as db:
            db.execute("INSERT INTO instruments (run_id, role, identity, calibration, time_s)"
                       " VALUES (?,?,?,?,?)", (run_id, role, _json(dict(identity)),
                                               _json(dict(calibration or {})), self._wall_s()))

    def instruments(self, run_ref: int | str) -> list[dict[str, Any]]:
        run_id = self.get_run(run_ref).id
        with self._lock:
            rows = self._db.execute("SELECT role, identity, calibration, time_s FROM instruments"
                                    " WHERE run_id=? ORDER BY id", (run_id,)).fetchall()
        return [{"role": r, "identity": json.loads(i), "calibration": json.loads(c), "time_s": t}
                for r, i, c, t in rows]

    # --- artifacts -------------------------------------------------------------------------
    def add_artifact(self, kind: str, name: str, arrays: Mapping[str, Any] | None = None, *,
                     metadata: Mapping[str, Any] | None = None,
                     run_ref: int | str | None = None) -> int:
        run_id = None if run_ref is None else self.get_run(run_ref).id
        encoded = [(n, *_encode(a)) for n, a in (arrays or {}).items()]
        with self._tx() as db:
            cur = db.execute("INSERT INTO artifacts (run_id, kind, name, created_s, metadata)"
                             " VALUES (?,?,?,?,?)",
                             (run_id, kind, name, self._wall_s(), _json(dict(metadata or {}))))
            aid = cur.lastrowid
            db.executemany("INSERT INTO arrays (owner, owner_id, name, shape, data)"
                           " VALUES ('artifact',?,?,?,?)",
                           [(aid, n, s, d) for n, s, d in encoded])
        return int(aid)

    def artifacts(self, kind: str | None = None, name: str | None = None,
                  run_ref: int | str | None = None) -> list[Artifact]:
        sql = "SELECT id, run_id, kind, name, created_s, metadata FROM artifacts WHERE 1=1"
        args: list[Any] = []
        if kind is not None:
            sql += " AND kind=?"
            args.append(kind)
        if name is not None:
            sql += " AND name=?"
            args.append(name)
        if run_ref is not None:
            sql += " AND run_id=?"
            args.append(self.get_run(run_ref).id)
        out = []
        with self._lock:
            for r in self._db.execute(sql + " ORDER BY id", args).fetchall():
                out.append(Artifact(r[0], r[1], r[2], r[3], r[4], json.loads(r[5]),
                                    self._arrays("artifact", r[0])))
        return out

    # --- quality flags (see normbox_lab.analyze.qa) ----------------------------------------
    def add_flag(self, *, run_id: int | None, artifact_id: int | None, key: str, gate: str,
                 severity: str, value: float | None, limit: float | None,
                 message: str) -> int:
        """Record one flag; the same (run, artifact, key, gate) replaces the earlier one."""
        if severity not in ("warning", "error"):
            raise StoreError(f"unknown flag severity {severity!r}")
        with self._tx() as db:
            cur = db.execute(
                "INSERT OR REPLACE INTO flags (run_id, artifact_id, key, gate, severity, value,"
                " limit_value, message, created_s) VALUES (?,?,?,?,?,?,?,?,?)",
                (int(run_id or 0), int(artifact_id or 0), key, gate, severity,
                 None if value is None else float(value),
                 None if limit is None else float(limit), message, self._wall_s()))
        return int(cur.lastrowid)

    def last_flag_id(self) -> int:
        """The id of the newest flag (0 when there is none): flags recorded later have larger
        ids (a re-recorded flag is replaced by a new row)."""
        with self._lock:
            return int(self._db.execute("SELECT COALESCE(MAX(id), 0) FROM flags").fetchone()[0])

    def delete_reading_flags(self, run_id: int, key: str, *, up_to_id: int) -> int:
        """Remove the flags of reading `key` recorded up to flag id `up_to_id` (those of
        earlier attempts at a reading taken again); returns how many went."""
        where = ("FROM flags WHERE run_id=? AND artifact_id=0 AND key=? AND id<=?",
                 (int(run_id), key, int(up_to_id)))
        with self._lock:               # (no write transaction for the usual reading: none)
            if self._db.execute("SELECT 1 " + where[0] + " LIMIT 1", where[1]).fetchone() is None:
                return 0
        with self._tx() as db:
            cur = db.execute("DELETE " + where[0], where[1])
        return int(cur.rowcount)

    def flag_rows(self, *, run_id: int | None = None,
                  artifact_id: int | None = None) -> list[dict[str, Any]]:
        """Flags (as dicts, oldest first) of a run and/or an artifact; all when both None."""
        sql = ("SELECT id, run_id, artifact_id, key, gate, severity, value, limit_value,"
               " message, created_s FROM flags WHERE 1=1")
        args: list[Any] = []
        if run_id is not None:
            sql += " AND run_id=?"
            args.append(int(run_id))
        if artifact_id is not None:
            sql += " AND artifact_id=?"
            args.append(int(artifact_id))
        cols = ("id", "run_id", "artifact_id", "key", "gate", "severity", "value", "limit",
                "message", "created_s")
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY id", args).fetchall()
        return [dict(zip(cols, r, strict=True)) for r in rows]

    def latest_artifact(self, kind: str, name: str) -> Artifact:
        found = self.artifacts(kind, name)
        if not found:
            raise StoreError(f"no artifact {kind}/{name} in {self.path}")
        return found[-1]
