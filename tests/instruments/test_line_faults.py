"""Transport faults on every line-protocol driver: connecting is retried, a late reply never
answers a later command (drain + re-handshake, or replies matched by id), undecodable bytes are
typed.  Each case here is one row of the fault-behaviour table in docs/fault-behaviour.md."""

from __future__ import annotations

import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import InstrumentError
from normbox_lab.drivers.cs2000 import CS2000A
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.drivers.sphere import SphereLightSource
from normbox_lab.sim import core


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


def _open(device: str, faults: str):
    clock = core.CONTEXT.clock
    url = f"sim://{device}?key={device}-{faults}&faults={faults}"
    if device == "rotator-apt":
        return AptRotationStage.open(url, clock)
    if device == "rotator-zaber":
        return ZaberRotationStage.open(url, clock)
    if device == "sphere":
        lamp = SphereLightSource.open(url, clock)
        lamp.identify()
        return lamp
    rad = CS2000A.open(url, clock)
    rad.set_remote(True)
    return rad


@pytest.mark.parametrize("device", ["rotator-apt", "rotator-zaber", "sphere", "cs2000a"])
@pytest.mark.parametrize("faults", ["no-reply@1", "garble@1", "truncate@1", "late-reply@1:7",
                                    "disconnect@1:2"])
def test_connect_is_retried_on_transport_faults(device, faults):
    inst = _open(device, faults)
    emu = core.CONTEXT.instances[f"{device}-{faults}"]
    assert emu.faults.log, "the fault did not fire"
    if device.startswith("rotator"):
        inst.home()
        inst.move_to(30.0)
        assert inst.position_deg() == pytest.approx(30.0, abs=0.05)
    elif device == "sphere":
        inst.set_output(True)
        assert inst.output() is True
    else:
        assert inst.remote


@pytest.mark.parametrize("delay_s", [3.0, 30.0])
def test_zaber_late_reply_never_answers_a_later_command(delay_s):
    stage = _open("rotator-zaber", "")
    emu = core.CONTEXT.instances["rotator-zaber-"]
    stage.home()
    stage.move_to(10.0)
    emu.faults.add("late-reply", at_count=emu.faults._counters.get("late-reply", 0) + 1,
                   parameter=delay_s)
    assert stage.position_deg() == pytest.approx(10.0, abs=0.05)
    assert stage.line_faults == 1
    for angle in (20.0, 30.0, 40.0):
        stage.move_to(angle)
        stage.clock.sleep(5.0)
        assert stage.position_deg() == pytest.approx(angle, abs=0.05)


def test_apt_undecodable_frame_is_typed_and_the_line_recovers():
    stage = _open("rotator-apt", "")
    stage.home()
    stage._unpacker.feed(b"\x64\x04\x0e\x00\x81\x01" + b"\x00" * 3)   # a frame cut short…
    stage._unpacker.feed(b"\xff" * 20)                                  # …then garbage
    try:
        stage.move_to(15.0)
    except InstrumentError:
        stage.move_to(15.0)
    assert stage.position_deg() == pytest.approx(15.0, abs=0.05)
