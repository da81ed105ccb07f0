"""`Store`: the typed interface of the measurement store, as the rest of the program uses it.

`normbox_lab.acquire.store.Store` (SQLite) is the one implementation; this Protocol is what a
function that takes a store names (``store: Store``) instead of ``store: Any``, so a reader
sees which calls it may make, a type checker checks them, and a test may hand in anything
that has them.  It is structural (`typing.Protocol`): nothing has to inherit from it.

Import it for annotations only (``from normbox_lab.acquire.store_api import Store``): it
imports the store's record types for type checkers only, so it costs nothing at run time.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from normbox_lab.acquire.store import Artifact, ReadingRecord, RunRecord, StoredReading


@runtime_checkable
class Store(Protocol):
    """Runs, readings, artifacts, flags and events of one store file."""

    path: Path

    # --- runs -------------------------------------------------------------------------------
    def get_run(self, run_ref: int | str) -> RunRecord: ...
    def runs(self) -> list[RunRecord]: ...
    def create_run(self, protocol: str, *, parameters: Mapping[str, Any] | None = None,
                   lab_config: str = "", seeds: Mapping[str, Any] | None = None,
                   planned: int = 0, status: str = "created") -> RunRecord: ...
    def create_complete_run(self, protocol: str, *,
                            parameters: Mapping[str, Any] | None = None,
                            readings: list[tuple[str, str, Mapping[str, Any],
                                                 Mapping[str, Any]]],
                            instrument: str = "") -> RunRecord: ...
    def set_run_status(self, run_ref: int | str, status: str, *, planned: int | None = None,
                       detail: Mapping[str, Any] | None = None) -> None: ...
    def add_event(self, run_ref: int | str, kind: str,
                  detail: Mapping[str, Any] | None = None) -> None: ...
    def events(self, run_ref: int | str) -> list[tuple[float, str, dict[str, Any]]]: ...
    def add_instrument(self, run_ref: int | str, role: str, identity: Mapping[str, Any],
                       calibration: Mapping[str, Any] | None = None) -> None: ...

    # --- readings ---------------------------------------------------------------------------
    def readings(self, run_ref: int | str, kind: str | None = None
                 ) -> Iterator[StoredReading]: ...
    def reading(self, run_ref: int | str, key: str) -> StoredReading: ...
    def keys(self, run_ref: int | str) -> set[str]: ...
    def add_record(self, run_ref: int | str, key: str, record: ReadingRecord) -> int: ...

    # --- artifacts and flags ----------------------------------------------------------------
    def add_artifact(self, kind: str, name: str, arrays: Mapping[str, Any] | None = None, *,
                     metadata: Mapping[str, Any] | None = None,
                     run_ref: int | str | None = None) -> int: ...
    def artifacts(self, kind: str | None = None, name: str | None = None,
                  run_ref: int | str | None = None) -> list[Artifact]: ...
    def latest_artifact(self, kind: str, name: str) -> Artifact: ...
    def add_flag(self, *, run_id: int | None, artifact_id: int | None, key: str, gate: str,
                 severity: str, value: float | None, limit: float | None,
                 message: str) -> int: ...
    def flag_rows(self, *, run_id: int | None = None,
                  artifact_id: int | None = None) -> list[dict[str, Any]]: ...


__all__ = ["Store"]
