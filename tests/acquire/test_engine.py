"""Engine semantics on fakes and a VirtualClock: ETA, pause/resume, abort, suspenders, retries,
prompts, subscribers, plan validation.  Nothing here sleeps: virtual seconds are what we check."""

from __future__ import annotations

import itertools
import queue
import threading

import pytest
from engine_fakes import FakeLab, timeout

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import DeviceError, NormboxError, ProtocolError, StoreError

SMALL = {"angles_deg": [30, 60, 90], "patches": [1, 2, 3, 4]}


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "t.sqlite")
    yield s
    s.close()


def make(lab, store, params=None, **kw):
    plan = eng.build_plan("reference-sweep", params, lab)
    return eng.Engine(lab, store, plan, **kw)


def started(events):
    return [(e.key, e.data.get("kind")) for e in events if e.kind == "step-started"]


def test_dry_run_eta_equals_executed_virtual_time(store):
    lab = FakeLab()
    e = make(lab, store)
    dry = e.dry_run()
    assert len(dry.executed) == 1 + 13 + 2 * 312 and dry.plan.planned == 312
    assert dry.prepare_s == lab.rotator.home_s
    t0 = lab.clock.now_s()
    res = e.run()
    elapsed = lab.clock.now_s() - t0
    assert res.status == "done" and res.done == 312
    assert dry.total_s > 312 * 3.0            # operator time alone
    assert abs(elapsed - dry.total_s) / dry.total_s < 0.01
    assert res.elapsed_s == pytest.approx(elapsed)
    # every reading was taken at its declared angle with its patch in view
    for r in store.readings(res.run_id):
        assert r.metadata["patch_seen"] == r.metadata["patch"]
        assert r.metadata["angle_seen"] == r.metadata["angle_deg"]
    assert store.get_run(res.run_id).status == "done"


def test_dry_run_of_a_resume_lists_only_what_is_needed(store):
    lab = FakeLab(lamp_on=True)
    e = make(lab, store, SMALL)
    committed = {"a30/p01", "a30/p02", "a30/p03", "a30/p04", "a60/p01"}
    dry = e.dry_run(committed)
    assert [x.key for x in dry.executed[:4]] == ["lamp", "a60/move", "a60/p02/place", "a60/p02"]
    assert dry.executed[0].duration_s == 0.0          # the lamp is already stable
    assert len(dry.remaining_keys) == 12 - 5


def test_deferred_pause_then_resume_after_restart_replays_exact_state(store):
    lab = FakeLab()
    e = make(lab, store)
    seen = []
    e.subscribe(seen.append)

    def pause_at_50(ev):
        if ev.kind == "reading-stored" and len(store.keys(ev.run_id)) == 50:
            e.pause()
    e.subscribe(pause_at_50)
    res = e.run()
    assert res.status == "paused" and res.done == 50
    assert store.get_run(res.run_id).status == "paused"

    # a new process: new lab (physical state unknown), same store
    lab2 = FakeLab()
    e2 = make(lab2, store)
    seen2 = []
    e2.subscribe(seen2.append)
    res2 = e2.run(resume=res.uuid)   # (an all-digit prefix would read as an id)
    assert res2.status == "done" and res2.taken == 262 and res2.done == 312
    # the first missing reading is a40/p03: the lamp, the angle and the patch come first
    assert started(seen2)[:4] == [("lamp", "wait-stable"), ("a40/move", "move"),
                                  ("a40/p03/place", "prompt"), ("a40/p03", "measure")]
    assert lab2.world.placed[0] == 3 and lab2.rotator.moves[0] == 40.0
    keys = [r.key for r in store.readings(res.run_id)]
    assert len(keys) == len(set(keys)) == 312
    assert set(keys) == set(e2.plan.commit_keys)
    kinds = [k for _, k, _ in store.events(res.run_id)]
    assert kinds.count("segment") == 2 and "status:paused" in kinds


def test_in_process_pause_waits_and_resumes_in_a_worker_thread(store):
    lab = FakeLab()
    e = make(lab, store, SMALL, wait_when_paused=True)
    paused = threading.Event()
    e.subscribe(lambda ev: paused.set() if ev.kind == "paused" else None)
    e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" and ev.key == "a30/p02"
                else None)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", e.run()))
    worker.start()
    assert paused.wait(10)
    assert e.state == "paused" and len(store.keys(e.run_id)) == 2
    e.resume()
    worker.join(10)
    assert result["r"].status == "done" and result["r"].done == 12
    # in-process resume keeps the known state: no second move to 30°
    assert lab.rotator.moves.count(30.0) == 1


def test_abort_is_immediate_and_stops_the_instruments(store):
    lab = FakeLab()
    e = make(lab, store, SMALL)
    lab.radiometer.during[7] = e.abort          # abort in the middle of the 7th reading
    res = e.run()
    assert res.status == "aborted" and res.done == 6
    assert lab.radiometer.aborted >= 1 and lab.rotator.stops >= 1
    assert store.get_run(res.run_id).status == "aborted"
    assert "a60/p03" not in store.keys(res.run_id)
    # an aborted run can still be completed later
    res2 = make(FakeLab(), store, SMALL).run(resume=res.run_id)
    assert res2.status == "done" and res2.done == 12 and res2.taken == 6


def test_lamp_glitch_suspends_and_the_interrupted_reading_is_taken_again(store):
    lab = FakeLab()
    e = make(lab, store, SMALL)
    glitch_at = []
    lab.radiometer.during[5] = lambda: (glitch_at.append(lab.clock.now_s()),
                                        lab.sphere.glitch(30.0))
    events = []
    e.subscribe(events.append)
    res = e.run()
    assert res.status == "done" and res.done == 12
    assert lab.radiometer.calls == 13                 # one reading taken twice, stored once
    kinds = [k for _, k, _ in store.events(res.run_id)]
    assert kinds.count("suspended") == 1 and kinds.count("unsuspended") == 1
    susp = next(ev for ev in events if ev.kind == "suspended")
    assert susp.key == "a60/p01" and susp.data["after_reading"] is True
    back = next(ev for ev in events if ev.kind == "unsuspended")
    assert back.time_s >= glitch_at[0] + 30.0 > susp.time_s   # waited for the lamp
    stored = store.reading(res.run_id, "a60/p01")
    assert stored.time_s >= lab.clock.wall_time_s() - lab.clock.now_s() + back.time_s


def test_transient_faults_are_retried_within_the_bound(store):
    lab = FakeLab()
    lab.radiometer.faults[3] = [timeout(), timeout()]
    res = make(lab, store, SMALL).run()
    assert res.status == "done" and res.done == 12
    faults = [d for _, k, d in store.events(res.run_id) if k == "fault"]
    assert [f["attempt"] for f in faults] == [1, 2] and faults[0]["key"] == "a30/p03"
    assert not [r for r in lab.operator.asked if r.kind == "fault"]


@pytest.mark.parametrize("answer, status, done", [("retry", "done", 12), ("skip", "interrupted", 11),
                                                   ("abort", "aborted", 2)])
def test_persistent_fault_asks_the_operator(store, answer, status, done):
    lab = FakeLab(fault_answers=[answer])
    lab.radiometer.faults[3] = [timeout(), timeout(), timeout()]     # 3 attempts: persistent
    res = make(lab, store, SMALL).run()
    assert (res.status, res.done) == (status, done)
    asked = [r for r in lab.operator.asked if r.kind == "fault"]
    assert len(asked) == 1 and asked[0].choices == ("retry", "skip", "abort")
    assert asked[0].key == "a30/p03"
    ops = [d for _, k, d in store.events(res.run_id) if k == "operator"]
    assert ops[-1]["answer"] == answer
    if answer == "skip":
        assert res.skipped == ("a30/p03",) and "a30/p03" not in store.keys(res.run_id)
        # resuming fills the hole, and nothing else is taken again
        res2 = make(FakeLab(), store, SMALL).run(resume=res.run_id)
        assert res2.taken == 1 and res2.done == 12


@pytest.mark.parametrize("error", [timeout("no reply to IDN within 10 s"),
                                   ProtocolError("IDDR: expected OK00,<name>", raw=b"OK00",
                                                 instrument="radiometer")])
def test_an_instrument_that_never_answers_identify_ends_the_segment_cleanly(store, error):
    """Identification is preparation like remote mode and homing: under replies later than the
    timeout, `identify()`'s InstrumentTimeout escaped `Engine.run` (run left `failed`).  Now:
    retried after recover(), then the operator (retry / abort); abort ends the segment
    `aborted` (resumable), nothing measured, and a resume with the instrument back works."""
    lab = FakeLab(fault_answers=["retry"])           # retry once, then (no answer left) abort

    def identify():
        raise error
    lab.radiometer.identify = identify
    res = make(lab, store, SMALL).run()               # no exception escapes
    assert (res.status, res.done, res.taken) == ("aborted", 0, 0)
    assert store.get_run(res.run_id).status == "aborted"
    faults = [d for _, k, d in store.events(res.run_id) if k == "fault"]
    assert {f["key"] for f in faults} == {"prepare/radiometer"} and len(faults) == 6
    asked = [r for r in lab.operator.asked if r.kind == "fault"]
    assert [r.choices for r in asked] == [("retry", "abort")] * 2
    assert lab.radiometer.calls == 0                  # nothing measured
    res2 = make(FakeLab(), store, SMALL).run(resume=res.run_id)
    assert (res2.status, res2.done) == ("done", 12)


def test_device_error_is_not_retried(store):
    lab = FakeLab(fault_answers=["retry"])
    lab.radiometer.faults[2] = [DeviceError("ER20", "overexposed")]
    res = make(lab, store, SMALL).run()
    assert res.status == "done"
    assert [d["attempt"] for _, k, d in store.events(res.run_id) if k == "fault"] == [1]
    assert len([r for r in lab.operator.asked if r.kind == "fault"]) == 1


def test_prompts_answered_from_another_thread(store):
    lab = FakeLab()
    lab.operator = None                                # no operator: the engine waits
    e = make(lab, store, {"angles_deg": [30], "patches": [5, 6]})
    prompts: queue.Queue = queue.Queue()
    e.subscribe(lambda ev: prompts.put(ev.data["prompt"]) if ev.kind == "prompt" else None)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", e.run()))
    worker.start()
    answered = []
    while worker.is_alive() or not prompts.empty():
        try:
            req = prompts.get(timeout=0.5)
        except queue.Empty:
            continue
        assert e.pending_prompt == req
        with pytest.raises(NormboxError):
            e.answer("maybe", req.id)
        lab.world.place_patch(req.data["patch"])
        e.answer("ok", req.id)
        answered.append(req.message)
    worker.join(5)
    assert answered == ["place patch 5 (blue flower)", "place patch 6 (bluish green)"]
    assert result["r"].done == 2


def test_a_failing_subscriber_never_kills_the_run(store, caplog):
    lab = FakeLab()
    e = make(lab, store, SMALL)

    def bad(ev):
        raise RuntimeError("plotting exploded")
    e.subscribe(bad)
    res = e.run()
    assert res.status == "done" and res.done == 12
    assert "plotting exploded" in caplog.text


def test_progress_events_count_up_with_a_shrinking_eta(store):
    lab = FakeLab()
    e = make(lab, store, SMALL)
    prog = []
    e.subscribe(lambda ev: prog.append(ev.data) if ev.kind == "progress" else None)
    e.run()
    assert [p["done"] for p in prog] == list(range(1, 13))
    etas = [p["eta_s"] for p in prog]
    assert etas[-1] == 0 and all(a >= b for a, b in itertools.pairwise(etas))


def test_plan_validation():
    with pytest.raises(eng.PlanError, match="not unique"):
        eng.Plan("x", {}, [eng.move("a", "rotator", 1), eng.move("a", "rotator", 2)])
    with pytest.raises(eng.PlanError, match="requires"):
        eng.Plan("x", {}, [eng.move("m", "rotator", 1),
                           eng.measure("r", requires={"rotator": 2.0})])
    with pytest.raises(eng.PlanError, match="unknown kind"):
        eng.Plan("x", {}, [eng.Step("k", "dance")])


def test_resume_refuses_a_changed_plan(store):
    lab = FakeLab()
    e = make(lab, store, SMALL)
    e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" else None)
    res = e.run()
    with pytest.raises(StoreError, match="different plan"):
        make(FakeLab(), store, {"angles_deg": [30, 60], "patches": [1, 2, 3, 4]}).run(
            resume=res.run_id)


def test_instrument_identities_recorded_per_segment(store):
    lab = FakeLab()
    e = make(lab, store, SMALL)
    e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" else None)
    res = e.run()
    make(FakeLab(), store, SMALL).run(resume=res.run_id)
    inst = store.instruments(res.run_id)
    assert {i["role"] for i in inst} == {"rotator", "sphere", "radiometer"}
    assert sorted({i["identity"]["segment"] for i in inst}) == [1, 2]


def test_stop_while_paused_in_process_ends_the_segment_resumably(store):
    lab = FakeLab()
    e = make(lab, store, SMALL, wait_when_paused=True)
    paused = threading.Event()
    e.subscribe(lambda ev: paused.set() if ev.kind == "paused" else None)
    e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" and ev.key == "a30/p03"
                else None)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", e.run()))
    worker.start()
    assert paused.wait(10)
    e.stop()
    worker.join(10)
    assert result["r"].status == "paused" and result["r"].done == 3
    assert make(FakeLab(), store, SMALL).run(resume=e.run_uuid).done == 12


def waiting_at_first_prompt(store):
    """An engine without an operator callable, run in a worker until it waits for an answer."""
    lab = FakeLab()
    lab.operator = None
    e = make(lab, store, SMALL)
    asked = threading.Event()
    e.subscribe(lambda ev: asked.set() if ev.kind == "prompt" else None)
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("r", e.run()))
    worker.start()
    assert asked.wait(10)
    return e, worker, result


def test_abort_while_waiting_for_an_answer(store):
    e, worker, result = waiting_at_first_prompt(store)
    e.abort()
    worker.join(10)
    assert result["r"].status == "aborted" and result["r"].done == 0
    assert store.get_run(e.run_id).status == "aborted"


def test_a_lamp_that_keeps_dropping_out_becomes_an_operator_decision(store):
    lab = FakeLab(fault_answers=["skip"])
    e = make(lab, store, {"angles_deg": [30], "patches": [1, 2]}, max_suspensions=3)
    for n in range(1, 10):                       # every measurement of patch 1 is spoiled
        lab.radiometer.during[n] = (lambda: lab.sphere.glitch(10.0)) if n <= 3 else None
    lab.radiometer.during = {k: v for k, v in lab.radiometer.during.items() if v}
    res = e.run()
    assert res.skipped == ("a30/p01",) and res.done == 1 and res.status == "interrupted"
    kinds = [k for _, k, _ in store.events(res.run_id)]
    assert kinds.count("suspended") == 3 and "skip" in kinds
    asked = [r for r in lab.operator.asked if r.kind == "fault"]
    assert len(asked) == 1 and "unstable" in asked[0].message


def test_stop_while_waiting_for_an_answer_pauses_and_resume_asks_again(store):
    e, worker, result = waiting_at_first_prompt(store)
    first = e.pending_prompt
    e.stop()
    worker.join(10)
    assert not worker.is_alive()
    assert result["r"].status == "paused" and result["r"].done == 0
    assert store.get_run(e.run_id).status == "paused"
    assert e.pending_prompt is None
    # the resumed segment asks the same question first, then completes
    lab2 = FakeLab()
    asked_again = []

    def operator(req):
        asked_again.append(req.message)
        lab2.world.place_patch(req.data["patch"])
        return "ok"
    lab2.operator = operator
    r = make(lab2, store, SMALL).run(resume=e.run_uuid)
    assert asked_again[0] == first.message
    assert r.status == "done" and r.done == 12


# --- lamps are found by capability, never by the role name "sphere" -----------------------------

def _lab_with_lamps_named(sphere_role: str, extra_lamp: str | None = None) -> FakeLab:
    """The fake lab with its light source under another role name (and maybe a second lamp
    the plan never names)."""
    from engine_fakes import FakeLamp

    lab = FakeLab()
    lamp = lab.instruments.pop("sphere")
    lab.instruments[sphere_role] = lamp
    lamps = [sphere_role]
    if extra_lamp is not None:
        lab.instruments[extra_lamp] = FakeLamp(lab.clock)
        lamps.append(extra_lamp)
    lab.light_sources = lambda: tuple(lamps)
    return lab


def test_an_emergency_stop_switches_off_every_lamp_of_the_lab(store):
    lab = _lab_with_lamps_named("sphere", extra_lamp="gonio_lamp")
    lab.instruments["gonio_lamp"].set_output(True)
    e = make(lab, store, SMALL)
    lab.radiometer.during[3] = e.emergency_stop
    res = e.run()
    assert res.status == "paused" and res.done == 2
    # the lamp the plan does not name goes off too: it is a light source of the lab
    assert lab.instruments["sphere"].state() == "off"
    assert lab.instruments["gonio_lamp"].state() == "off"


def test_a_lamp_under_any_role_name_is_waited_for_and_named_in_the_fault(store):
    """The radiometer reading waits for the lab's light source whatever its role is called, and
    a lamp that keeps dropping out is named by its own role in the operator's question."""
    lab = _lab_with_lamps_named("panel_light")
    plan = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [1, 2],
                                              "lamp": "panel_light"}, lab)
    lab.operator.fault_answers = ["skip"]
    e = eng.Engine(lab, store, plan, max_suspensions=2)
    for n in range(1, 4):
        lab.radiometer.during[n] = lambda: lab.instruments["panel_light"].glitch(10.0)
    res = e.run()
    assert res.skipped == ("a30/p01",) and res.done == 1
    faults = [d for _, k, d in store.events(res.run_id) if k == "fault"]
    assert faults and all(d["role"] == "panel_light" for d in faults)
    suspended = [d["role"] for _, k, d in store.events(res.run_id) if k == "suspended"]
    assert len(suspended) >= 2 and set(suspended) == {"panel_light"}



def test_a_skipped_reading_taken_again_on_resume_loses_its_skip_error(store):
    """A reading skipped at a fault and measured on resume is data like any other: its
    `skipped` error (and the faults of the attempt that was skipped) go, `qa` exits 0 for it
    and the run is `done`, not "completed with flags"."""
    from normbox_lab.analyze import qa
    from normbox_lab.core.errors import ImplausibleData

    lab = FakeLab(fault_answers=["skip"])
    lab.radiometer.faults[3] = [ImplausibleData("garbled", instrument="radiometer"),
                                timeout(), timeout()]
    res = make(lab, store, SMALL).run()
    assert res.skipped == ("a30/p03",)
    before = {(f.key, f.gate, f.severity) for f in qa.flags(store, res.run_id)}
    assert before == {("a30/p03", "skipped", "error"),
                      ("a30/p03", "instrument-error:implausible-data", "error")}
    res2 = make(FakeLab(), store, SMALL).run(resume=res.run_id)
    assert res2.status == "done" and res2.done == 12
    assert qa.flags(store, res.run_id) == []
    assert qa.run_status(store, res.run_id) == "done"
    # a flag recorded while a reading is taken stays with it
    lab3 = FakeLab()
    lab3.radiometer.faults[2] = [ImplausibleData("garbled", instrument="radiometer")]
    res3 = make(lab3, store, SMALL).run()
    assert [(f.key, f.severity) for f in qa.flags(store, res3.run_id)] == [("a30/p02", "error")]


def test_run_command_with_a_lamp_that_never_answers_identify(tmp_path, monkeypatch, capsys):
    """The same on the command line, on the simulated lab: one status line and the resume
    hint, exit 1, no traceback; `runs` shows the run aborted (resumable), not `failed`."""
    from normbox_lab.cli import main
    from normbox_lab.core.errors import InstrumentTimeout
    from normbox_lab.drivers.sphere import SphereLightSource

    def identify(self):
        raise InstrumentTimeout("no reply to *IDN? within 5 s", instrument="sphere")
    monkeypatch.setattr(SphereLightSource, "identify", identify)
    monkeypatch.chdir(tmp_path)
    argv = ["run", "reference-sweep", "--world", "analytic", "--plain", "--store", "s.sqlite",
            "--param", "angles_deg=[30]", "--param", "patches=[1]"]
    assert main(argv) == 1
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "normbox-lab: error" not in err
    assert "fault: prepare/sphere sphere no reply to *IDN? within 5 s (InstrumentTimeout)" in err
    status = [ln for ln in out.splitlines() if "readings" in ln]
    assert len(status) == 1 and ": aborted, 0/1 readings (0 taken now)" in status[0]
    with Store(tmp_path / "s.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "aborted" and s.keys(run.id) == set()
    # the complete command: protocol, store and the world the run was measured in
    assert out.splitlines()[-1] == (f"resume with: normbox-lab run reference-sweep --resume "
                                    f"{run.uuid} --store s.sqlite --world analytic")


def test_after_a_skip_the_next_reading_is_estimated_with_the_state_it_must_establish(store):
    """The lamp faults while being switched on for the first reading, which is skipped; the
    next reading switches it on and waits its 120 s.  The segment's dry run had counted that
    wait for the first reading only: the next one's estimate (and the ETA) must include it
    (sim campaign seed 7 scenario 113: a light-map reading took 322 s against its 16 s)."""
    from normbox_lab.core.errors import InstrumentTimeout

    lab = FakeLab(fault_answers=["skip"])
    fails = {"n": 3}
    switch = lab.sphere.set_output

    def set_output(on):
        if fails["n"] > 0:
            fails["n"] -= 1
            raise InstrumentTimeout("no reply to OUTP ON", instrument="sphere")
        switch(on)
    lab.sphere.set_output = set_output
    e = make(lab, store, SMALL)
    seen: dict[str, float] = {}
    took: dict[str, float] = {}
    updates = []

    def on_event(ev):
        if ev.kind == "step-started" and ev.data.get("kind") == "measure":
            seen[ev.key] = e._estimates.get(ev.key, 0.0)
        elif ev.kind == "step-finished" and ev.data.get("kind") == "measure":
            took[ev.key] = ev.data["duration_s"]
        elif ev.kind == "estimates":
            updates.append(dict(ev.data["estimates"]))
    e.subscribe(on_event)
    res = e.run()
    assert res.skipped == ("a30/p01",) and res.done == 11
    assert took["a30/p02"] >= lab.sphere.settle_s          # it did warm the lamp up
    assert seen["a30/p02"] >= took["a30/p02"] - 1e-6       # and was expected to
    assert len(updates) == 1 and set(updates[0]) == set(took)
    # every later reading stays within its (new) estimate: no inflated ETA ratio
    assert all(took[k] <= seen[k] + 1e-6 for k in took), {k: (took[k], seen[k]) for k in took}
