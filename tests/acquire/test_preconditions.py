"""Preconditions the engine checks whatever the protocol declares: a stable lamp for every
radiometer reading, and a calibration for every reading of a calibratable instrument."""

from __future__ import annotations

import pytest
from engine_fakes import FakeGonio, FakeLab

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.plan import Plan
from normbox_lab.acquire.steps import PlanError
from normbox_lab.acquire.store import Store


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "t.sqlite")
    yield s
    s.close()


def test_radiometer_reading_waits_for_an_undeclared_lamp_to_be_stable(store):
    """The protocol forgot `wait_stable` and the `lamp: "stable"` requirement; the lamp was
    just switched on.  The engine still waits for it before the reading."""
    lab = FakeLab()
    lab.sphere.set_output(True)                     # warming up now
    switched_on_s = lab.clock.now_s()
    plan = Plan("careless", {}, [
        eng.move("move", "rotator", 45.0),
        eng.measure("a45/p01", "radiometer", requires={"rotator": 45.0}, angle_deg=45.0,
                    patch=1),
    ])
    res = eng.Engine(lab, store, plan).run()
    assert res.status == "done"
    kinds = [k for _, k, d in store.events(res.run_id)]
    assert "suspended" in kinds
    susp = next(d for _, k, d in store.events(res.run_id) if k == "suspended")
    assert susp["role"] == "sphere" and susp["key"] == "a45/p01"
    assert lab.radiometer.calls == 1
    assert lab.clock.now_s() >= switched_on_s + lab.sphere.settle_s


def test_stable_lamp_costs_nothing(store):
    lab = FakeLab(lamp_on=True)
    plan = Plan("careless", {}, [
        eng.move("move", "rotator", 45.0),
        eng.measure("a45/p01", "radiometer", requires={"rotator": 45.0}, angle_deg=45.0,
                    patch=1)])
    res = eng.Engine(lab, store, plan).run()
    assert res.status == "done"
    assert "suspended" not in [k for _, k, _ in store.events(res.run_id)]


def test_gonio_reading_without_a_calibration_is_refused_before_anything_moves(store):
    lab = FakeLab()
    lab.instruments["gonio"] = FakeGonio(lab.clock, lab.world)
    plan = Plan("uncalibrated", {}, [
        eng.prompt("p01/mount", "mount patch 1", sets={"gonio_sample": "p01"}),
        eng.measure("p01/i-30/o+30", "gonio", requires={"gonio_sample": "p01"},
                    theta_i_deg=-30.0, theta_o_deg=30.0)])
    with pytest.raises(PlanError, match="'p01/i-30/o\\+30'.*calibrat"):
        eng.Engine(lab, store, plan).run()
    assert store.keys(store.runs()[-1].id) == set()
    # with a calibrate step it is required from, the same plan runs
    ok = Plan("calibrated", {}, [
        eng.prompt("p01/mount", "mount patch 1", sets={"gonio_sample": "p01"}),
        eng.calibrate("p01/calibrate", "gonio", requires={"gonio_sample": "p01"},
                      sets={"gonio_cal": "p01"}),
        eng.measure("p01/i-30/o+30", "gonio", requires={"gonio_sample": "p01",
                                                        "gonio_cal": "p01"},
                    theta_i_deg=-30.0, theta_o_deg=30.0)])
    assert eng.Engine(lab, store, ok, operator=lab.operator).run().status == "done"
