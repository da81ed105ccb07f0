"""Setpoint and readback: every stage's `locate()`, stored with each reading, read
back as one typed geometry (`ReadingGeometry`), and the `position` gate on a stage that
stopped short.  The short stop is the APT emulator's own ``stall`` fault, timed so that the
rotor stops 0.3° before the target (the fraction of the move's duration is computed from the
emulator's trapezoid); the open-loop controller still reports the move done, the encoder tells
the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.quality import position_flags
from normbox_lab.acquire.queries import reference_data
from normbox_lab.acquire.store import Store
from normbox_lab.analyze.angles import AngleOffsets
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.types import Location, ReadingGeometry
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.sim import core, labsim

SHORT_DEG = 0.3


def _stall_fraction(emulator_key: str, from_deg: float, to_deg: float,
                    short_deg: float = SHORT_DEG) -> float:
    """The `stall` fault's fraction of the move's duration at which the rotor is `short_deg`
    before the target (in the deceleration: left = a·τ²/2)."""
    trap = core.CONTEXT.instances[emulator_key].move_trapezoid
    total = trap.duration_s(to_deg - from_deg)
    tau = math.sqrt(2.0 * short_deg / trap.acceleration_deg_s2)
    return (total - tau) / total


def test_the_stage_keeps_setpoint_and_readback_and_a_short_stop_is_not_lost():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    probe = AptRotationStage.open("sim://rotator-apt?key=apt-probe", clock)
    f = _stall_fraction("apt-probe", 10.0, 70.0)
    stage = AptRotationStage.open(f"sim://rotator-apt?key=apt-short&faults=stall@2:{f:.9f}",
                                  clock)
    stage.home()
    stage.move_to(10.0)                                       # move 1: in place
    loc = stage.locate()
    assert (loc.setpoint, loc.unit, loc.tolerance) == (10.0, "deg", 0.05)
    assert loc.readback == pytest.approx(10.0, abs=1e-4) and not loc.out_of_tolerance()
    stage.move_to(70.0)                                       # move 2 stops 0.3° short
    loc = stage.locate()
    assert loc.setpoint == 70.0
    assert loc.readback == pytest.approx(70.0 - SHORT_DEG, abs=2e-3)
    assert loc.out_of_tolerance()
    assert core.CONTEXT.instances["apt-short"].angle_deg() == pytest.approx(loc.readback,
                                                                            abs=1e-4)
    probe.close()
    stage.close()
    core.CONTEXT.reset()


def _sweep(path, faults: str = ""):
    core.CONTEXT.reset(VirtualClock())
    url = "sim://rotator-apt" + (f"?key=rot-short&faults={faults}" if faults else "")
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://rotator-apt"', f'port = "{url}"')
    lab = labsim.build_lab(parse_config(text), world="analytic")
    store = Store(path)
    plan = {"angles_deg": [30, 60], "patches": [1, 2]}
    try:
        res = eng.Engine(lab, store, eng.build_plan("reference-sweep", plan, lab)).run()
        readings = {r.key: r for r in store.readings(res.run_id)}
        flags = [f for f in store.flag_rows(run_id=res.run_id) if f["gate"] == "position"]
        ref = reference_data(store, res.run_id) if res.status == "done" else None
    finally:
        store.close()
        lab.close()
        core.CONTEXT.reset()
    return res, readings, flags, ref


def test_every_reading_stores_setpoint_and_readback(tmp_path):
    res, readings, flags, ref = _sweep(tmp_path / "s.sqlite")
    assert res.status == "done" and len(readings) == 4 and flags == []
    np.testing.assert_allclose(ref.readback_offset_deg(), [0.0, 0.0], atol=1e-4)
    for key, r in readings.items():
        g = ReadingGeometry.of(r.metadata)
        angle = r.metadata["angle_deg"]
        assert g.angle_deg == angle and g.patch == r.metadata["patch"], key
        assert g.sample_angle.setpoint == angle
        assert g.sample_angle.readback == pytest.approx(angle, abs=1e-4)
        assert g.sample_angle.tolerance == 0.05 and g.sample_angle.unit == "deg"
        # the lamp monitor and the integration time at the reading, stored the same way
        assert g.lamp_monitor.unit == "cd/m2" and g.lamp_monitor.readback > 0
        assert g.lamp_monitor.readback == r.metadata["lamp_monitor_cd_m2"]
        assert g.integration_time.unit == "s"
        assert g.integration_time.readback == r.metadata["integration_time_s"] > 0
        assert not g.out_of_tolerance()


def test_a_rotator_that_stops_0_3_deg_short_flags_the_reading(tmp_path):
    # move 1 goes 0 → 30°, move 2 30 → 60°: the second stops 0.3° short
    core.CONTEXT.reset(VirtualClock())
    probe = AptRotationStage.open("sim://rotator-apt?key=rot-probe", VirtualClock())
    f = _stall_fraction("rot-probe", 30.0, 60.0)
    probe.close()
    res, readings, flags, ref = _sweep(tmp_path / "s.sqlite", f"stall@2:{f:.9f}")
    assert res.status == "done" and len(readings) == 4
    short = {k for k, r in readings.items() if r.metadata["angle_deg"] == 60.0}
    assert {f["key"] for f in flags} == short                 # both readings at 60°, no other
    for f_ in flags:
        assert f_["severity"] == "error"
        assert f_["value"] == pytest.approx(-SHORT_DEG, abs=2e-3) and f_["limit"] == 0.05
    for key in short:
        loc = ReadingGeometry.of(readings[key].metadata).sample_angle
        assert loc.setpoint == 60.0 and loc.readback == pytest.approx(60.0 - SHORT_DEG, abs=2e-3)
    # the error budget's angle offsets take the stage's own from the readback
    np.testing.assert_allclose(ref.angle_deg, [30.0, 60.0])
    np.testing.assert_allclose(ref.readback_offset_deg(), [0.0, -SHORT_DEG], atol=2e-3)
    est = AngleOffsets(ref.angle_deg, np.array([0.02, -0.35]), np.array([0.1, 0.1]), 2,
                       readback_deg=ref.readback_offset_deg())
    np.testing.assert_allclose(est.unexplained_deg(), [0.02, -0.05], atol=2e-3)
    assert "angle_offset_readback_deg" in est.to_arrays()


def test_the_store_protocol_is_what_the_sqlite_store_offers(tmp_path):
    from normbox_lab.acquire.store_api import Store as StoreProtocol

    with Store(tmp_path / "s.sqlite") as s:
        assert isinstance(s, StoreProtocol)
    assert not isinstance(object(), StoreProtocol)


def test_an_old_reading_without_readback_reads_as_not_recorded():
    old = {"angle_deg": 45.0, "patch": 7, "lamp_monitor_cd_m2": 3000.0,
           "integration_time_s": 0.5}                   # a reading stored before readbacks were recorded
    g = ReadingGeometry.of(old)
    assert g.angle_deg == 45.0 and g.patch == 7
    assert g.sample_angle == Location(45.0, None, "deg")
    assert not g.sample_angle.recorded and g.sample_angle.deviation is None
    assert "not recorded" in g.sample_angle.describe()
    assert g.sample_angle.value == 45.0                 # the best value is then the setpoint
    assert g.lamp_monitor == Location(None, 3000.0, "cd/m2")
    assert position_flags("a45/p07", old) == []         # never flagged for what is missing


def test_locations_round_trip_through_the_metadata():
    loc = Location(60.0, 59.7, "deg", 0.05)
    assert Location.from_dict(loc.to_dict()) == loc
    assert loc.deviation == pytest.approx(-0.3) and loc.out_of_tolerance()
    assert not Location(60.0, 60.04, "deg", 0.05).out_of_tolerance()
    assert not Location(60.0, 59.0, "deg", None).out_of_tolerance()   # no tolerance stated


def test_the_console_shows_a_readback_beyond_its_tolerance():
    from normbox_lab.tui.views import geometry_text

    loc = Location(60.0, 59.7, "deg", 0.05).to_dict()
    assert geometry_text({"angle_deg": 60.0, "locations": {"rotator": loc}}) == \
        "60.0° (read 59.7°)"
    assert geometry_text({"angle_deg": 60.0}) == "60.0°"                 # an old store
    assert geometry_text({"theta_i_deg": -30.0, "theta_o_deg": 10.0}) == "θi -30 θo 10"
    assert geometry_text({}) == "-"


def test_a_brdf_reading_stores_both_arms_setpoint_and_readback(tmp_path):
    core.CONTEXT.reset(VirtualClock())
    lab = labsim.build_lab(parse_config(SIM_CONFIG_TEMPLATE), world="analytic")
    try:
        with Store(tmp_path / "b.sqlite") as store:
            plan = eng.build_plan("brdf-inplane", {"materials": [7], "theta_i_deg": [-40],
                                                   "theta_o_deg": [-30, 60]}, lab)
            res = eng.Engine(lab, store, plan).run()
            readings = list(store.readings(res.run_id))
    finally:
        lab.close()
        core.CONTEXT.reset()
    assert res.status == "done" and len(readings) == 2
    for r in readings:
        g = ReadingGeometry.of(r.metadata)
        assert g.theta_i.setpoint == r.metadata["theta_i_deg"] == -40.0
        assert g.theta_o.setpoint == r.metadata["theta_o_deg"]
        for loc in (g.theta_i, g.theta_o):
            assert loc.unit == "deg" and loc.tolerance == 0.05
            assert loc.readback == pytest.approx(loc.setpoint, abs=1e-3)
        assert g.integration_time.readback == r.metadata["integration_time_s"] > 0
