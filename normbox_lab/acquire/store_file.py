"""The store's file: what is checked before SQLite may touch it, and the run lock beside it.

SQLite recovers a hot rollback journal or WAL when a file is opened for writing (and
checkpoints and deletes the WAL when the last connection closes), so a file that will be
refused must be recognised before that can happen (`preflight`): its 100-byte header by plain
file I/O (magic, ``application_id``, ``user_version``), then an ``immutable=1`` open (no
journal or WAL is looked at); `normbox_lab.acquire.store.Store` then reads it ``mode=ro``
(`read_only_uri`) before it opens it for writing.  A refused file keeps its bytes and its side
files.

`RunLock` is the execution lock of one run: an ``flock`` on ``STORE.RUN-UUID.lock``; `held`
asks whether a live process holds it without taking it.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import tempfile
import time
from pathlib import Path
from typing import Any, Self

from normbox_lab.core.errors import BadPath, StoreError

#: PRAGMA application_id of a normbox-lab store: "NBOX" as a big-endian 32-bit integer
APPLICATION_ID = 0x4E424F58
#: the tables by which a store from before the application id is recognised
_CORE_TABLES = {"runs", "run_events", "readings", "arrays", "instruments", "artifacts"}


class RunLock:
    """Who is executing a run: an exclusive `flock` on a sidecar file next to the store
    (``STORE.RUN-UUID.lock``, holding the owner's pid for the message).  The kernel drops the
    lock when its process dies, so `kill -9` cannot leave it stuck; the file is removed on
    release.  Without `fcntl` (Windows) locking is skipped."""

    #: how long a refused lock is tried again before it counts as another owner's
    PROBE_GRACE_S = 0.5

    def __init__(self, store_path: Path, run_uuid: str) -> None:
        self.path = store_path.with_name(f"{store_path.name}.{run_uuid}.lock")
        self.run_uuid = run_uuid
        self._fh: Any = None

    def acquire(self) -> Self:
        if self.path.name.startswith(":memory:"):    # no other process can see it
            return self
        try:
            import fcntl
        except ImportError:                      # pragma: no cover - not on POSIX
            return self
        # `held` probes with a momentary shared lock (another thread's status poll, or
        # another process's `runs`): a refusal that lasts less than PROBE_GRACE_S is a probe,
        # not an owner, so it is tried again before being reported
        deadline = time.monotonic() + self.PROBE_GRACE_S
        while True:
            fh = open(self.path, "a+", encoding="utf-8")  # noqa: SIM115 - held until release
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                fh.seek(0)
                holder = fh.read().strip()
                fh.close()
                if time.monotonic() < deadline:
                    time.sleep(0.005)
                    continue
                raise StoreError(
                    f"run {self.run_uuid} is being executed by another normbox-lab process"
                    f"{f' (pid {holder})' if holder else ''}; wait for it to finish or pause "
                    "it, then resume") from None
            try:                                   # a releasing owner may have removed it
                same = os.fstat(fh.fileno()).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                fh.seek(0)
                fh.truncate()
                fh.write(str(os.getpid()))
                fh.flush()
                self._fh = fh
                return self
            fh.close()

    @staticmethod
    def held(store_path: Path, run_uuid: str) -> bool:
        """Whether a live process holds the lock of `run_uuid` — asked without taking it and
        without creating or writing any file (a shared, non-blocking probe of the sidecar)."""
        path = store_path.with_name(f"{store_path.name}.{run_uuid}.lock")
        if path.name.startswith(":memory:"):
            return True
        try:
            import fcntl
        except ImportError:                      # pragma: no cover - not on POSIX
            return True
        try:
            fh = open(path, encoding="utf-8")  # noqa: SIM115 - closed below
        except FileNotFoundError:
            return False
        except OSError:
            return True
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            fh.close()                         # (closing drops the probe's shared lock)
        return False

    def release(self) -> None:
        if self._fh is not None:
            try:
                os.unlink(self.path)
            except OSError:
                pass
            self._fh.close()
            self._fh = None

    def __enter__(self) -> Self:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def damaged(path: Path, exc: Exception) -> StoreError:
    return StoreError(f"{path}: the store is damaged or unreadable ({exc}); check it with "
                      "`sqlite3 FILE 'PRAGMA integrity_check'` and restore a copy")


_SQLITE_MAGIC = b"SQLite format 3\x00"


def uri(path: Path, **query: str) -> str:
    from urllib.parse import quote

    q = "&".join(f"{k}={v}" for k, v in query.items())
    return f"file:{quote(str(path.resolve()))}?{q}"


def read_only_uri(path: Path) -> str:
    """A read-only URI: ``mode=ro`` where a WAL is beside the file (its pages are read, nothing
    is recovered into the file or checkpointed; SQLite may rebuild the ``-shm`` index), else
    ``immutable=1`` (no side file is created)."""
    if path.with_name(path.name + "-wal").exists():
        return uri(path, mode="ro")
    return uri(path, immutable="1")


#: the files SQLite keeps beside a store (write-ahead log, its index, a rollback journal)
SIDE_SUFFIXES = ("-wal", "-shm", "-journal")


def side_files(path: Path) -> list[Path]:
    return [path.with_name(path.name + s) for s in SIDE_SUFFIXES]


class ReadView:
    """A connection that reads a store without touching it or its side files.

    With no ``-wal`` or ``-journal`` beside the file it is opened ``immutable=1`` (SQLite
    looks at nothing else).  With one, SQLite would recover (a hot journal), checkpoint or
    re-index (``-shm``) the real files even on a read-only open, so the file and its side
    files are copied into a private folder and read there: what a reader sees is the store
    with every committed transaction, and the real files keep their bytes."""

    def __init__(self, path: Path) -> None:
        self.folder: str | None = None
        sides = [p for p in side_files(path) if p.exists() and not p.name.endswith("-shm")]
        if not sides:
            self.db = sqlite3.connect(uri(path, immutable="1"), uri=True,
                                      isolation_level=None, check_same_thread=False)
            return
        self.folder = tempfile.mkdtemp(prefix="normbox-store-read-")
        copy = Path(self.folder) / path.name
        try:
            shutil.copyfile(path, copy)
            for side in sides:
                shutil.copyfile(side, copy.with_name(copy.name + side.name[len(path.name):]))
            self.db = sqlite3.connect(str(copy), isolation_level=None, check_same_thread=False,
                                      timeout=30.0)
        except (OSError, sqlite3.Error):
            self.close()
            raise

    def close(self) -> None:
        db = getattr(self, "db", None)
        if db is not None:
            db.close()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def read_only_problem(path: Path) -> str:
    """Why a store at `path` cannot be written ("" when it can): a file, a side file or a
    folder the process may not write (SQLite creates the ``-wal`` and ``-shm`` beside the
    store, so its folder must be writable too).  Asked before anything is opened, so a
    read-only store is named read-only at once, not after a run's start-up."""
    folder = path.resolve().parent
    if path.exists() and not os.access(path, os.W_OK):
        return (f"{path}: the store is read-only (the file is not writable); nothing was "
                "changed: make it writable, or use a read-only command (runs, qa, export)")
    for side in side_files(path):
        if side.exists() and not os.access(side, os.W_OK):
            return (f"{path}: the store is read-only ({side.name} is not writable); nothing "
                    "was changed")
    if not os.access(folder, os.W_OK | os.X_OK):
        return (f"{path}: the store is read-only (its folder {folder} is not writable, and "
                "SQLite writes its journal beside the store); nothing was changed")
    return ""


def refusal(path: Path, app_id: int, version: int, tables: set[str], newest: int) -> str:
    """Why a file is not a store this program (schema version `newest`) may open ("" when it
    is)."""
    if app_id not in (0, APPLICATION_ID):
        return (f"{path}: not a normbox-lab store (SQLite application id {app_id:#010x}); "
                "refusing to touch it (the file was not changed)")
    if app_id == 0 and tables and not (_CORE_TABLES <= tables and version >= 1):
        return (f"{path}: not a normbox-lab store (an SQLite file with tables "
                f"{', '.join(sorted(tables)[:6])}); refusing to touch it (the file was not "
                "changed)")
    if version > newest:
        return (f"{path}: schema version {version} is newer than this normbox-lab "
                f"({newest}); upgrade normbox-lab (the file was not changed)")
    return ""


def refusal_error(path: Path, app_id: int, version: int, tables: set[str],
                  newest: int) -> StoreError | None:
    """`refusal` as the error to raise: a file that is not a store is a path a person gave
    that cannot be one (`BadPath`, exit 2); a newer schema asks for a newer program."""
    why = refusal(path, app_id, version, tables, newest)
    if not why:
        return None
    not_a_store = why.startswith(f"{path}: not a normbox-lab store")
    return BadPath(why) if not_a_store else StoreError(why)


def describe(db: sqlite3.Connection) -> tuple[int, int, set[str]]:
    app_id = int(db.execute("PRAGMA application_id").fetchone()[0])
    version = int(db.execute("PRAGMA user_version").fetchone()[0])
    tables = {r[0] for r in db.execute(
        "SELECT name FROM sqlite_master WHERE type='table'").fetchall()}
    return app_id, version, tables


def preflight(path: Path, newest: int) -> bool:
    """Check a store file before SQLite may recover (and so change) it: the header by plain
    file I/O, then an ``immutable=1`` open.  Returns False when there is no file or it is
    empty (a new store), True for a file that may be opened; raises `StoreError` otherwise."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return False
    except (OSError, ValueError) as exc:       # a name too long, a NUL byte: a typed path
        raise BadPath(f"{path}: cannot be a store ({exc})") from None
    import stat

    if not stat.S_ISREG(st.st_mode):
        raise BadPath(f"{path}: not a file")
    try:
        with open(path, "rb") as fh:
            header = fh.read(100)
    except OSError as exc:
        raise StoreError(f"{path}: cannot read ({exc})") from None
    if not header:                   # empty (a size of 0 is not enough: /proc's files say 0)
        return False
    if len(header) < 100 or not header.startswith(_SQLITE_MAGIC):
        raise BadPath(f"{path}: not a normbox-lab store (not an SQLite file); refusing to "
                      "touch it (the file was not changed)")
    error = refusal_error(path, int.from_bytes(header[68:72], "big"),
                          int.from_bytes(header[60:64], "big"), set(), newest)
    if error is not None:
        raise error
    try:
        db = sqlite3.connect(uri(path, immutable="1"), uri=True)
        try:
            error = refusal_error(path, *describe(db), newest)
        finally:
            db.close()
    except sqlite3.Error as exc:
        raise damaged(path, exc) from None
    if error is not None:
        raise error
    return True


__all__ = ["APPLICATION_ID", "SIDE_SUFFIXES", "ReadView", "RunLock", "damaged", "describe",
           "preflight", "read_only_problem", "read_only_uri", "refusal", "refusal_error", "side_files",
           "uri"]
