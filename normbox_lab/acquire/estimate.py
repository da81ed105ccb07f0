"""Dry run and ETA: the steps a run (or a resume) would execute, timed by the instruments'
own timing models (each capability carries one), so the estimate is exact where the models are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from normbox_lab.acquire.plan import Plan
from normbox_lab.acquire.steps import KINDS, EstimateContext
from normbox_lab.core.capabilities import Homeable, Movable, Settling


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
        total = (f"{self.total_s:.1f} s" if math.isfinite(self.total_s)
                 and self.total_s < _DAYS_FROM_S else format_duration(self.total_s))
        out.append(f"ETA {format_duration(self.total_s)} ({total})")
        return out


#: beyond this a duration is written in days (a lab time of 10^300 s stays one short word)
_DAYS_FROM_S = 100 * 86400.0


def format_duration(seconds: float) -> str:
    """"4:05", "1:02:03"; "?" when unknown (NaN), "∞" for an infinite time, days ("1.2e+303
    days") beyond 100 days.  Never raises for a number."""
    try:
        seconds = float(seconds)
    except OverflowError:        # an int beyond a float
        seconds = math.inf if seconds > 0 else 0.0
    if math.isnan(seconds):      # unknown
        return "?"
    if math.isinf(seconds):
        return "∞" if seconds > 0 else "0:00"
    if seconds >= _DAYS_FROM_S:
        return f"{seconds / 86400:.3g} days"
    seconds = max(0, int(round(seconds)))  # noqa: RUF046
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def initial_state(plan: Plan, instrument: Callable[[str], Any],
                  est: EstimateContext) -> float:
    """Current stage positions and lamp states into `est`; returns the homing time the
    prepare phase needs."""
    prepare_s = 0.0
    for role in plan.roles:
        inst = instrument(role)
        if isinstance(inst, Movable):
            if isinstance(inst, Homeable) and not inst.is_homed():
                prepare_s += float(inst.estimate_home_time_s())
                est.positions[role] = 0.0
            else:
                est.positions[role] = float(inst.position_deg())
        elif isinstance(inst, Settling):
            est.lamps_stable[role] = bool(inst.is_stable())
    return prepare_s


def dry_run(plan: Plan, est: EstimateContext,
            committed: Iterable[str] = ()) -> tuple[DryRun, dict[str, float]]:
    """The steps a run (or a resume with `committed` keys) would execute, with their ETA, and
    the estimated cost of each reading still to take (its state steps included)."""
    committed = set(committed)
    prepare_s = initial_state(plan, est.instrument, est)
    known: dict[str, Any] = {}
    executed: list[StepEstimate] = []
    per_key: dict[str, float] = {}
    total = prepare_s

    def do(j: int) -> float:
        s = plan.steps[j]
        d = KINDS[s.kind].estimate_s(s, est)
        executed.append(StepEstimate(s.key, s.kind, d, j))
        known.update(s.sets)
        return d

    last_commit = plan.last_commit_index
    for i, s in enumerate(plan.steps):
        if s.commits:
            if s.key in committed:
                continue
            cost = sum(do(j) for j in plan.pending_state_steps(i, known))
            cost += do(i)
            per_key[s.key] = cost
            total += cost
        elif i > last_commit:
            total += do(i)
    remaining = [k for k in plan.commit_keys if k not in committed]
    return DryRun(plan, executed, prepare_s, total, remaining), per_key


def prompts_left(plan: Plan, committed: Iterable[str]) -> int:
    """Operator prompts the readings still to take will ask: a prompt counts when a reading it
    serves (up to the next prompt that sets the same state) is not committed.  A reference
    sweep asks one per reading, a BRDF run one per material, repeatability one in all.

    Called after every reading: the keys each prompt serves are the plan's
    (`Plan.prompt_serves`, found once), so a call is one set test per prompt."""
    done = committed if isinstance(committed, (set, frozenset)) else set(committed)
    return sum(1 for keys in plan.prompt_serves if not keys <= done)


class RemainingTime:
    """The time a run still takes on the console's clock, right from its first reading.

    A reading's time is the operator's (answering its prompts: not scaled, measured per
    prompt) plus the instruments' (the timing model's lab seconds × the time scale, plus a
    per-reading overhead: drivers, emulators, the store).  The first reading of a segment also
    pays one-off costs the model does not know (first move from wherever the stage stood, the
    first measurement's set-up): it is kept out of the instruments' rate as soon as a later
    reading tells it, and only the model (× the time scale) prices the rest until then.  The
    operator's answer time is the mean over this segment's prompts, × the prompts left.
    One-off waits (preparation, lamp warm-ups, suspensions, pauses) count for nothing.

    Times are console-clock seconds passed in by the caller (no clock here); model costs are lab
    seconds of the engine's timing model, prompts excluded.
    """

    def __init__(self) -> None:
        self.start(0.0)

    def start(self, now_s: float, model_left_s: float | None = None,
              prompts_left: int | None = None) -> None:
        """A segment starts (its preparation is a one-off wait until `active`)."""
        self.active = False                 # measuring (not in a one-off wait)
        self.active_since_s = now_s
        self.inactive_since_s = now_s
        self.active_total_s = 0.0           # active time before `active_since_s`
        self.prompt_since_s: float | None = None
        self.answers_s: list[float] = []
        self.person_in_reading_s = 0.0      # prompt time within the reading under way
        self.prompts_in_reading = 0
        self.last_reading_active_s = 0.0
        self.model_left_s = model_left_s
        self.prompts_left = prompts_left
        #: per reading: (model lab s, instrument console s), the segment's first reading first
        self.readings: list[tuple[float | None, float]] = []

    # --- what happens ---------------------------------------------------------------------
    def active_s(self, now_s: float) -> float:
        return self.active_total_s + (now_s - self.active_since_s if self.active else 0.0)

    def set_active(self, now_s: float, on: bool) -> None:
        """`on`: measuring; off: a one-off wait (preparation, warm-up, suspension, pause)."""
        if on and not self.active:
            self.active, self.active_since_s = True, now_s
        elif not on and self.active:
            self.active_total_s += now_s - self.active_since_s
            self.active, self.inactive_since_s = False, now_s

    def was_active(self) -> None:
        """A reading came with no step event since the wait began: it was no wait (the time
        since counts as measuring)."""
        if not self.active:
            self.active, self.active_since_s = True, self.inactive_since_s

    def prompt(self, now_s: float) -> None:
        if self.prompt_since_s is None:
            self.prompt_since_s = now_s

    def answered(self, now_s: float) -> None:
        if self.prompt_since_s is not None:
            took = max(0.0, now_s - self.prompt_since_s)
            self.answers_s.append(took)
            self.person_in_reading_s += took
            self.prompts_in_reading += 1
            self.prompt_since_s = None

    def reading(self, now_s: float, model_left_s: float | None,
                prompts_left: int | None, count: int = 1) -> None:
        """`count` readings were stored (one, unless events were missed); `model_left_s`: the
        model's instrument lab seconds of the readings left; `prompts_left`: their prompts."""
        count = max(1, int(count))
        active = self.active_s(now_s)
        took = active - self.last_reading_active_s
        self.last_reading_active_s = active
        model = None
        if model_left_s is not None and self.model_left_s is not None:
            model = max(0.0, self.model_left_s - model_left_s) / count
        instruments = max(0.0, took - self.person_in_reading_s) / count
        self.readings.extend([(model, instruments)] * count)
        self.person_in_reading_s, self.prompts_in_reading = 0.0, 0
        self.model_left_s, self.prompts_left = model_left_s, prompts_left

    # --- the estimate ---------------------------------------------------------------------
    def answer_s(self) -> float | None:
        """The operator's mean answer time so far (None before the first answer)."""
        return sum(self.answers_s) / len(self.answers_s) if self.answers_s else None

    def instrument_model(self, time_scale: float) -> tuple[float, float]:
        """(a, b): a reading's instrument time = a + b × its model cost (lab s).  From the
        readings after the segment's first (whose one-off costs would inflate the rate):
        b = the time scale, a = their mean overhead; with only the first reading, a = 0."""
        steady = self.readings[1:]
        if not steady:
            return 0.0, time_scale
        if all(m is not None for m, _ in steady):
            over = [t - time_scale * float(m) for m, t in steady]
            return max(0.0, sum(over) / len(over)), time_scale
        # no model: the plain mean of the steady readings
        return sum(t for _, t in steady) / len(steady), 0.0

    def remaining_s(self, now_s: float, time_scale: float, left: int) -> float | None:
        """The estimate (None before the segment's first reading)."""
        if not self.readings:
            return None
        if left <= 0:
            return 0.0
        a, b = self.instrument_model(time_scale)
        if b > 0 and self.model_left_s is not None:
            instruments = a * left + b * self.model_left_s
        elif b == 0 and len(self.readings) > 1:
            instruments = a * left
        else:                                   # no model at all: the readings so far
            instruments = sum(t for _, t in self.readings) / len(self.readings) * left
        answer = self.answer_s()
        prompts = self.prompts_left if self.prompts_left is not None else left
        person = (answer or 0.0) * prompts
        estimate = instruments + person
        # the reading under way counts down (never below what one more reading takes)
        under_way = self.active_s(now_s) - self.last_reading_active_s
        return max(estimate * (left - 1) / left, estimate - max(0.0, under_way))


__all__ = ["DryRun", "RemainingTime", "StepEstimate", "dry_run", "format_duration",
           "initial_state", "prompts_left"]
