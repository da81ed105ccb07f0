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


__all__ = ["DryRun", "StepEstimate", "dry_run", "format_duration", "initial_state"]
