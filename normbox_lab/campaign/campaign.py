"""`normbox-lab sim campaign`: deterministic simulation testing of the whole lab.

    run_campaign(scenarios=30, seed=11, jobs=1)     # prints one line per scenario, then
                                                    # "30 scenarios: V violations"

Scenario i of seed S is `scenario.draw(S, i)`; it is executed by `harness.execute` (the real
command line in forked processes, with kills, pauses and emergency stops) and judged by
`invariants.check`.  A failing scenario is shrunk (`shrink`: greedy delta debugging over its
faults, its actions and its protocol parameters, keeping a candidate while it still shows the
same violation class) and printed with the one command that reproduces the shrunk scenario:
``normbox-lab sim campaign --replay 'JSON'``.  V counts (scenario, violation class) pairs.
"""

from __future__ import annotations

import multiprocessing
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from normbox_lab.campaign.harness import execute, preload
from normbox_lab.campaign.invariants import Violation, check
from normbox_lab.campaign.scenario import Scenario, draw

#: shrinking stops after this many candidate runs per failing scenario
SHRINK_BUDGET = 40


@dataclass
class Result:
    scenario: Scenario
    violations: list[Violation]
    wall_s: float
    segments: int
    status: str | None
    readings: int
    shrunk: Scenario | None = None
    shrink_runs: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def classes(self) -> list[str]:
        return sorted({v.cls for v in self.violations})


def run_one(scenario: Scenario, root: Path, *, keep: bool = False, tag: str = "") -> Result:
    """Execute and check one scenario in ``root/NAME[tag]``."""
    workdir = root / f"{scenario.name}{tag}"
    if workdir.exists():
        shutil.rmtree(workdir)
    t0 = time.monotonic()
    try:
        ex = execute(scenario, workdir)
        violations = check(ex)
        status, readings = _status(ex)
        segments = len(ex.segments)
    finally:
        if not keep:
            shutil.rmtree(workdir, ignore_errors=True)
    return Result(scenario, violations, time.monotonic() - t0, segments, status, readings)


def _status(ex) -> tuple[str | None, int]:
    from normbox_lab.acquire.store import Store

    if ex.run_uuid is None:
        return None, 0
    try:
        with Store(ex.store) as s:
            rec = s.get_run(ex.run_uuid)
            return rec.status, rec.done
    except Exception:                    # noqa: BLE001 - the checks have reported it
        return None, 0


# --- shrinking --------------------------------------------------------------------------------
def _smaller_params(s: Scenario) -> Iterator[Scenario]:
    for k, v in sorted(s.params.items()):
        if isinstance(v, list) and len(v) > 1:
            half = len(v) // 2
            yield s.with_(params={**s.params, k: v[:half]})
            yield s.with_(params={**s.params, k: v[half:]})
        elif isinstance(v, int) and not isinstance(v, bool) and k in ("repeats", "rows",
                                                                       "columns") and v > 1:
            yield s.with_(params={**s.params, k: v - 1})


def candidates(s: Scenario) -> Iterator[Scenario]:
    """Smaller scenarios, the biggest cuts first."""
    if len(s.faults) > 1:
        yield s.with_(faults=())
    if len(s.actions) > 1:
        yield s.with_(actions=())
    for i in range(len(s.faults)):
        yield s.with_(faults=s.faults[:i] + s.faults[i + 1:])
    for i in range(len(s.actions)):
        yield s.with_(actions=s.actions[:i] + s.actions[i + 1:])
    for i, a in enumerate(s.actions):
        if a.nth > 1:
            yield s.with_(actions=(*s.actions[:i], a.__class__(a.what, a.event, 1),
                                   *s.actions[i + 1:]))
    yield from _smaller_params(s)


def shrink(scenario: Scenario, cls: str, root: Path, *,
           budget: int = SHRINK_BUDGET) -> tuple[Scenario, int]:
    """The smallest scenario found that still shows violation class `cls`, and the number of
    candidate runs it took."""
    current, runs = scenario, 0
    improved = True
    while improved and runs < budget:
        improved = False
        for cand in candidates(current):
            if runs >= budget:
                break
            runs += 1
            r = run_one(cand, root, tag=f"-shrink{runs}")
            if cls in r.classes:
                current, improved = cand, True
                break
    return current, runs


def replay_command(s: Scenario) -> str:
    return f"normbox-lab sim campaign --replay '{s.to_json()}'"


# --- the campaign ---------------------------------------------------------------------------
def _worker(args: tuple[int, int, str, bool, float, int]) -> Result:
    seed, index, root, keep, normbox_share, max_faults = args
    return run_one(draw(seed, index, normbox_share=normbox_share, max_faults=max_faults),
                   Path(root), keep=keep)


def _format(r: Result) -> str:
    verdict = "ok" if not r.violations else f"{len(r.classes)} violation class(es)"
    return (f"{r.scenario.name:<10} {r.status or 'no run':<11} {r.readings:>3} readings "
            f"{r.segments} seg {r.wall_s:5.1f} s  {verdict}  {r.scenario.describe()}")


def run_campaign(scenarios: int = 30, seed: int = 0, jobs: int = 1, keep: str | None = None,
                 *, shrink_failures: bool = True, normbox_share: float = 0.0,
                 max_faults: int = 3,
                 replay: str | None = None, out: TextIO | None = None,
                 verbose: bool = True) -> list[Result]:
    """Run the campaign; prints as it goes; the last line is "N scenarios: V violations"."""
    out = out or sys.stdout
    preload()
    root = Path(keep).resolve() if keep else Path(tempfile.mkdtemp(prefix="normbox-campaign-"))
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    try:
        if replay is not None:
            chosen = [Scenario.from_json(replay)]
            print(f"replay: {chosen[0].describe()}", file=out, flush=True)
            results = [run_one(chosen[0], root, keep=keep is not None)]
        else:
            print(f"campaign seed {seed}: {scenarios} scenarios, {jobs} job(s), world analytic"
                  f"{f' (normbox share {normbox_share:g})' if normbox_share else ''}"
                  f"{f', up to {max_faults} faults' if max_faults != 3 else ''}",
                  file=out, flush=True)
            tasks = [(seed, i, str(root), keep is not None, normbox_share, max_faults)
                     for i in range(scenarios)]
            results = []
            if jobs > 1:
                ctx = multiprocessing.get_context("fork")
                with ctx.Pool(jobs) as pool:
                    for r in pool.imap(_worker, tasks):
                        results.append(r)
                        if verbose or r.violations:
                            print(_format(r), file=out, flush=True)
            else:
                for t in tasks:
                    r = _worker(t)
                    results.append(r)
                    if verbose or r.violations:
                        print(_format(r), file=out, flush=True)
        failing = [r for r in results if r.violations]
        shrunk_classes: set[str] = set()
        for r in failing:
            print(f"\n{r.scenario.name}: {r.scenario.describe()}", file=out)
            for v in r.violations[:8]:
                print(f"  {v.line()}", file=out)
            if len(r.violations) > 8:
                print(f"  … {len(r.violations) - 8} more", file=out)
            targets = [c for c in r.classes if c not in shrunk_classes] if shrink_failures \
                else []
            for target in targets:            # each class once per campaign: its own culprit
                shrunk_classes.add(target)
                small, runs = shrink(r.scenario, target, root / "shrink")
                r.shrunk, r.shrink_runs = small, r.shrink_runs + runs
                print(f"  shrunk ({target}, {runs} runs) to: {small.describe()}", file=out)
                print(f"  reproduce: {replay_command(small)}", file=out, flush=True)
            if not targets:
                print(f"  reproduce: {replay_command(r.scenario)}", file=out, flush=True)
        violations = sum(len(r.classes) for r in results)
        if failing:
            classes: dict[str, int] = {}
            for r in failing:
                for c in r.classes:
                    classes[c] = classes.get(c, 0) + 1
            print("\nviolation classes: " + ", ".join(f"{c} ×{n}" for c, n in
                                                     sorted(classes.items())), file=out)
        print(f"wall time {time.monotonic() - t0:.1f} s", file=out)
        print(f"{len(results)} scenarios: {violations} violations", file=out, flush=True)
        return results
    finally:
        if keep is None:
            shutil.rmtree(root, ignore_errors=True)


__all__ = ["Result", "candidates", "replay_command", "run_campaign", "run_one", "shrink"]
