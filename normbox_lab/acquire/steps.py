"""Steps and step kinds: what a protocol declares, and how each kind is estimated and executed.

A step is data (`Step`: key, kind, params, the state it `sets` and `requires`); its kind is a
class here with `estimate_s()` (the dry run's timing, from the instruments' timing models) and
`execute()` (the real thing, through the runner's retry policy).  Kinds talk to instruments
only through capabilities (`normbox_lab.core.capabilities`): a step kind never knows which
instrument it drives, only what the instrument can do.  A new step kind is one class here plus
its entry in `KINDS`; a new instrument only has to have the capabilities the steps ask for.

    move         Movable: set a stage;                 params {"role", "angle_deg"}
    wait-stable  Switchable + Settling: lamp on if off, wait until stable; sets {role: "stable"}
    prompt       ask the operator (place a patch, mount a material); sets e.g. {"sample": ...}
    calibrate    Calibratable: take the instrument's references, stored as a run artifact
    measure      SpectrumReadable or BrdfReadable: one reading, committed under the step's key
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sized
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

from normbox_lab.acquire.store import ReadingRecord, brdf_record, spectral_record
from normbox_lab.acquire.store_api import Store
from normbox_lab.core import errors
from normbox_lab.core.capabilities import (
    BrdfReadable,
    Calibratable,
    LampLevel,
    Movable,
    Settling,
    SpectrumReadable,
    Switchable,
)
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import NotReady, OperatorAbort
from normbox_lab.core.types import ANGLE_DEG, BrdfReading

PlanError = errors.PlanError   # defined with the hierarchy (core.errors); here by its old name


C = TypeVar("C")


def require(inst: Any, cap: type[C], role: str, key: str) -> C:
    """`inst` as capability `cap`, or a PlanError that names what is missing."""
    if not isinstance(inst, cap):
        raise PlanError(f"step {key!r}: the {role} ({type(inst).__name__}) is not "
                        f"{cap.__name__}")
    return inst


# --- the step ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Step:
    key: str
    kind: str
    params: Mapping[str, Any] = field(default_factory=dict)
    sets: Mapping[str, Any] = field(default_factory=dict)
    requires: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""

    @property
    def role(self) -> str:
        return str(self.params.get("role", ""))

    @property
    def commits(self) -> bool:
        return KINDS[self.kind].commits

    def describe(self) -> str:
        return self.label or KINDS[self.kind].describe(self)


def move(key: str, role: str, angle_deg: float, label: str = "") -> Step:
    return Step(key, "move", {"role": role, ANGLE_DEG: float(angle_deg)},
                sets={role: float(angle_deg)}, label=label)


def wait_stable(key: str, role: str, *, timeout_s: float = 3600.0,
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
    a BRDF instrument's reading needs theta_i_deg and theta_o_deg."""
    return Step(key, "measure", {"role": role, **params}, requires=dict(requires or {}))


# --- what a kind may use -----------------------------------------------------------------------

@dataclass
class EstimateContext:
    """The dry run's view of the lab: instruments (for their timing models) and the state the
    steps so far have left (stage positions, lamps known stable)."""

    instrument: Callable[[str], Any]
    luminance_hint_cd_m2: Callable[[Step], float]
    prompt_time_s: float
    poll_s: float
    positions: dict[str, Any] = field(default_factory=dict)
    lamps_stable: dict[str, bool] = field(default_factory=dict)


class StepRunner(Protocol):
    """What the runner offers a step kind while it executes."""

    clock: Clock
    poll_s: float
    store: Store
    run_id: int | None
    segment: int

    def instrument(self, role: str) -> Any: ...
    def busy(self, role: str, inst: Any) -> AbstractContextManager[None]:
        """Mark `inst` as the one an abort must halt while the block runs."""
        ...
    def with_retry(self, key: str, role: str, action: Callable[[], Any]) -> Any: ...
    def has(self, role: str, capability: type) -> bool:
        """`isinstance(instrument(role), capability)`, cached while the run goes on."""
        ...
    def abort_requested(self) -> bool: ...
    def stop_requested(self) -> bool:
        """`Engine.stop()` was called: a wait (a lamp warm-up) ends the segment paused."""
        ...
    def ask_operator(self, key: str, message: str, data: Mapping[str, Any]) -> str: ...


@runtime_checkable
class TimedOperator(Protocol):
    """An operator that says how long a person takes to answer (for the ETA)."""

    expected_response_s: float


def wait_until_stable(run: StepRunner, role: str, timeout_s: float, *, switch_on: bool = True,
                      level_percent: float | None = None, key: str = "") -> None:
    """Switch the lamp on if it is off (and `switch_on`), then wait until it is stable."""
    lamp = require(run.instrument(role), Settling, role, key)
    switch = require(lamp, Switchable, role, key) if switch_on else None
    if switch is not None and switch.state() == "off":
        if level_percent is not None:
            require(lamp, LampLevel, role, key).set_level_percent(level_percent)
        switch.set_output(True)
    deadline = run.clock.now_s() + timeout_s
    while not lamp.is_stable():
        if run.abort_requested():
            raise OperatorAbort("abort requested")
        if run.stop_requested():       # quitting: no need to wait minutes for the warm-up
            from normbox_lab.acquire.retry import StopAtPrompt

            raise StopAtPrompt(f"the {role} warm-up of {key or role}")
        if isinstance(lamp, Switchable) and lamp.state() == "off":
            raise NotReady(f"{role} is off", instrument=role)
        if run.clock.now_s() >= deadline:
            raise NotReady(f"{role} not stable after {timeout_s:.0f} s", instrument=role)
        for _ in range(4):             # the poll's wait in quarters: a stop is seen at once
            run.clock.sleep(run.poll_s / 4)
            if run.stop_requested():
                break


# --- the kinds ---------------------------------------------------------------------------------

class StepKind:
    """One kind of step.  State kinds (`commits = False`) establish state and return nothing;
    commit kinds return a reading that `commit()` stores under the step's key."""

    name: ClassVar[str]
    commits: ClassVar[bool] = False

    def describe(self, step: Step) -> str:
        return f"{self.name} {step.role}".strip()

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        return 0.0

    def execute(self, step: Step, run: StepRunner, for_key: str) -> Any:
        raise NotImplementedError

    def commit(self, step: Step, reading: Any, run: StepRunner,
               metadata: dict[str, Any]) -> ReadingRecord:
        """Store `reading` under the step's key; returns what was stored (the quality gates
        check it)."""
        raise NotImplementedError


class MoveKind(StepKind):
    name = "move"

    def describe(self, step: Step) -> str:
        return f"move {step.role} to {step.params.get('angle_deg')}°"

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        stage = require(est.instrument(step.role), Movable, step.role, step.key)
        target = float(step.params[ANGLE_DEG])
        t = float(stage.estimate_move_time_s(est.positions.get(step.role, 0.0), target))
        est.positions[step.role] = target
        return t

    def execute(self, step: Step, run: StepRunner, for_key: str) -> None:
        def act() -> None:
            stage = require(run.instrument(step.role), Movable, step.role, step.key)
            with run.busy(step.role, stage):
                stage.move_to(float(step.params[ANGLE_DEG]), wait=True)
        run.with_retry(for_key, step.role, act)


class WaitStableKind(StepKind):
    name = "wait-stable"

    def describe(self, step: Step) -> str:
        return f"wait until {step.role or 'the lamp'} is stable"

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        stable = est.lamps_stable.get(step.role, False)
        est.lamps_stable[step.role] = True
        if stable:
            return 0.0
        lamp = require(est.instrument(step.role), Settling, step.role, step.key)
        settle = float(lamp.estimate_settle_time_s())
        if settle <= 0:
            return 0.0
        return math.ceil(settle / est.poll_s - 1e-9) * est.poll_s

    def execute(self, step: Step, run: StepRunner, for_key: str) -> None:
        level = step.params.get("level_percent")
        run.with_retry(for_key, step.role, lambda: wait_until_stable(
            run, step.role, float(step.params.get("timeout_s", 3600.0)),
            level_percent=None if level is None else float(level), key=step.key))


class PromptKind(StepKind):
    name = "prompt"

    def describe(self, step: Step) -> str:
        return str(step.params.get("message", "operator prompt"))

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        return est.prompt_time_s

    def execute(self, step: Step, run: StepRunner, for_key: str) -> None:
        run.ask_operator(step.key, str(step.params.get("message", "")),
                         {k: v for k, v in step.params.items() if k != "message"})


class CalibrateKind(StepKind):
    name = "calibrate"

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        inst = require(est.instrument(step.role), Calibratable, step.role, step.key)
        return float(inst.estimate_calibrate_time_s())

    def execute(self, step: Step, run: StepRunner, for_key: str) -> None:
        def cal() -> None:
            inst = require(run.instrument(step.role), Calibratable, step.role, step.key)
            with run.busy(step.role, inst):
                result = inst.calibrate()
            # the references (dark/white arrays) are kept as an artifact of the run
            arrays = {k: v for k, v in (result or {}).items() if isinstance(v, Sized)}
            run.store.add_artifact("calibration", step.key, arrays,
                                   metadata={"segment": run.segment, **dict(step.params)},
                                   run_ref=run.run_id)
        run.with_retry(for_key, step.role, cal)


class MeasureKind(StepKind):
    """One reading from a SpectrumReadable (spectral radiance) or a BrdfReadable (BRDF at the
    step's θi/θo) instrument — the capability decides, not the step."""

    name = "measure"
    commits = True

    def describe(self, step: Step) -> str:
        details = ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}"
                            for k, v in step.params.items() if k != "role")
        return f"{step.role}: {details}" if details else f"measure ({step.role})"

    @staticmethod
    def _geometry(step: Step) -> tuple[float, float]:
        try:
            return float(step.params["theta_i_deg"]), float(step.params["theta_o_deg"])
        except KeyError as exc:
            raise PlanError(f"step {step.key!r}: a BRDF reading needs theta_i_deg and "
                            "theta_o_deg") from exc

    def estimate_s(self, step: Step, est: EstimateContext) -> float:
        inst = est.instrument(step.role)
        if isinstance(inst, BrdfReadable):
            ti, to = self._geometry(step)
            where = f"{step.role}#geometry"        # where the previous reading left the arms
            t = float(inst.estimate_measure_time_s(ti, to,
                                                   from_geometry_deg=est.positions.get(where)))
            est.positions[where] = (ti, to)
            return t
        inst = require(inst, SpectrumReadable, step.role, step.key)
        return float(inst.estimate_measure_time_s(est.luminance_hint_cd_m2(step)))

    def execute(self, step: Step, run: StepRunner, for_key: str) -> Any:
        role = step.role
        inst = run.instrument(role)
        with run.busy(role, inst):
            if run.has(role, BrdfReadable):
                return inst.measure_brdf(*self._geometry(step))
            if not run.has(role, SpectrumReadable):
                require(inst, SpectrumReadable, role, step.key)   # raises the PlanError
            return inst.measure()

    def commit(self, step: Step, reading: Any, run: StepRunner,
               metadata: dict[str, Any]) -> ReadingRecord:
        record = (brdf_record(reading, metadata) if isinstance(reading, BrdfReading)
                  else spectral_record(reading, metadata))
        run.store.add_record(run.run_id, step.key, record)
        return record


#: kind name → kind; a protocol's steps may use these names
KINDS: dict[str, StepKind] = {k.name: k for k in (
    MoveKind(), WaitStableKind(), PromptKind(), CalibrateKind(), MeasureKind())}
STEP_KINDS: tuple[str, ...] = tuple(KINDS)
COMMIT_KINDS: tuple[str, ...] = tuple(n for n, k in KINDS.items() if k.commits)


def iter_roles(steps: list[Step]) -> Iterator[str]:
    seen: set[str] = set()
    for s in steps:
        if s.role and s.role not in seen:
            seen.add(s.role)
            yield s.role


__all__ = [
    "COMMIT_KINDS",
    "KINDS",
    "STEP_KINDS",
    "EstimateContext",
    "PlanError",
    "Step",
    "StepKind",
    "StepRunner",
    "TimedOperator",
    "calibrate",
    "measure",
    "move",
    "prompt",
    "require",
    "wait_stable",
    "wait_until_stable",
]
