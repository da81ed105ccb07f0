"""The protocol engine: declared keyed steps, exact dry-run/ETA, pause/abort, crash resume.

A protocol declares its whole plan up front as a list of `Step`s.  Every step has a key unique
in the run and a kind:

    move         set a rotation stage:          params {"role", "angle_deg"}; sets {role: angle}
    wait-stable  switch the lamp on if off and wait until it reports stable; sets {role: "stable"}
    prompt       ask the operator (place a patch, mount a material); sets e.g. {"sample": "patch:7"}
    calibrate    instrument self-calibration (gonio dark + white references); sets e.g.
                 {"gonio_cal": "for:patch:7"}
    measure      one reading, committed to the store under the step's key

Only `measure` steps produce readings ("commit steps").  The other kinds *establish state*:
each declares the state variables it sets (`sets`), and every step declares the state it needs
(`requires`).  The engine executes state steps lazily: before a measurement it looks at what the
measurement requires, and runs — in plan order — the latest step before it that sets each
variable whose value is not known to be right.  In a fresh run this is exactly the declared
order; after a crash (physical state unknown: `known = {}`) it replays precisely the moves and
prompts the first missing measurement needs (re-move to the angle, re-prompt for the patch),
skips every committed key, and takes nothing twice.

Execution semantics follow bluesky's run engine ([BLUESKY] in docs/references.md): deferred pause
(the current reading finishes and is committed first), immediate abort (the busy instrument is
told to abort, motors stopped), suspension while the lamp is unstable with the interrupted
reading taken again, bounded retries of transient faults (`InstrumentTimeout`, `ProtocolError`,
a dropped port), and an operator decision (retry / skip / abort) for persistent ones — recorded
in the run's events.  Subscribers get `EngineEvent`s; a subscriber that raises is logged and
never stops the run.

Threading: `Engine.run()` executes in the calling thread (a worker thread for the TUI);
`pause()`, `resume()`, `stop()`, `abort()` and `answer()` may be called from any thread.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import itertools
import json
import logging
import math
import os
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

from normbox_lab.core.errors import (
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    NormboxError,
    NotReady,
    OperatorAbort,
    ProtocolError,
    StoreError,
)

log = logging.getLogger("normbox_lab.acquire.engine")

STEP_KINDS = ("move", "wait-stable", "prompt", "calibrate", "measure")
COMMIT_KINDS = ("measure",)


class PlanError(NormboxError):
    """A protocol declared an inconsistent plan (duplicate keys, unsatisfiable requirements)."""


# --- steps and plans ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Step:
    key: str
    kind: str
    params: Mapping[str, Any] = field(default_factory=dict)
    sets: Mapping[str, Any] = field(default_factory=dict)
    requires: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""

    @property
    def commits(self) -> bool:
        return self.kind in COMMIT_KINDS

    def describe(self) -> str:
        if self.label:
            return self.label
        p = dict(self.params)
        if self.kind == "move":
            return f"move {p.get('role')} to {p.get('angle_deg')}°"
        if self.kind == "prompt":
            return str(p.get("message", "operator prompt"))
        if self.kind == "wait-stable":
            return f"wait until {p.get('role', 'sphere')} is stable"
        if self.kind == "calibrate":
            return f"calibrate {p.get('role', 'gonio')}"
        role = p.get("role", "radiometer")
        if "theta_i_deg" in p:
            return f"{role}: θi {p['theta_i_deg']:g}°, θo {p['theta_o_deg']:g}°"
        if "patch" in p and "angle_deg" in p:
            return f"{role}: patch {p['patch']} at {p['angle_deg']:g}°"
        if "x_mm" in p:
            return f"{role}: panel x {p['x_mm']:+.0f} mm, y {p.get('y_mm', 0):+.0f} mm"
        return f"measure ({role})"


def move(key: str, role: str, angle_deg: float, label: str = "") -> Step:
    return Step(key, "move", {"role": role, "angle_deg": float(angle_deg)},
                sets={role: float(angle_deg)}, label=label)


def wait_stable(key: str, role: str = "sphere", *, timeout_s: float = 3600.0,
                level_percent: float | None = None) -> Step:
    params: dict[str, Any] = {"role": role, "timeout_s": float(timeout_s)}
    if level_percent is not None:
        params["level_percent"] = float(level_percent)
    return Step(key, "wait-stable", params, sets={role: "stable"})


def prompt(key: str, message: str, *, sets: Mapping[str, Any] | None = None,
           requires: Mapping[str, Any] | None = None, action: str | None = None,
           **data: Any) -> Step:
    params: dict[str, Any] = {"message": message, **data}
    if action is not None:
        params["action"] = action
    return Step(key, "prompt", params, sets=dict(sets or {}), requires=dict(requires or {}))


def calibrate(key: str, role: str = "gonio", *, sets: Mapping[str, Any] | None = None,
              requires: Mapping[str, Any] | None = None, **params: Any) -> Step:
    return Step(key, "calibrate", {"role": role, **params}, sets=dict(sets or {}),
                requires=dict(requires or {}))


def measure(key: str, role: str = "radiometer", *, requires: Mapping[str, Any] | None = None,
            **params: Any) -> Step:
    """A reading.  `params` go into the reading's metadata (angle_deg, patch, theta_i_deg ...);
    a gonio measurement needs theta_i_deg and theta_o_deg."""
    return Step(key, "measure", {"role": role, **params}, requires=dict(requires or {}))


class Plan:
    """An ordered, validated list of steps with the bookkeeping the lazy executor needs."""

    def __init__(self, protocol: str, parameters: Mapping[str, Any], steps: Iterable[Step],
                 on_reading: Callable[[Step, Any, dict[str, Any]], Sequence[str] | None]
                 | None = None):
        self.protocol = protocol
        #: optional protocol hook after each committed reading → warnings to flag in the run
        self.on_reading = on_reading
        self.parameters = dict(parameters)
        self.steps: list[Step] = list(steps)
        seen: set[str] = set()
        last_setter: dict[str, int] = {}
        #: setter_before[i][var] = index of the latest step before i that sets var
        self.setter_before: list[dict[str, int]] = []
        for i, s in enumerate(self.steps):
            if s.kind not in STEP_KINDS:
                raise PlanError(f"step {s.key!r}: unknown kind {s.kind!r}; known: "
                                f"{', '.join(STEP_KINDS)}")
            if not s.key or s.key in seen:
                raise PlanError(f"step key {s.key!r} is empty or not unique in the plan")
            seen.add(s.key)
            self.setter_before.append(dict(last_setter))
            for var, val in s.requires.items():
                j = last_setter.get(var)
                if j is None or self.steps[j].sets[var] != val:
                    raise PlanError(f"step {s.key!r} requires {var}={val!r} but the latest "
                                    f"earlier step setting {var} is "
                                    f"{self.steps[j].key + ' → ' + repr(self.steps[j].sets[var]) if j is not None else 'none'}")
            for var in s.sets:
                last_setter[var] = i
        self.commit_keys: list[str] = [s.key for s in self.steps if s.commits]

    def __len__(self) -> int:
        return len(self.steps)

    @property
    def planned(self) -> int:
        return len(self.commit_keys)

    def fingerprint(self) -> str:
        """Hash of the plan (keys, kinds, parameters, state): a resumed run must match it."""
        h = hashlib.sha256()
        for s in self.steps:
            h.update(json.dumps([s.key, s.kind, dict(s.params), dict(s.sets), dict(s.requires)],
                                sort_keys=True, default=str).encode())
        return h.hexdigest()[:16]

    def pending_state_steps(self, i: int, known: Mapping[str, Any]) -> list[int]:
        """State steps (in plan order) to run so that step i's requirements hold."""
        out: set[int] = set()

        def need(idx: int, state: dict[str, Any]) -> None:
            step = self.steps[idx]
            for var, val in step.requires.items():
                if state.get(var) == val:
                    continue
                j = self.setter_before[idx][var]
                if j not in out:
                    need(j, state)
                    out.add(j)
        need(i, dict(known))
        return sorted(out)


# --- protocols ---------------------------------------------------------------------------------

PROTOCOL_NAMES = {
    "reference-sweep": "normbox_lab.protocols.reference_sweep",
    "brdf-inplane": "normbox_lab.protocols.brdf_inplane",
    "light-map": "normbox_lab.protocols.light_map",
    "repeatability": "normbox_lab.protocols.repeatability",
}


def load_protocol(name_or_path: str) -> ModuleType:
    """A shipped protocol by name (`reference-sweep`) or any protocol file (`my_sweep.py`)."""
    if name_or_path in PROTOCOL_NAMES:
        return importlib.import_module(PROTOCOL_NAMES[name_or_path])
    path = Path(name_or_path)
    if path.suffix != ".py":
        raise PlanError(f"unknown protocol {name_or_path!r}; known: "
                        f"{', '.join(PROTOCOL_NAMES)} or a path to a .py file")
    if not path.is_file():
        raise PlanError(f"protocol file {path} does not exist")
    mod_name = "normbox_lab_user_protocol_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:8]
    spec = importlib.util.spec_from_file_location(mod_name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for attr in ("PARAMETERS", "steps"):
        if not hasattr(module, attr):
            raise PlanError(f"protocol file {path} defines no {attr}")
    return module


def coerce_param(default: Any, text: str) -> Any:
    """`--param K=V`: parse V like the default (JSON for lists, numbers, booleans)."""
    if isinstance(default, str):
        return text
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        if isinstance(default, list):
            value = [json.loads(v) if v.strip().lstrip("-").replace(".", "", 1).isdigit() else v
                     for v in text.split(",")]
        else:
            value = text
    if isinstance(default, bool) and not isinstance(value, bool):
        raise PlanError(f"expected true/false, got {text!r}")
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    return value


def resolve_parameters(module: ModuleType, lab_defaults: Mapping[str, Any] | None = None,
                       overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Protocol defaults ← lab config `[protocols.NAME]` ← command-line overrides."""
    params = dict(module.PARAMETERS)
    for source in (lab_defaults or {}, overrides or {}):
        for k, v in source.items():
            if k not in params:
                raise PlanError(f"unknown parameter {k!r}; known: {', '.join(params)}")
            params[k] = v
    return params


def build_plan(protocol: str, params: Mapping[str, Any] | None = None, lab: Any = None,
               *, module: ModuleType | None = None) -> Plan:
    module = module or load_protocol(protocol)
    full = resolve_parameters(module, None, params) if params is not None \
        else dict(module.PARAMETERS)
    hook = getattr(module, "on_reading", None)
    on_reading = None
    if hook is not None:
        def on_reading(step: Step, reading: Any, context: dict[str, Any]) -> Any:
            return hook(full, step, reading, context)
    return Plan(protocol, full, module.steps(full, lab), on_reading)


# --- events ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EngineEvent:
    kind: str           # run-started, step-started, step-finished, reading-stored, prompt,
                        # answer, warning, fault, suspended, unsuspended, paused, resumed,
                        # progress, run-finished
    run_id: int | None
    key: str = ""
    time_s: float = 0.0  # the lab clock (virtual seconds in a simulation)
    data: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PromptRequest:
    id: int
    key: str
    kind: str                 # "operator" (a prompt step) or "fault"
    message: str
    choices: tuple[str, ...]  # ("ok",) for a prompt step; ("retry", "skip", "abort") for faults
    data: Mapping[str, Any] = field(default_factory=dict)


Operator = Callable[[PromptRequest], str]


@dataclass(frozen=True)
class RetryPolicy:
    attempts: int = 3                      # tries per step for a transient fault
    transient: tuple[type[BaseException], ...] = (InstrumentTimeout, ProtocolError, OSError)
    persistent: str = "prompt"             # prompt | skip | abort (what to do without asking)


@dataclass(frozen=True)
class StepEstimate:
    key: str
    kind: str
    duration_s: float
    index: int


@dataclass(frozen=True)
class DryRun:
    plan: Plan
    executed: list[StepEstimate]           # steps the run would execute, in order
    prepare_s: float
    total_s: float
    remaining_keys: list[str]

    def lines(self) -> list[str]:
        out = [(f"protocol {self.plan.protocol}: {len(self.plan)} steps, "
               f"{self.plan.planned} readings, {len(self.remaining_keys)} to take")]
        out.append(f"  {'prepare':<22} {'init/home':<11} {self.prepare_s:9.1f} s")
        for e in self.executed:
            s = self.plan.steps[e.index]
            out.append(f"  {e.key:<22} {e.kind:<11} {e.duration_s:9.1f} s  {s.describe()}")
        out.append(f"ETA {format_duration(self.total_s)} ({self.total_s:.1f} s)")
        return out


@dataclass(frozen=True)
class RunResult:
    run_id: int
    uuid: str
    status: str                  # done | paused | interrupted (skipped readings) | aborted
    taken: int                   # readings committed in this segment
    done: int                    # readings committed in total
    planned: int
    skipped: tuple[str, ...]
    elapsed_s: float             # lab-clock seconds of this segment


def format_duration(seconds: float) -> str:
    if math.isnan(seconds):      # unknown
        return "?"
    seconds = max(0, int(round(float(seconds))))  # noqa: RUF046
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


# --- the engine --------------------------------------------------------------------------------

class _Skip(Exception):
    """The operator chose to skip the current measurement."""


class _StopAtPrompt(Exception):
    """`Engine.stop()` while the engine waited for an answer (no operator callable)."""


class Engine:
    """Runs one plan against a lab, committing every reading to the store.

    `lab` needs `.clock`, `.instrument(role)` (or `.instruments[role]`), and optionally
    `.operator` (a callable answering `PromptRequest`s), `.luminance_hint_cd_m2(step)`,
    `.record_identities(store, run_id)`.
    """

    def __init__(self, lab: Any, store: Any, plan: Plan, *, operator: Operator | None = None,
                 retry: RetryPolicy | None = None, wait_when_paused: bool = False,
                 poll_s: float = 1.0, suspend_timeout_s: float = 3600.0,
                 max_suspensions: int = 5,
                 segment_info: Mapping[str, Any] | None = None) -> None:
        self.lab = lab
        self.store = store
        self.plan = plan
        self.clock = lab.clock
        self.operator = operator if operator is not None else getattr(lab, "operator", None)
        self.retry = retry or RetryPolicy()
        self.wait_when_paused = wait_when_paused
        self.poll_s = float(poll_s)
        self.suspend_timeout_s = float(suspend_timeout_s)
        self.max_suspensions = int(max_suspensions)
        #: recorded with each segment event (e.g. the simulated world used)
        self.segment_info = dict(segment_info or {})
        self.run_id: int | None = None
        self.run_uuid = ""
        self.state = "idle"        # idle running paused suspended finished
        self._subs: dict[int, Callable[[EngineEvent], None]] = {}
        self._sub_ids = itertools.count(1)
        self._pause = threading.Event()
        self._stop = threading.Event()
        self._abort = threading.Event()
        self._resume = threading.Event()
        self._lock = threading.Lock()
        self._busy: tuple[str, Any] | None = None     # (role, instrument) while a step runs
        self._prompt_ids = itertools.count(1)
        self._pending_prompt: PromptRequest | None = None
        self._answer: str | None = None
        self._answered = threading.Event()
        self._known: dict[str, Any] = {}
        self._estimates: dict[str, float] = {}
        self._committed: set[str] = set()
        self._skipped: list[str] = []
        self._segment = 0
        self._ratio = 1.0
        self._hook_context: dict[str, Any] = {}
        self._remaining_s = 0.0

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
            self._halt_instrument(*busy)

    def answer(self, choice: str, prompt_id: int | None = None) -> None:
        """Answer the prompt the engine is waiting on (when no operator callable is set)."""
        p = self._pending_prompt
        if p is None or (prompt_id is not None and prompt_id != p.id):
            raise NormboxError("no such prompt is waiting for an answer")
        if choice not in p.choices:
            raise NormboxError(f"answer {choice!r} is not one of {', '.join(p.choices)}")
        self._answer = choice
        self._answered.set()

    @property
    def pending_prompt(self) -> PromptRequest | None:
        return self._pending_prompt

    # --- instruments -------------------------------------------------------------------------
    def _instrument(self, role: str) -> Any:
        getter = getattr(self.lab, "instrument", None)
        if getter is not None:
            return getter(role)
        return self.lab.instruments[role]

    def _has(self, role: str) -> bool:
        try:
            self._instrument(role)
        except (KeyError, NormboxError):
            return False
        return True

    @staticmethod
    def _halt_instrument(role: str, inst: Any) -> None:
        for name in ("abort", "stop"):
            fn = getattr(inst, name, None)
            if fn is not None:
                try:
                    fn()
                except (InstrumentError, OSError) as exc:
                    log.warning("%s.%s() during abort failed: %s", role, name, exc)
                return

    def _roles_used(self) -> list[str]:
        roles: list[str] = []
        for s in self.plan.steps:
            r = s.params.get("role")
            if r and r not in roles:
                roles.append(str(r))
        return roles

    # --- estimates ---------------------------------------------------------------------------
    def _luminance_hint(self, step: Step) -> float:
        if "luminance_cd_m2" in step.params:
            return float(step.params["luminance_cd_m2"])
        hint = getattr(self.lab, "luminance_hint_cd_m2", None)
        return float(hint(step)) if hint is not None else 20.0

    def _prompt_time_s(self) -> float:
        op = self.operator
        return float(getattr(op, "expected_response_s", 0.0) or 0.0)

    def _settle_estimate_s(self, lamp: Any, assume_stable: bool) -> float:
        if assume_stable:
            return 0.0
        est = getattr(lamp, "estimate_settle_time_s", None)
        settle = float(est()) if est is not None else 0.0
        if settle <= 0:
            return 0.0
        return math.ceil(settle / self.poll_s - 1e-9) * self.poll_s

    def estimate_step_s(self, step: Step, positions: dict[str, Any],
                        lamp_stable: dict[str, bool]) -> float:
        role = step.params.get("role", "")
        if step.kind == "move":
            stage = self._instrument(role)
            target = float(step.params["angle_deg"])
            t = float(stage.estimate_move_time_s(positions.get(role, 0.0), target))
            positions[role] = target
            return t
        if step.kind == "wait-stable":
            stable = lamp_stable.get(role, False)
            lamp_stable[role] = True
            return self._settle_estimate_s(self._instrument(role), stable)
        if step.kind == "prompt":
            return self._prompt_time_s()
        if step.kind == "calibrate":
            inst = self._instrument(role)
            est = getattr(inst, "estimate_calibrate_time_s", None)
            return float(est()) if est is not None else 0.0
        inst = self._instrument(role or "radiometer")
        if "theta_i_deg" in step.params:
            return self._estimate_gonio_s(role, inst, float(step.params["theta_i_deg"]),
                                          float(step.params["theta_o_deg"]), positions)
        return float(inst.estimate_measure_time_s(self._luminance_hint(step)))

    @staticmethod
    def _estimate_gonio_s(role: str, inst: Any, ti: float, to: float,
                          positions: dict[str, Any]) -> float:
        """The gonio's model counts the arm moves from where the arms are *now*; in a dry run
        they are where the previous geometry left them, so swap that part of the estimate."""
        est = getattr(inst, "estimate_measure_time_s", None)
        if est is None:
            return 0.0
        total = float(est(ti, to))
        arms = (getattr(inst, "light_arm", None), getattr(inst, "detector_arm", None))
        if all(hasattr(a, "estimate_move_time_s") for a in arms):
            key = f"{role}#geometry"
            if key not in positions:
                status = inst.status() if hasattr(inst, "status") else {}
                positions[key] = tuple(status.get("geometry_deg", (0.0, 0.0)))
            now = tuple(inst.status().get("geometry_deg", (0.0, 0.0))) \
                if hasattr(inst, "status") else (0.0, 0.0)
            light, detector = arms
            prev = positions[key]
            total += max(light.estimate_move_time_s(prev[0], ti),
                         detector.estimate_move_time_s(prev[1], to)) \
                - max(light.estimate_move_time_s(now[0], ti),
                      detector.estimate_move_time_s(now[1], to))
            positions[key] = (ti, to)
        return total

    def _initial_positions(self) -> tuple[dict[str, float], dict[str, bool], float]:
        """Current stage positions and lamp states; the homing time the prepare phase needs."""
        positions: dict[str, float] = {}
        lamps: dict[str, bool] = {}
        prepare_s = 0.0
        for role in self._roles_used():
            inst = self._instrument(role)
            if hasattr(inst, "estimate_move_time_s") and hasattr(inst, "is_homed"):
                if inst.is_homed():
                    positions[role] = float(inst.position_deg())
                else:
                    est = getattr(inst, "estimate_home_time_s", None)
                    prepare_s += float(est()) if est is not None else 0.0
                    positions[role] = 0.0
            elif hasattr(inst, "is_stable"):
                lamps[role] = bool(inst.is_stable())
        return positions, lamps, prepare_s

    def dry_run(self, committed: Iterable[str] = ()) -> DryRun:
        """The steps a run (or a resume with `committed` keys) would execute, and their ETA."""
        committed = set(committed)
        positions, lamps, prepare_s = self._initial_positions()
        known: dict[str, Any] = {}
        executed: list[StepEstimate] = []
        self._estimates = {}
        total = prepare_s

        def do(j: int) -> float:
            s = self.plan.steps[j]
            d = self.estimate_step_s(s, positions, lamps)
            executed.append(StepEstimate(s.key, s.kind, d, j))
            known.update(s.sets)
            return d

        last_commit = max((i for i, s in enumerate(self.plan.steps) if s.commits), default=-1)
        for i, s in enumerate(self.plan.steps):
            if s.commits:
                if s.key in committed:
                    continue
                cost = sum(do(j) for j in self.plan.pending_state_steps(i, known))
                cost += do(i)
                self._estimates[s.key] = cost
                total += cost
            elif i > last_commit:
                total += do(i)
        remaining = [k for k in self.plan.commit_keys if k not in committed]
        return DryRun(self.plan, executed, prepare_s, total, remaining)

    # --- running -----------------------------------------------------------------------------
    def run(self, resume: int | str | None = None) -> RunResult:
        """Execute the plan (a new run, or continue `resume`).  Returns when the run is done,
        paused (unless `wait_when_paused`), or aborted."""
        self._abort.clear()
        self._pause.clear()
        self._stop.clear()
        if resume is None:
            rec = self.store.create_run(
                self.plan.protocol, parameters=self.plan.parameters,
                lab_config=getattr(getattr(self.lab, "config", None), "text", ""),
                seeds={"lab": getattr(getattr(self.lab, "config", None), "seed", 0)},
                planned=self.plan.planned, status="running")
            self.run_id, self.run_uuid = rec.id, rec.uuid
            self._committed = set()
            self._segment = 1
            self._store_event("plan", fingerprint=self.plan.fingerprint(),
                              steps=len(self.plan), planned=self.plan.planned)
            self._store_event("segment", segment=1, pid=os.getpid(), **self.segment_info)
        else:
            rec = self.store.get_run(resume)
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
            self._segment = 1 + sum(1 for _, k, _ in events if k == "segment")
            self.store.set_run_status(rec.id, "running",
                                      detail={"resumed_from": rec.status,
                                              "committed": len(self._committed)})
            self._store_event("segment", segment=self._segment, pid=os.getpid(),
                              resumed_from=rec.status, committed=len(self._committed),
                              **self.segment_info)
        self._skipped = []
        self._known = {}     # physical state after a (re)start: unknown
        self.state = "running"
        t0 = self.clock.now_s()
        taken = 0
        status = "done"
        try:
            eta_s = self.dry_run(self._committed).total_s
        except (InstrumentError, OSError) as exc:      # no ETA is no reason to stop
            log.warning("no ETA: %s", exc)
            self._estimates, eta_s = {}, float("nan")
        self._remaining_s = sum(self._estimates.values())
        self._emit("run-started", run_uuid=self.run_uuid, segment=self._segment,
                   planned=self.plan.planned, done=len(self._committed), eta_s=eta_s,
                   resumed=resume is not None)
        try:
            self._prepare()
            last_commit = max((i for i, s in enumerate(self.plan.steps) if s.commits),
                              default=-1)
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
                    status = "paused"
                    break
                try:
                    self._take(i)
                    taken += 1
                except _Skip:
                    self._skipped.append(step.key)
        except _StopAtPrompt as exc:
            # stopped while a question was open: the unanswered step is asked again on resume
            status = "paused"
            self._store_event("stop", reason=f"stopped at the prompt of {exc}")
        except OperatorAbort as exc:
            status = "aborted"
            self._halt_all()
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
        done = len(self._committed)
        detail: dict[str, Any] = {"taken": taken, "done": done}
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
        """(Re-)initialise: remote mode, homing where needed; record instrument identities."""
        record = getattr(self.lab, "record_identities", None)
        if record is not None:
            record(self.store, self.run_id, segment=self._segment)
        for role in self._roles_used():
            inst = self._instrument(role)
            try:
                self._with_retry(f"prepare/{role}", role,
                                 lambda inst=inst: self._prepare_one(inst))
            except _Skip:
                self._emit("warning", f"prepare/{role}", message=f"{role} not prepared (skipped)")

    @staticmethod
    def _prepare_one(inst: Any) -> None:
        if hasattr(inst, "set_remote"):
            inst.set_remote(True)
        if hasattr(inst, "is_homed") and hasattr(inst, "home") and not inst.is_homed():
            inst.home(wait=True)

    def _halt_all(self) -> None:
        for role in self._roles_used():
            try:
                inst = self._instrument(role)
            except (KeyError, NormboxError):
                continue
            if hasattr(inst, "is_moving") or hasattr(inst, "abort"):
                self._halt_instrument(role, inst)

    # --- one measurement, with the state it needs ---------------------------------------------
    def _take(self, i: int) -> None:
        step = self.plan.steps[i]
        t_start = self.clock.now_s()
        suspensions = 0
        while True:
            for j in self.plan.pending_state_steps(i, self._known):
                self._run_state_step(j, for_key=step.key)
            if suspensions >= self.max_suspensions:
                # the lamp keeps dropping out: a persistent fault, the operator decides
                role = next((r for r, v in step.requires.items() if v == "stable"), "sphere")
                exc = NotReady(f"unstable during {suspensions} attempts at {step.key}",
                               instrument=role)
                self._store_event("fault", key=step.key, role=role, attempt=suspensions,
                                  error="NotReady", message=str(exc))
                choice = self._fault_decision(step.key, role, exc, suspensions)
                if choice == "skip":
                    self._store_event("skip", key=step.key, role=role, error=str(exc))
                    raise _Skip(step.key)
                suspensions = 0
            if self._lamp_unstable(step):
                suspensions += 1
                continue                      # suspended and back: re-establish, then measure
            self._emit("step-started", step.key, kind=step.kind, label=step.describe())
            reading = self._with_retry(step.key, step.params.get("role", "radiometer"),
                                       lambda: self._measure(step))
            if self._abort.is_set():
                raise OperatorAbort("abort requested")
            if self._lamp_unstable(step, after=True):
                suspensions += 1
                continue                      # the interrupted reading is taken again
            break
        meta = {k: v for k, v in step.params.items() if k != "role"}
        meta["segment"] = self._segment
        if step.requires:
            meta["requires"] = dict(step.requires)
        if hasattr(reading, "brdf_per_sr"):
            self.store.add_brdf(self.run_id, step.key, reading, metadata=meta)
        else:
            self.store.add_spectral(self.run_id, step.key, reading, metadata=meta)
        self._committed.add(step.key)
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
                   eta_s=remaining * self._ratio, remaining_estimate_s=remaining)

    def _measure(self, step: Step) -> Any:
        role = step.params.get("role", "radiometer")
        inst = self._instrument(role)
        self._busy = (role, inst)
        try:
            if "theta_i_deg" in step.params:
                return inst.measure_brdf(float(step.params["theta_i_deg"]),
                                         float(step.params["theta_o_deg"]))
            return inst.measure()
        finally:
            self._busy = None

    def _lamp_unstable(self, step: Step, after: bool = False) -> bool:
        """Suspender: the lamp this reading requires is not stable → wait, return True."""
        roles = [r for r, v in step.requires.items() if v == "stable"]
        if not roles:
            return False
        for role in roles:
            lamp = self._instrument(role)
            if lamp.is_stable():
                continue
            self._known.pop(role, None)
            self.state = "suspended"
            self._store_event("suspended", key=step.key, role=role, after_reading=after)
            self._emit("suspended", step.key, role=role, after_reading=after)
            self._emit("warning", step.key, message=f"{role} not stable: "
                       f"{'reading discarded, ' if after else ''}waiting to retake {step.key}")
            self._with_retry(step.key, role, lambda role=role: self._wait_stable(
                role, self.suspend_timeout_s, step.key, switch_on=False))
            self.state = "running"
            self._store_event("unsuspended", key=step.key, role=role)
            self._emit("unsuspended", step.key, role=role)
            return True
        return False

    def _wait_stable(self, role: str, timeout_s: float, key: str, *, switch_on: bool = True,
                     level_percent: float | None = None) -> None:
        lamp = self._instrument(role)
        if switch_on and lamp.state() == "off":
            if level_percent is not None:
                lamp.set_level_percent(level_percent)
            lamp.set_output(True)
        deadline = self.clock.now_s() + timeout_s
        while not lamp.is_stable():
            if self._abort.is_set():
                raise OperatorAbort("abort requested")
            if lamp.state() == "off":
                raise NotReady(f"{role} is off", instrument=role)
            if self.clock.now_s() >= deadline:
                raise NotReady(f"{role} not stable after {timeout_s:.0f} s", instrument=role)
            self.clock.sleep(self.poll_s)

    def _run_state_step(self, j: int, for_key: str) -> None:
        step = self.plan.steps[j]
        role = step.params.get("role", "")
        self._emit("step-started", step.key, kind=step.kind, label=step.describe(),
                   for_key=for_key)
        t0 = self.clock.now_s()
        for var in step.sets:
            self._known.pop(var, None)
        if step.kind == "move":
            def act() -> None:
                stage = self._instrument(role)
                self._busy = (role, stage)
                try:
                    stage.move_to(float(step.params["angle_deg"]), wait=True)
                finally:
                    self._busy = None
            self._with_retry(for_key, role, act)
        elif step.kind == "wait-stable":
            self._with_retry(for_key, role, lambda: self._wait_stable(
                role, float(step.params.get("timeout_s", 3600.0)), step.key,
                level_percent=step.params.get("level_percent")))
        elif step.kind == "prompt":
            req = PromptRequest(next(self._prompt_ids), step.key, "operator",
                                str(step.params.get("message", "")), ("ok",),
                                {k: v for k, v in step.params.items() if k != "message"})
            self._ask(req)
        elif step.kind == "calibrate":
            def cal() -> None:
                inst = self._instrument(role)
                self._busy = (role, inst)
                try:
                    result = inst.calibrate()
                finally:
                    self._busy = None
                self._store_calibration(step, result)
            self._with_retry(for_key, role, cal)
        self._known.update(step.sets)
        self._emit("step-finished", step.key, kind=step.kind,
                   duration_s=self.clock.now_s() - t0)

    def _store_calibration(self, step: Step, result: Any) -> None:
        """Keep calibration data (dark/white references) as an artifact of the run."""
        arrays = None
        if isinstance(result, Mapping):
            arrays = {k: v for k, v in result.items() if hasattr(v, "__len__")}
        refs = getattr(self._instrument(step.params.get("role", "gonio")), "references", None)
        if arrays is None and callable(refs):
            arrays = dict(refs())
        self.store.add_artifact("calibration", step.key, arrays or {},
                                metadata={"segment": self._segment, **dict(step.params)},
                                run_ref=self.run_id)

    # --- faults and prompts ----------------------------------------------------------------------
    def _with_retry(self, key: str, role: str, action: Callable[[], Any]) -> Any:
        attempt = 0
        while True:
            if self._abort.is_set():
                raise OperatorAbort("abort requested")
            attempt += 1
            try:
                return action()
            except OperatorAbort:
                raise
            except (InstrumentError, OSError) as exc:
                if self._abort.is_set():
                    raise OperatorAbort("abort requested") from exc
                transient = isinstance(exc, self.retry.transient)
                self._store_event("fault", key=key, role=role, attempt=attempt,
                                  error=type(exc).__name__, message=str(exc))
                self._emit("fault", key, role=role, attempt=attempt, error=repr(exc),
                           transient=transient)
                self._invalidate_role(role)
                if transient and attempt < self.retry.attempts:
                    self._emit("warning", key, message=f"{role}: {exc} — retry "
                               f"{attempt}/{self.retry.attempts - 1}")
                    self._recover(role)
                    continue
                choice = self._fault_decision(key, role, exc, attempt)
                if choice == "retry":
                    attempt = 0
                    self._recover(role)
                    continue
                if choice == "skip":
                    self._store_event("skip", key=key, role=role, error=str(exc))
                    raise _Skip(key) from exc
                raise OperatorAbort(f"operator aborted after {type(exc).__name__} at {key}") \
                    from exc

    def _invalidate_role(self, role: str) -> None:
        self._known.pop(role, None)

    def _recover(self, role: str) -> None:
        inst = self._instrument(role) if role and self._has(role) else None
        fn = getattr(inst, "recover", None)
        if fn is not None:
            try:
                fn()
            except (InstrumentError, OSError) as exc:
                log.warning("%s.recover() failed: %s", role, exc)

    def _fault_decision(self, key: str, role: str, exc: BaseException, attempt: int) -> str:
        if self.retry.persistent in ("skip", "abort"):
            choice = self.retry.persistent
            self._store_event("operator", key=key, prompt="fault", answer=choice, automatic=True)
            return choice
        kind = "device-error" if isinstance(exc, DeviceError) else type(exc).__name__
        req = PromptRequest(next(self._prompt_ids), key, "fault",
                            f"{role}: {exc} (after {attempt} attempt(s)) — retry, skip this "
                            "reading, or abort the run?", ("retry", "skip", "abort"),
                            {"role": role, "error": kind})
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
                    raise _StopAtPrompt(req.key)
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


__all__ = [
    "PROTOCOL_NAMES",
    "STEP_KINDS",
    "DryRun",
    "Engine",
    "EngineEvent",
    "Plan",
    "PlanError",
    "PromptRequest",
    "RetryPolicy",
    "RunResult",
    "Step",
    "build_plan",
    "calibrate",
    "coerce_param",
    "format_duration",
    "load_protocol",
    "measure",
    "move",
    "prompt",
    "resolve_parameters",
    "wait_stable",
]
