"""The Run tab's remaining time against the truth, on the virtual clock.

A reduced reference sweep (3 angles × 3 patches, the operator's sweep of the console report)
runs on a simulated lab — every real driver against its emulator, the analytic world, lab time
on a `VirtualClock` at time scale 0 — while the console's clock is what the operator's wall
clock would read at time scale S: S × lab time + the person's own time (6 s to place each
patch, and one 100 s pause after the 6th reading).  `RunProgress` is fed the engine's events
exactly as the app feeds it; each estimate is compared with the time the run then really took.

    python tests/tui/test_tui_remaining.py        # the table in docs/tui.md
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.session import open_run
from normbox_lab.sim.labsim import build_lab
from normbox_lab.tui.tabs.run import RunProgress

PERSON_S = 6.0            # placing a patch and pressing Enter
PAUSE_S = 100.0           # one pause, after the 6th reading
PAUSE_AFTER = 6


class OperatorWallClock:
    """What the operator's clock reads: the lab's time × the time scale, plus the person's."""

    def __init__(self, lab_clock: Any, time_scale: float) -> None:
        self.lab_clock, self.time_scale, self.person_s = lab_clock, time_scale, 0.0

    def now_s(self) -> float:
        return self.time_scale * self.lab_clock.now_s() + self.person_s

    def wall_time_s(self) -> float:
        return 1_767_225_600.0 + self.now_s()

    def sleep(self, duration_s: float) -> None:
        self.person_s += duration_s


def simulate(time_scale: float, tmp: Path, person_s: float = PERSON_S,
             first_extra_s: float = 0.0, overhead_s: float = 0.0,
             pause: bool = True) -> list[dict[str, Any]]:
    """One run; for every reading: done, the estimate shown right after it, the truth, and
    what the old estimate (the segment's plain average) would have said.  `person_s`: the
    operator's answer time per prompt; `first_extra_s`: one-off console-clock seconds of the
    first measurement (its set-up, which no timing model knows); `overhead_s`: console-clock
    seconds every measurement costs beyond the model × the time scale (drivers, emulators,
    the store on a loaded machine)."""
    config = replace(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), time_scale=0.0)
    lab = build_lab(config, world="analytic", operator_response_s=0.0)
    clock = OperatorWallClock(lab.clock, time_scale)
    virtual = lab.operator

    def person(req: Any) -> str:
        if req.kind == "operator":
            clock.sleep(person_s)
        return virtual(req)

    progress = RunProgress(clock)
    rows: list[dict[str, Any]] = []
    start: list[float] = []
    with open_run("reference-sweep", lab=lab, store=tmp / f"r{time_scale:g}.sqlite",
                  params={"angles_deg": [30, 60, 90], "patches": [7, 9, 19]},
                  operator=person) as opened:
        engine = opened.engine

        measured: list[str] = []

        def on_event(ev: Any) -> None:
            progress.on_event(ev.kind, ev.data)
            if ev.kind == "step-started" and ev.data.get("kind") == "measure":
                clock.sleep(overhead_s + (0.0 if measured else first_extra_s))
                measured.append(ev.key)
            if ev.kind == "run-started":
                progress.started(ev.data["done"], ev.data["planned"], float(ev.data["eta_s"]),
                                 ev.data)
                start.append(clock.now_s())
            elif ev.kind == "progress":
                progress.progressed(ev.data["done"], float(ev.data["eta_s"]),
                                    ev.data.get("remaining_estimate_s"), ev.data)
                rows.append({"done": ev.data["done"], "t": clock.now_s(),
                             "shown": progress.remaining_s(time_scale),
                             "old": (clock.now_s() - start[0]) / ev.data["done"]
                             * (ev.data["planned"] - ev.data["done"])})
                if pause and ev.data["done"] == PAUSE_AFTER:   # the engine waits here
                    progress.on_event("paused", {})
                    progress.status = "paused"
                    rows[-1]["while_paused"] = progress.remaining_s(time_scale)
                    clock.sleep(PAUSE_S)
                    progress.on_event("resumed", {})
                    progress.status = "running"
                    rows[-1]["t"] = clock.now_s()
                    rows[-1]["shown"] = progress.remaining_s(time_scale)
        engine.subscribe(on_event)
        result = opened.run()
        lab.close()
    assert result.status == "done" and result.done == 9
    end = clock.now_s()
    paused_until = next(r["t"] for r in rows if r["done"] == PAUSE_AFTER) if pause else 0.0
    for r in rows:
        # what the run then took, the operator's later pause left out (no one can know it)
        r["truth"] = end - r["t"] - (PAUSE_S if r["t"] < paused_until else 0.0)
        r["warm_up_s"] = rows[0]["t"] - start[0]
    return rows


@pytest.mark.parametrize("time_scale", [0.2, 1.0])
def test_remaining_time_within_25_percent_after_the_first_reading(tmp_path, time_scale):
    """Warm-up and pauses are modelled as one-off waits: every estimate after the first reading
    is within ±25 % of the time the run then took (the plain average was 3–10× too long), and
    none is shown while paused."""
    rows = simulate(time_scale, tmp_path)
    assert rows[0]["warm_up_s"] > 5 * (rows[1]["t"] - rows[0]["t"])   # a real warm-up
    for r in rows[:-1]:
        assert r["shown"] == pytest.approx(r["truth"], rel=0.25), r
    assert rows[-1]["shown"] == 0.0
    assert rows[PAUSE_AFTER - 1]["while_paused"] is None
    assert rows[0]["old"] > 3 * rows[0]["truth"]         # what the console used to show


@pytest.mark.parametrize("person_s", [1.8, 6.5])
def test_remaining_time_within_15_percent_from_the_first_reading(tmp_path, person_s):
    """Reported: at ×0.2 the first reading took 10–16 s against about 3.6 s for every later
    one (the first measurement's set-up, which no model knows), and the operator's answer time
    was not modelled: the estimate after reading 1 was +207 % (answers in 1.8 s) and +74 %
    (6.5 s).  Here the first measurement costs 7 s more, every measurement 0.3 s beyond the
    model, and the estimate is within ±15 % from the first reading on."""
    rows = simulate(0.2, tmp_path, person_s=person_s, first_extra_s=7.0, overhead_s=0.3,
                    pause=False)
    for r in rows[:-1]:
        assert r["shown"] == pytest.approx(r["truth"], rel=0.15), r
    assert rows[0]["old"] > 1.5 * rows[0]["truth"]       # the segment's plain average


def _recorded(first_s: float, later_s: float, answer_s: float, model_s: float,
              scale: float = 0.2, n: int = 9) -> list[tuple[float, float]]:
    """(estimate, truth) after each reading of a recorded run: every reading's console time
    (the first `first_s`, the others `later_s`, each with one prompt answered in `answer_s`)
    and the model's lab seconds per reading (`model_s`, prompts excluded)."""
    from normbox_lab.acquire.estimate import RemainingTime

    est = RemainingTime()
    times = [first_s] + [later_s] * (n - 1)
    now = 0.0
    est.start(now, model_s * n, n)
    est.set_active(now, True)
    out = []
    for i, took in enumerate(times):
        est.prompt(now)
        now += answer_s
        est.answered(now)
        now += took - answer_s
        est.reading(now, model_s * (n - i - 1), n - i - 1)
        left = n - i - 1
        if left:
            out.append((est.remaining_s(now, scale, left), sum(times[i + 1:])))
    return out


@pytest.mark.parametrize("run, first_s, later_s, answer_s", [
    ("A (answers in 1.8 s)", 11.05, 3.6, 1.8),      # the reported run A: +207 % after reading 1
    ("B (answers in 6.5 s)", 14.4, 8.3, 6.5),       # run B: +74 %
    ("answers in 0.5 s", 9.0, 2.3, 0.5),
    ("answers in 20 s", 28.0, 21.8, 20.0),
])
def test_the_issues_recorded_runs_are_within_15_percent_from_reading_1(run, first_s, later_s,
                                                                        answer_s):
    """The two reported runs (first reading 11–14 s, later ones 3.6 s and 8.3 s; 1.8 s of
    instruments a reading, the model 8 lab s × 0.2 = 1.6 s of it), and two other answer
    times: every estimate from reading 1 on within ±15 %."""
    for shown, truth in _recorded(first_s, later_s, answer_s, model_s=8.0):
        assert shown == pytest.approx(truth, rel=0.15), (run, shown, truth)


def test_no_estimate_while_paused_and_counting_down_within_a_reading():
    from normbox_lab.core.clock import VirtualClock

    clock = VirtualClock()
    progress = RunProgress(clock)
    progress.started(done=0, planned=4, lab_remaining_s=100.0)
    progress.on_event("step-started", {"kind": "wait-stable"})
    clock.advance(300.0)                                   # a five-minute warm-up
    assert progress.remaining_text(1.0) == "remaining: measuring… (lamp warming up)"
    progress.on_event("step-finished", {"kind": "wait-stable"})
    progress.on_event("step-started", {"kind": "move"})
    clock.advance(10.0)
    progress.progressed(1, 75.0)
    assert progress.remaining_s(1.0) == 30.0               # 10 s a reading, not 310 s
    clock.advance(4.0)                                     # the next reading is under way
    assert progress.remaining_s(1.0) == 26.0
    progress.on_event("paused", {})
    progress.status = "paused"
    clock.advance(100.0)
    assert progress.remaining_text(1.0) == ""
    progress.on_event("resumed", {})
    progress.status = "running"
    assert progress.remaining_s(1.0) == 26.0               # the pause is not reading time


def _table() -> None:
    import tempfile

    print("| time scale | readings done | shown | then took (a later pause left out) | error | "
          "plain average (before) |")
    print("|---|---|---|---|---|---|")
    from normbox_lab.acquire.estimate import format_duration

    with tempfile.TemporaryDirectory() as tmp:
        for scale in (0.2, 1.0):
            rows = simulate(scale, Path(tmp))
            for r in rows[:-1]:
                err = 100.0 * (r["shown"] / r["truth"] - 1.0)
                note = " (after the 100 s pause)" if r["done"] == PAUSE_AFTER else ""
                print(f"| ×{scale:g} | {r['done']}/9{note} | {format_duration(r['shown'])} | "
                      f"{format_duration(r['truth'])} | {err:+.0f} % | "
                      f"{format_duration(r['old'])} |")
            print(f"<!-- ×{scale:g}: warm-up and preparation {rows[0]['warm_up_s']:.0f} s "
                  "before the first reading -->")


def _issue_table() -> None:
    """The reported table again: ×0.2, 3 angles × 3 patches, answers in 1.8 s and 6.5 s, the
    first measurement 7 s dearer, 0.3 s a measurement beyond the model."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        runs = {p: simulate(0.2, Path(tmp), person_s=p, first_extra_s=7.0, overhead_s=0.3,
                            pause=False) for p in (1.8, 6.5)}
    print("| after reading | answers in 1.8 s | answers in 6.5 s |")
    print("|---|---|---|")
    for i in range(8):
        cells = [f"{100.0 * (runs[p][i]['shown'] / runs[p][i]['truth'] - 1.0):+.1f} %"
                 for p in (1.8, 6.5)]
        print(f"| {i + 1}/9 | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    sys.exit(_issue_table() if "--issue" in sys.argv else _table())
