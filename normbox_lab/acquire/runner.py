"""The runner: executes a plan against a lab, committing every reading to the store.

Execution semantics follow bluesky's run engine ([BLUESKY] in docs/references.md): deferred
pause (the current reading finishes and is committed first), immediate abort (the busy
instrument is told to abort, motors stopped), suspension while a lamp a reading requires is
unstable with the interrupted reading taken again, bounded retries of transient faults and an
operator decision for persistent ones (`retry.py`) — recorded in the run's events.
Subscribers get `EngineEvent`s; a subscriber that raises is logged and never stops the run.

The runner knows no instrument: step kinds (`steps.py`) do the work through capabilities, and
the lab is reached through `LabAccess`.

Threading: `Engine.run()` executes in the calling thread (a worker thread for the TUI);
`pause()`, `resume()`, `stop()`, `abort()` and `answer()` may be called from any thread.
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Protocol

from normbox_lab.acquire.estimate import DryRun, dry_run, prompts_left
from normbox_lab.acquire.events import EngineEvent, Operator, PromptRequest, RunResult
from normbox_lab.acquire.plan import Plan
from normbox_lab.acquire.quality import LAMP_SAMPLES, RunGates, limits_from_text
from normbox_lab.acquire.retry import RetryPolicy, Skip, StopAtPrompt, run_with_retry
from normbox_lab.acquire.steps import (
    KINDS,
    EstimateContext,
    PlanError,
    Step,
    TimedOperator,
    require,
    wait_until_stable,
)
from normbox_lab.acquire.store import ReadingRecord
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.capabilities import (
    Abortable,
    BrdfReadable,
    Calibratable,
    Homeable,
    LampMonitor,
    Movable,
    Recoverable,
    RemoteControllable,
    Settling,
    SpectrumReadable,
    Stoppable,
    Switchable,
)
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    DeviceError,
    ImplausibleData,
    InstrumentError,
    NormboxError,
    NotReady,
    OperatorAbort,
    StoreError,
)
from normbox_lab.core.types import (
    INTEGRATION_TIME,
    LAMP_MONITOR,
    LOCATIONS,
    BrdfReading,
    Location,
    SpectralReading,
)

log = logging.getLogger("normbox_lab.acquire.engine")


class LabAccess(Protocol):
    """What the engine needs of a lab (`normbox_lab.acquire.lab.Lab`, or a test's fake)."""

    clock: Clock
    operator: Operator | None

    def instrument(self, role: str) -> Any: ...
    def light_sources(self) -> tuple[str, ...]:
        """The roles of the lab whose instrument is a light source (`Settling`), known without
        opening any (a radiometer reading needs each of them stable; an emergency stop switches
        each of them off)."""
        ...
    def luminance_hint_cd_m2(self, step: Step) -> float:
        """Expected luminance of a reading (the radiometer's timing model needs it)."""
        ...
    def record_identities(self, store: Store, run_id: int, segment: int = 1,
                          roles: Iterable[str] | None = None) -> None:
        """Store the identity of each open instrument (of `roles` only, when given: the
        engine identifies one role at a time, through its fault policy)."""
        ...
    def provenance(self) -> Mapping[str, Any]:
        """What a new run records about the lab: {"lab_config": text, "seeds": {...}}."""
        ...


def halt(role: str, inst: Any) -> None:
    """Tell an instrument to stop what it is doing now (abort a reading, stop a motion)."""
    try:
        if isinstance(inst, Abortable):
            inst.abort()
        elif isinstance(inst, Stoppable):
            inst.stop()
    except (InstrumentError, OSError) as exc:
        log.warning("%s: halting during abort failed: %s", role, exc)


class _Busy:
    """``with engine.busy(role, inst):`` — `inst` is the one an abort must halt meanwhile."""

    __slots__ = ("_engine", "_what")

    def __init__(self, engine: Engine, what: tuple[str, Any]) -> None:
        self._engine = engine
        self._what = what

    def __enter__(self) -> None:
        self._engine._busy = self._what

    def __exit__(self, *exc: object) -> None:
        self._engine._busy = None


class Engine:
    """Runs one plan against a lab, committing every reading to the store."""

    def __init__(self, lab: LabAccess, store: Store, plan: Plan, *,
                 operator: Operator | None = None, retry: RetryPolicy | None = None,
                 wait_when_paused: bool = False, poll_s: float = 1.0,
                 suspend_timeout_s: float = 3600.0, max_suspensions: int = 5,
                 segment_info: Mapping[str, Any] | None = None) -> None:
        self.lab = lab
        self.store = store
        self.plan = plan
        self.clock = lab.clock
        self.operator = operator if operator is not None else lab.operator
        self.retry = retry or RetryPolicy()
        self.wait_when_paused = wait_when_paused
        self.poll_s = float(poll_s)
        self.suspend_timeout_s = float(suspend_timeout_s)
        self.max_suspensions = int(max_suspensions)
        #: recorded with each segment event (e.g. the simulated world used)
        self.segment_info = dict(segment_info or {})
        self.run_id: int | None = None
        self.run_uuid = ""
        self.segment = 0
        self.state = "idle"        # idle running paused suspended finished
        self._subs: dict[int, Callable[[EngineEvent], None]] = {}
        self._sub_ids = itertools.count(1)
        self._pause = threading.Event()
        self._stop = threading.Event()
        self._abort = threading.Event()
        self._emergency = threading.Event()
        self._resume = threading.Event()
        self._busy: tuple[str, Any] | None = None     # (role, instrument) while a step runs
        self._prompt_ids = itertools.count(1)
        self._pending_prompt: PromptRequest | None = None
        self._answer: str | None = None
        self._answered = threading.Event()
        self._known: dict[str, Any] = {}
        self._estimates: dict[str, float] = {}
        self._committed: set[str] = set()
        self._skipped: list[str] = []
        self._taken = 0                   # readings taken in this segment
        self._gates: RunGates | None = None
        self._ratio = 1.0
        self._hook_context: dict[str, Any] = {}
        self._remaining_s = 0.0
        self._light_cache: dict[tuple[str, tuple[str, ...]], tuple[str, ...]] = {}

    # --- subscribers ---------------------------------------------------------------------------
    def subscribe(self, callback: Callable[[EngineEvent], None]) -> Callable[[], None]:
        """Call `callback(event)` for every event (from the engine's thread); returns an
        unsubscribe function.  Exceptions in callbacks are logged, never propagated."""
        sid = next(self._sub_ids)
        self._subs[sid] = callback

        def unsubscribe() -> None:
            self._subs.pop(sid, None)
        return unsubscribe

    def _emit(self, event_kind: str, key: str = "", /, **data: Any) -> None:
        ev = EngineEvent(event_kind, self.run_id, key, self.clock.now_s(), data)
        for cb in list(self._subs.values()):
            try:
                cb(ev)
            except Exception:
                log.exception("engine subscriber %r failed on %s", cb, event_kind)

    def _store_event(self, event_kind: str, /, **detail: Any) -> None:
        if self.run_id is not None:
            self.store.add_event(self.run_id, event_kind, detail)

    # --- control (any thread) ------------------------------------------------------------------
    def pause(self) -> None:
        """Deferred pause: the current reading finishes and is committed, then the run pauses."""
        self._pause.set()

    def stop(self) -> None:
        """Deferred: finish the current reading, end this segment (status `paused`, resumable),
        also when paused in-process or waiting for an answer (the prompt is asked again on
        resume)."""
        self._stop.set()
        self._pause.set()
        self._resume.set()

    def resume(self) -> None:
        """Continue a run paused in-process (`wait_when_paused=True`)."""
        self._pause.clear()
        self._resume.set()

    def abort(self) -> None:
        """Immediate: the busy instrument aborts / stops, the run ends as `aborted`."""
        self._abort.set()
        self._resume.set()
        self._answered.set()
        busy = self._busy
        if busy is not None:
            halt(*busy)

    def emergency_stop(self) -> None:
        """Immediate, the operator's emergency stop: the busy instrument halts now, then every
        instrument of the plan halts and every lamp is switched off; the reading under way is
        abandoned (never committed) and the segment ends `paused`, resumable (lamps warm up
        again on resume: their state is forgotten)."""
        self._emergency.set()
        self.abort()

    def answer(self, choice: str, prompt_id: int | None = None) -> None:
        """Answer the prompt the engine is waiting on (when no operator callable is set)."""
        p = self._pending_prompt
        if p is None or (prompt_id is not None and prompt_id != p.id):
            raise NormboxError("no such prompt is waiting for an answer")
        if choice not in p.choices:
            raise NormboxError(f"answer {choice!r} is not one of {', '.join(p.choices)}")
        self._answer = choice
        self._answered.set()

    def next_key(self) -> str | None:
        """The first planned reading not stored yet (where a resume starts), None when none."""
        return next((k for k in self.plan.commit_keys if k not in self._committed), None)

    @property
    def pending_prompt(self) -> PromptRequest | None:
        return self._pending_prompt

    # --- what step kinds use (steps.StepRunner) ------------------------------------------------
    def instrument(self, role: str) -> Any:
        return self.lab.instrument(role)

    def busy(self, role: str, inst: Any) -> _Busy:
        return _Busy(self, (role, inst))

    def has(self, role: str, capability: type) -> bool:
        """Whether the instrument of `role` has `capability`: ``isinstance``, answered from the
        capabilities' own per-type cache (`core.capabilities._CapabilityMeta`)."""
        return isinstance(self.instrument(role), capability)

    def abort_requested(self) -> bool:
        return self._abort.is_set()

    def stop_requested(self) -> bool:
        return self._stop.is_set()

    def ask_operator(self, key: str, message: str, data: Mapping[str, Any]) -> str:
        return self._ask(PromptRequest(next(self._prompt_ids), key, "operator", message,
                                       ("ok",), dict(data)))

    def with_retry(self, key: str, role: str, action: Callable[[], Any]) -> Any:
        def on_fault(exc: BaseException, attempt: int, transient: bool) -> None:
            self._store_event("fault", key=key, role=role, attempt=attempt,
                              error=type(exc).__name__, message=str(exc))
            self._emit("fault", key, role=role, attempt=attempt, error=repr(exc),
                       transient=transient)
            self._known.pop(role, None)
            if isinstance(exc, DeviceError) and self._gates is not None:
                self._gates.device_error(key, role, str(exc.code), exc.meaning)
            if isinstance(exc, ImplausibleData) and self._gates is not None:
                # corrupted on the wire and refused after re-reads: a quality flag too
                self._gates.device_error(key, role, "implausible-data", str(exc))
            if transient and attempt < self.retry.attempts:
                detail = str(exc).removeprefix(f"{role}: ")    # the role named once
                self._emit("warning", key, message=f"{role}: {detail} — retry "
                           f"{attempt}/{self.retry.attempts - 1}")

        try:
            return run_with_retry(
                action, key=key, policy=self.retry, aborted=self._abort.is_set,
                on_fault=on_fault, recover=lambda: self._recover(role),
                decide=lambda exc, attempt: self._fault_decision(key, role, exc, attempt))
        except Skip as skip:
            self._store_event("skip", key=key, role=role, error=str(skip.__cause__))
            if self._gates is not None:
                self._gates.skipped(key, role, str(skip.__cause__))
            raise

    def _recover(self, role: str) -> None:
        if not role:
            return
        try:
            inst = self.instrument(role)
        except (KeyError, NormboxError):
            return
        if isinstance(inst, Recoverable):
            try:
                inst.recover()
            except (InstrumentError, OSError) as exc:
                log.warning("%s.recover() failed: %s", role, exc)

    # --- estimates ---------------------------------------------------------------------------
    def estimate_context(self) -> EstimateContext:
        op = self.operator
        prompt_s = float(op.expected_response_s or 0.0) if isinstance(op, TimedOperator) else 0.0
        return EstimateContext(self.instrument, self._luminance_hint, prompt_s, self.poll_s)

    def _luminance_hint(self, step: Step) -> float:
        if "luminance_cd_m2" in step.params:
            return float(step.params["luminance_cd_m2"])
        return float(self.lab.luminance_hint_cd_m2(step))

    def estimate_step_s(self, step: Step, est: EstimateContext) -> float:
        return KINDS[step.kind].estimate_s(step, est)

    def dry_run(self, committed: Iterable[str] = ()) -> DryRun:
        """The steps a run (or a resume with `committed` keys) would execute, and their ETA."""
        result, self._estimates = dry_run(self.plan, self.estimate_context(), committed)
        return result

    # --- running -----------------------------------------------------------------------------
    def run(self, resume: int | str | None = None) -> RunResult:
        """Execute the plan (a new run, or continue `resume`).  Returns when the run is done,
        paused (unless `wait_when_paused`), or aborted.  The run's execution lock is held
        throughout: a second process resuming the same run is refused at once."""
        self._run_lock: Any = None
        try:
            return self._run_segment(resume)
        finally:
            if self._run_lock is not None:
                self._run_lock.release()

    def _run_segment(self, resume: int | str | None) -> RunResult:
        """One segment: open (or reopen) the run, take the readings still missing, record
        how it ended."""
        t0 = self._start_segment(resume)
        status = "done"
        try:
            status = self._take_missing()
        except StopAtPrompt as exc:
            # stopped while a question was open: the unanswered step is asked again on resume
            status = "paused"
            self._store_event("stop", reason=f"stopped at {exc}")
        except OperatorAbort as exc:
            status = "aborted"
            self._halt_all()
            if self._emergency.is_set():
                status = "paused"
                self._store_event("emergency-stop", reason=str(exc))
            else:
                self._store_event("abort", reason=str(exc))
        except BaseException as exc:
            # KeyboardInterrupt / unexpected error: the run stays resumable
            status = "paused" if isinstance(exc, KeyboardInterrupt) else "failed"
            try:
                self.store.set_run_status(self.run_id, status, detail={"error": repr(exc)})
            except StoreError:
                log.exception("could not record the run status")
            self.state = "finished"
            self._emit("run-finished", status=status, error=repr(exc))
            raise
        return self._finish_segment(status, self._taken, t0)

    def _start_segment(self, resume: int | str | None) -> float:
        """Open or reopen the run, reset the segment's state, estimate, announce; the lab
        time the segment started."""
        self._abort.clear()
        self._pause.clear()
        self._stop.clear()
        if resume is None:
            self._open_new_run()
        else:
            self._reopen_run(resume)
        self._skipped = []
        self._taken = 0
        # the limits of the lab config the run recorded (its [quality] table)
        self._gates = RunGates(self.store, self.run_id, limits_from_text(
            self.store.get_run(self.run_id).lab_config, "lab config"))
        self._known = {}     # physical state after a (re)start: unknown
        self._light_cache = {}
        self.state = "running"
        t0 = self.clock.now_s()
        try:
            eta_s = self.dry_run(self._committed).total_s
        except (InstrumentError, OSError) as exc:      # no ETA is no reason to stop
            log.warning("no ETA: %s", exc)
            self._estimates, eta_s = {}, float("nan")
        self._remaining_s = sum(self._estimates.values())
        self._emit("run-started", run_uuid=self.run_uuid, segment=self.segment,
                   planned=self.plan.planned, done=len(self._committed), eta_s=eta_s,
                   resumed=resume is not None, **self._time_model())
        return t0

    def _take_missing(self) -> str:
        """Walk the plan: every reading not yet committed, with the state steps it needs
        (counted in `_taken`); "done" or "paused".  Aborts, stops and errors propagate."""
        self._check_preconditions()
        self._prepare()
        last_commit = self.plan.last_commit_index
        for i, step in enumerate(self.plan.steps):
            if self._abort.is_set():
                raise OperatorAbort("abort requested")
            if not step.commits:
                if i > last_commit:          # trailing steps (e.g. return home)
                    self._run_state_step(i, for_key=step.key)
                continue
            if step.key in self._committed:
                continue
            if self._checkpoint(step.key):
                return "paused"
            try:
                self._take(i)
                self._taken += 1
            except Skip:
                self._skipped.append(step.key)
                self._reestimate()
        return "done"

    def _finish_segment(self, status: str, taken: int, t0: float) -> RunResult:
        """The run-end gates, the run's status with its detail, the closing event."""
        done = len(self._committed)
        self._gates.finish(self.plan.protocol)
        detail: dict[str, Any] = {"taken": taken, "done": done}
        flags = self.store.flag_rows(run_id=self.run_id)
        if flags:
            errors = sum(1 for f in flags if f["severity"] == "error")
            detail["flags"] = {"errors": errors, "warnings": len(flags) - errors}
        if self._skipped:
            detail["skipped"] = self._skipped
            if status == "done":
                status = "interrupted"     # readings are missing: resumable, not done
        self.store.set_run_status(self.run_id, status, detail=detail)
        self.state = "finished" if status != "paused" else "paused"
        elapsed = self.clock.now_s() - t0
        self._emit("run-finished", status=status, taken=taken, done=done,
                   planned=self.plan.planned, skipped=list(self._skipped), elapsed_s=elapsed)
        return RunResult(self.run_id, self.run_uuid, status, taken, done, self.plan.planned,
                         tuple(self._skipped), elapsed)

    def _reestimate(self) -> None:
        """After a skip the lab is not in the state the segment's dry run assumed (the
        skipped reading's state steps may not have run: a lamp that faulted while warming up
        is warmed up by the next reading).  The readings still to take are estimated again
        from now — positions and lamps as they are, every state step counted — for the ETA
        and for each reading's expected time."""
        try:
            _, per_key = dry_run(self.plan, self.estimate_context(),
                                 self._committed | set(self._skipped))
        except (InstrumentError, OSError) as exc:     # an instrument that cannot say: keep
            log.warning("no new estimate after the skip: %s", exc)
            return
        self._estimates.update(per_key)
        self._remaining_s = sum(per_key.values())
        self._emit("estimates", estimates=dict(per_key))

    def _open_new_run(self) -> None:
        prov = self.lab.provenance()
        rec = self.store.create_run(
            self.plan.protocol, parameters=self.plan.parameters,
            lab_config=prov.get("lab_config", ""), seeds=prov.get("seeds", {}),
            planned=self.plan.planned, status="running")
        self.run_id, self.run_uuid = rec.id, rec.uuid
        self._run_lock = self.store.lock_run(rec.id)
        self._committed = set()
        self.segment = 1
        self._store_event("plan", fingerprint=self.plan.fingerprint(),
                          steps=len(self.plan), planned=self.plan.planned)
        self._store_event("segment", segment=1, pid=os.getpid(), **self.segment_info)

    def _reopen_run(self, resume: int | str) -> None:
        rec = self.store.get_run(resume)
        self._run_lock = self.store.lock_run(rec.id)    # before anything is written
        rec = self.store.get_run(rec.id)
        if rec.status == "done":
            raise StoreError(f"run {rec.uuid} is already done; nothing to resume")
        self.run_id, self.run_uuid = rec.id, rec.uuid
        events = self.store.events(rec.id)
        fps = [d.get("fingerprint") for _, k, d in events if k == "plan"]
        if fps and fps[0] != self.plan.fingerprint():
            raise StoreError(f"run {rec.uuid}: the protocol now declares a different plan "
                             f"(fingerprint {self.plan.fingerprint()} ≠ {fps[0]}); "
                             "resume with the same protocol file and parameters")
        self._committed = self.store.keys(rec.id)
        unknown = self._committed - set(self.plan.commit_keys)
        if unknown:
            raise StoreError(f"run {rec.uuid} holds keys the plan does not declare: "
                             f"{sorted(unknown)[:5]}")
        self.segment = 1 + sum(1 for _, k, _ in events if k == "segment")
        self.store.set_run_status(rec.id, "running",
                                  detail={"resumed_from": rec.status,
                                          "committed": len(self._committed)})
        self._store_event("segment", segment=self.segment, pid=os.getpid(),
                          resumed_from=rec.status, committed=len(self._committed),
                          **self.segment_info)

    def _checkpoint(self, next_key: str) -> bool:
        """Between readings: honour a pause.  True when the segment should end (paused)."""
        if not self._pause.is_set():
            return False
        self.state = "paused"
        self.store.set_run_status(self.run_id, "paused", detail={"next": next_key})
        self._emit("paused", next_key, done=len(self._committed))
        if not self.wait_when_paused or self._stop.is_set():
            return True
        self._resume.clear()
        while not self._resume.wait(0.1):
            pass
        if self._abort.is_set():
            raise OperatorAbort("abort requested while paused")
        if self._stop.is_set():
            return True
        self.state = "running"
        self.store.set_run_status(self.run_id, "running", detail={"in_process": True})
        self._emit("resumed", next_key)
        return False

    def _prepare(self) -> None:
        """(Re-)initialise: remote mode, homing where needed; record instrument identities.
        Every exchange here goes through the fault policy, identification included: retries
        after `recover()`, then the operator (retry or abort).  An instrument that never
        answers ends the segment `aborted` (resumable) like any other fault, never with an
        exception escaping `run()`."""
        for role in self.plan.roles:
            inst = self.instrument(role)
            self.with_retry(f"prepare/{role}", role, lambda inst=inst: self._prepare_one(inst))
            self.with_retry(f"prepare/{role}", role, lambda role=role: self.lab.record_identities(
                self.store, self.run_id, segment=self.segment, roles=(role,)))

    @staticmethod
    def _prepare_one(inst: Any) -> None:
        if isinstance(inst, RemoteControllable):
            inst.set_remote(True)
        if isinstance(inst, Homeable) and not inst.is_homed():
            inst.home(wait=True)

    def _halt_all(self) -> None:
        roles = list(self.plan.roles)
        if self._emergency.is_set():               # every lamp of the lab goes off
            roles += [r for r in self.lab.light_sources() if r not in roles]
        for role in roles:
            try:
                inst = self.instrument(role)
            except (KeyError, NormboxError):
                continue
            halt(role, inst)
            if self._emergency.is_set() and isinstance(inst, Switchable):
                try:
                    inst.set_output(False)
                except (InstrumentError, OSError) as exc:
                    log.warning("%s: switching off during the emergency stop failed: %s",
                                role, exc)
                self._known.pop(role, None)

    # --- one measurement, with the state it needs ---------------------------------------------
    def _take(self, i: int) -> None:
        step = self.plan.steps[i]
        kind = KINDS[step.kind]
        t_start = self.clock.now_s()
        mark = self._gates.attempt(step.key) if self._gates is not None else 0
        suspensions = 0
        role = step.role                      # the lamp that last dropped out, once one has
        while True:
            for j in self.plan.pending_state_steps(i, self._known):
                self._run_state_step(j, for_key=step.key)
            if suspensions >= self.max_suspensions:
                # the lamp keeps dropping out: a persistent fault, the operator decides
                exc = NotReady(f"unstable during {suspensions} attempts at {step.key}",
                               instrument=role)
                self._store_event("fault", key=step.key, role=role, attempt=suspensions,
                                  error="NotReady", message=str(exc))
                choice = self._fault_decision(step.key, role, exc, suspensions)
                if choice == "skip":
                    self._store_event("skip", key=step.key, role=role, error=str(exc))
                    raise Skip(step.key)
                suspensions = 0
            unstable = self._unstable_suspend(step)
            if unstable:
                role, suspensions = unstable, suspensions + 1
                continue                      # suspended and back: re-establish, then measure
            self._emit("step-started", step.key, kind=step.kind, label=step.describe())
            before = self._lamp_monitors(step)
            reading = self.with_retry(step.key, step.role,
                                      lambda: kind.execute(step, self, step.key))
            if self._abort.is_set():
                raise OperatorAbort("abort requested")
            unstable = self._unstable_suspend(step, after=True)
            if unstable:
                role, suspensions = unstable, suspensions + 1
                continue                      # the interrupted reading is taken again
            break
        meta = {k: v for k, v in step.params.items() if k != "role"}
        meta["segment"] = self.segment
        if step.requires:
            meta["requires"] = dict(step.requires)
        # the lamp's own monitor just before and after the reading (the lamp gates): the
        # samples nearest the reading, and all of them (their scatter is the lamp's noise)
        monitors = self._lamp_monitors(step)
        for lamp_role, after in monitors.items():
            meta["lamp_monitor_cd_m2"] = after[0]
            if lamp_role in before:
                meta["lamp_monitor_before_cd_m2"] = before[lamp_role][-1]
                meta["lamp_monitor_samples_cd_m2"] = [*before[lamp_role], *after]
        meta[LOCATIONS] = self._locations(step, reading, monitors)
        record = kind.commit(step, reading, self, meta)
        self._committed.add(step.key)
        if mark and self._gates is not None:
            self._gates.superseded(step.key, mark)     # a skip of an earlier segment is undone
        self._quality_gates(step.key, record)
        took = self.clock.now_s() - t_start
        est = self._estimates.get(step.key, 0.0)
        if est > 0 and took > 0:
            self._ratio = 0.8 * self._ratio + 0.2 * (took / est)
        self._remaining_s = max(0.0, self._remaining_s - est)
        remaining = self._remaining_s if len(self._committed) < self.plan.planned else 0.0
        self._emit("step-finished", step.key, kind=step.kind, duration_s=took)
        self._emit("reading-stored", step.key, reading=reading)
        if self.plan.on_reading is not None:
            try:
                flags = list(self.plan.on_reading(step, reading, self._hook_context) or ())
            except Exception:
                log.exception("protocol on_reading hook failed at %s", step.key)
                flags = []
            for message in flags:
                self._store_event("flag", key=step.key, message=message)
                self._emit("warning", step.key, message=message, flag=True)
        self._emit("progress", step.key, done=len(self._committed), planned=self.plan.planned,
                   eta_s=remaining * self._ratio, remaining_estimate_s=remaining,
                   **self._time_model())

    def _time_model(self) -> dict[str, Any]:
        """What a remaining-time estimate needs (`estimate.RemainingTime`): the timing
        model's lab seconds of the readings left (prompts included at `prompt_model_s` each)
        and the prompts they will ask."""
        if len(self._committed) >= self.plan.planned:
            return {"remaining_model_s": 0.0, "prompts_left": 0, "prompt_model_s": 0.0}
        return {"remaining_model_s": self._remaining_s,
                "prompts_left": prompts_left(self.plan, self._committed),
                "prompt_model_s": self.estimate_context().prompt_time_s}

    def _locations(self, step: Step, reading: Any,
                   monitors: Mapping[str, list[float]]) -> dict[str, dict[str, Any]]:
        """What the instruments did at this reading, each as a `Location` (setpoint,
        readback): every stage the step requires at an angle (`Movable.locate()`), the lamp
        monitor nearest the reading and the integration time the radiometer used; the
        instrument's own (the gonio's arms) kept."""
        typed = isinstance(reading, (SpectralReading, BrdfReading))
        out = dict(reading.metadata.get(LOCATIONS) or {}) if typed else {}
        for role, value in step.requires.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool) \
                    and self.has(role, Movable):
                # the stage kept its readback when the step's move ended: no exchange
                out[role] = self.instrument(role).locate().to_dict()
        for after in monitors.values():
            out[LAMP_MONITOR] = Location(None, after[0], "cd/m2").to_dict()
        if typed:
            out[INTEGRATION_TIME] = Location(None, float(reading.integration_time_s),
                                             "s").to_dict()
        return out

    def _lamp_monitors(self, step: Step) -> dict[str, list[float]]:
        """`LAMP_SAMPLES` readings of the monitor of each lamp the step requires stable that
        has one (`LampMonitor`), back to back: their scatter measures the lamp's output noise
        on this reading alone (the `lamp-unstable` gate), not only over the run's last
        readings."""
        out: dict[str, list[float]] = {}
        for role in (r for r, v in step.requires.items() if v == "stable"):
            lamp = self.instrument(role)
            if isinstance(lamp, LampMonitor):
                out[role] = [float(self.with_retry(step.key, role, lamp.luminance_cd_m2))
                             for _ in range(LAMP_SAMPLES)]
        return out

    def _quality_gates(self, key: str, record: ReadingRecord) -> None:
        """The acquisition quality gates on the reading just committed (flags are stored):
        on the record the store committed, kind, metadata and arrays as stored, so nothing is
        read back."""
        if self._gates is None:
            return
        for flag in self._gates.reading(key, record.kind, record.metadata, record.arrays):
            self._store_event("flag", key=key, gate=flag.gate, severity=flag.severity,
                              message=flag.message)
            self._emit("warning", key, message=f"{flag.severity} {flag.gate}: {flag.message}",
                       flag=True, gate=flag.gate, severity=flag.severity)

    def _check_preconditions(self) -> None:
        """What a reading needs is the engine's to check, not the protocol's convention:
        a reading from a Calibratable instrument must require the state that one of its own
        calibrate steps sets (else `PlanError` naming the step, before anything moves)."""
        cal_sets: dict[str, set[str]] = {}
        for s in self.plan.steps:
            if s.kind == "calibrate":
                cal_sets.setdefault(s.role, set()).update(s.sets)
        for s in self.plan.steps:
            if not s.commits:
                continue
            inst = self.instrument(s.role)
            if isinstance(inst, Calibratable) and isinstance(inst, BrdfReadable) and \
                    not cal_sets.get(s.role, set()) & set(s.requires):
                raise PlanError(f"step {s.key!r} reads {s.role!r}, a calibratable instrument, "
                                f"without requiring one of its calibrate steps' states; add a "
                                f"calibrate step (sets=...) and require it")

    def _light_roles(self, step: Step) -> tuple[str, ...]:
        """Lamps that must be stable for this reading: those the step requires stable, and —
        for a radiometer reading — every light source of the plan and of the lab
        (`LabAccess.light_sources`), whether the protocol declared it or not (warm-up is a
        precondition, not a habit).
        Worked out once per segment for each (reading role, required lamps), unless a lamp
        could not be reached (then asked again at the next reading)."""
        required = tuple(r for r, v in step.requires.items() if v == "stable")
        key = (step.role, required)
        roles = self._light_cache.get(key)
        if roles is not None:
            return roles
        found = list(required)
        complete = True
        if self.has(step.role, SpectrumReadable):
            for r in (*self.plan.roles, *self.lab.light_sources()):
                if r in found or r == step.role:
                    continue
                try:
                    if self.has(r, Settling):
                        found.append(r)
                except KeyError:          # the lab has no such role
                    continue
                except NormboxError:      # it could not be opened now
                    complete = False
        roles = tuple(found)
        if complete:
            self._light_cache[key] = roles
        return roles

    def _unstable_suspend(self, step: Step, after: bool = False) -> str:
        """Suspender: a lamp this reading needs stable (`_light_roles`) is not → wait, return
        its role ("" when every lamp was stable)."""
        roles = self._light_roles(step)
        for role in roles:
            lamp = self.instrument(role)
            if not isinstance(lamp, Settling):
                require(lamp, Settling, role, step.key)       # raises the PlanError
            # the check talks to the lamp: inside the retry loop like any instrument call
            if self.with_retry(step.key, role, lamp.is_stable):
                continue
            self._known.pop(role, None)
            self.state = "suspended"
            self._store_event("suspended", key=step.key, role=role, after_reading=after)
            self._emit("suspended", step.key, role=role, after_reading=after)
            self._emit("warning", step.key, message=f"{role} not stable: "
                       f"{'reading discarded, ' if after else ''}waiting to retake {step.key}")
            self.with_retry(step.key, role, lambda role=role: wait_until_stable(
                self, role, self.suspend_timeout_s, switch_on=False, key=step.key))
            self.state = "running"
            self._store_event("unsuspended", key=step.key, role=role)
            self._emit("unsuspended", step.key, role=role)
            return role
        return ""

    def _run_state_step(self, j: int, for_key: str) -> None:
        step = self.plan.steps[j]
        self._emit("step-started", step.key, kind=step.kind, label=step.describe(),
                   for_key=for_key)
        t0 = self.clock.now_s()
        for var in step.sets:
            self._known.pop(var, None)
        KINDS[step.kind].execute(step, self, for_key)
        self._known.update(step.sets)
        self._emit("step-finished", step.key, kind=step.kind,
                   duration_s=self.clock.now_s() - t0)

    # --- faults and prompts ----------------------------------------------------------------------
    def _fault_decision(self, key: str, role: str, exc: BaseException, attempt: int) -> str:
        # preparing an instrument (remote mode, homing) is not a reading: it cannot be skipped,
        # the run can only go on once the instrument is ready
        preparing = key.startswith("prepare/")
        if self.retry.persistent in ("skip", "abort"):
            choice = "abort" if preparing else self.retry.persistent
            self._store_event("operator", key=key, prompt="fault", answer=choice, automatic=True)
            return choice
        kind = "device-error" if isinstance(exc, DeviceError) else type(exc).__name__
        detail = str(exc).removeprefix(f"{role}: ")        # errors often name the role already
        hint = ("check the instrument's own display or error state" if isinstance(exc, DeviceError)
                else "check the cable, the port and that the instrument is powered on")
        question, choices = (("retry, or abort the run?", ("retry", "abort")) if preparing else
                             ("retry, skip this reading, or abort the run?",
                              ("retry", "skip", "abort")))
        req = PromptRequest(next(self._prompt_ids), key, "fault",
                            f"{role}: {detail} (after {attempt} attempt(s); {hint}) — {question}",
                            choices, {"role": role, "error": kind})
        return self._ask(req)

    def _ask(self, req: PromptRequest) -> str:
        self._pending_prompt = req
        self._answered.clear()
        self._answer = None
        self._emit("prompt", req.key, prompt=req)
        try:
            if self.operator is not None:
                choice = self.operator(req)
            else:
                while not self._answered.wait(0.1) and not self._stop.is_set():
                    pass
                if self._abort.is_set():
                    raise OperatorAbort("abort requested during a prompt")
                if not self._answered.is_set():
                    raise StopAtPrompt(f"the prompt of {req.key}")
                choice = self._answer or req.choices[0]
        finally:
            self._pending_prompt = None
        if choice not in req.choices:
            raise NormboxError(f"operator answered {choice!r}; expected one of "
                               f"{', '.join(req.choices)}")
        if req.kind == "fault" or choice != "ok":
            self._store_event("operator", key=req.key, prompt=req.kind, message=req.message,
                              answer=choice)
        self._emit("answer", req.key, prompt_id=req.id, answer=choice)
        if choice == "abort":
            raise OperatorAbort(f"operator aborted at {req.key}")
        return choice


__all__ = ["Engine", "LabAccess", "halt"]
