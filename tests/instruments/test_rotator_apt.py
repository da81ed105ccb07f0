"""Thorlabs APT (K10CR1) rotation stage: exact frames, emulator mechanics, faults."""

from __future__ import annotations

import struct

import pytest
from wire import Exchange, ScriptedPort

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.sim import core
from normbox_lab.sim.rotator_apt import AptRotatorEmulator

STEPS = 409600 / 3
# host → controller frames, written out byte by byte from the protocol (not from the library)
REQ_INFO = bytes.fromhex("050000005001")
ENABLE = bytes.fromhex("100201015001")
REQ_VEL = bytes.fromhex("140401005001")
REQ_STATUS = bytes.fromhex("800401005001")
HOME = bytes.fromhex("430401005001")
STOP = bytes.fromhex("650401025001")
STOP_NOW = bytes.fromhex("650401015001")
IDENTIFY = bytes.fromhex("230201005001")
START_UPDATES = bytes.fromhex("110000005001")
STOP_UPDATES = bytes.fromhex("120000005001")
DISCONNECT = bytes.fromhex("020000005001")
ACK = bytes.fromhex("920400005001")
V_APT = round(10 * STEPS * 53.68)          # 10 °/s
A_APT = round(10 * STEPS / 90.9)           # 10 °/s²
SET_VEL = bytes.fromhex("13040e00d001") + struct.pack("<H3l", 1, 0, A_APT, V_APT)

HOMED_BITS = 0x80000000 | 0x400 | 0x100


def move_abs(steps: int) -> bytes:
    return bytes.fromhex("53040600d001") + struct.pack("<Hl", 1, steps)


def reply_long(msg_id: int, data: bytes) -> bytes:
    return struct.pack("<HHBB", msg_id, len(data), 0x81, 0x50) + data


def status(pos: int, enc: int | None = None, bits: int = HOMED_BITS, msg_id: int = 0x0481) -> bytes:
    if msg_id in (0x0464, 0x0466):        # MOVE_COMPLETED / STOPPED: chan, pos, vel, 0, bits
        return reply_long(msg_id, struct.pack("<HlhHL", 1, pos, 0, 0, bits))
    return reply_long(msg_id, struct.pack("<HllL", 1, pos, pos if enc is None else enc, bits))


INFO = reply_long(0x0006, struct.pack("<l8sH4B60sHHH", 55000001, b"K10CR1\0\0", 16, 0, 3, 1, 0,
                                      b"".ljust(60, b"\0"), 1, 0, 1))
VEL = reply_long(0x0415, struct.pack("<H3l", 1, 0, A_APT, V_APT))
CONNECT = [Exchange(REQ_INFO, INFO), Exchange(ENABLE), Exchange(SET_VEL), Exchange(REQ_VEL, VEL)]


def scripted(script: list[Exchange], **options) -> tuple[AptRotationStage, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(CONNECT + script, clock=clock, timeout=0.05)
    return AptRotationStage(port, clock, **options), port


# --- exact frames -------------------------------------------------------------------------------

def test_connect_identify_and_profile():
    stage, port = scripted([Exchange(IDENTIFY)])
    ident = stage.identify()
    assert ident.model == "K10CR1" and ident.serial_number == "55000001"
    assert stage.max_velocity_deg_s == pytest.approx(10.0, rel=1e-6)
    assert stage.acceleration_deg_s2 == pytest.approx(10.0, rel=1e-4)
    stage.flash_led()
    port.assert_done()


def test_move_absolute_frames_wait_for_completion_and_check_position():
    target = round(60 * STEPS)
    assert target == 8192000
    stage, port = scripted([
        Exchange(REQ_STATUS, status(0)),                     # homed?
        Exchange(REQ_STATUS, status(0)),                     # where from (ETA)
        Exchange(move_abs(target), status(target, msg_id=0x0464), delay_s=7.0),
        Exchange(REQ_STATUS, status(target)),                # readback check
    ])
    t0 = stage.clock.now_s()
    stage.move_to(60.0)
    assert stage.clock.now_s() - t0 == pytest.approx(7.0, abs=0.06)
    port.assert_done()


def test_home_frames():
    stage, port = scripted([Exchange(HOME, bytes.fromhex("440401000150"), delay_s=2.0),
                            Exchange(REQ_STATUS, status(0))])
    stage.home()
    port.assert_done()


def test_stop_and_close_frames():
    # stop() halts at once (immediate, 0x01: the emergency stop); stop(profiled=True) sends 0x02
    stage, port = scripted([Exchange(STOP_NOW, status(1000, msg_id=0x0466)),
                            Exchange(STOP, status(1000, msg_id=0x0466)),
                            Exchange(DISCONNECT)])
    stage.stop()
    stage.stop(profiled=True)
    stage.close()
    port.assert_done()


def test_push_mode_sends_keepalive_and_uses_pushed_status():
    pushes = [(0.1 * k, status(k * 1000, bits=HOMED_BITS | 0x10)) for k in range(1, 30)]
    stage, port = scripted([Exchange(START_UPDATES, pushes), Exchange(ACK), Exchange(ACK),
                            Exchange(STOP_UPDATES), Exchange(DISCONNECT)],
                           update_messages=True)
    # listening for 2.5 s: pushed frames are consumed, an ACK goes out every 0.9 s
    deadline = stage.clock.now_s() + 2.55
    n = 0
    while (msg := stage._next_frame(deadline)) is not None:
        stage._handle(msg)
        n += 1
    assert n == 25 and stage._status["position"] == 25000
    stage.close()
    port.assert_done()


def test_soft_limit_refused_before_anything_is_sent():
    stage, port = scripted([], min_angle_deg=0.0, max_angle_deg=95.0)
    with pytest.raises(DeviceError) as err:
        stage.move_to(120.0)
    assert err.value.code == "SOFT_LIMIT"
    port.assert_done()


def test_limit_switch_reply_raises_limit_error():
    stage, port = scripted([
        Exchange(REQ_STATUS, status(0)), Exchange(REQ_STATUS, status(0)),
        Exchange(move_abs(round(175 * STEPS)), status(round(170 * STEPS), msg_id=0x0466,
                                                      bits=HOMED_BITS | 0x1), delay_s=18.0),
        Exchange(REQ_STATUS, status(round(170 * STEPS), bits=HOMED_BITS | 0x1)),
    ], max_angle_deg=200.0)
    with pytest.raises(DeviceError) as err:
        stage.move_to(175.0)
    assert err.value.code == "LIMIT"
    port.assert_done()


def test_garbage_before_a_reply_is_skipped():
    stage, port = scripted([Exchange(REQ_STATUS, b"\xff\x13\x00" + status(4096))])
    assert stage.position_deg() == pytest.approx(4096 / STEPS)
    port.assert_done()


def test_no_reply_times_out_typed():
    stage, _port = scripted([Exchange(REQ_STATUS, b"")])
    with pytest.raises(InstrumentError):
        stage.position_deg()


# --- emulator on the virtual clock ----------------------------------------------------------------

def frames(emu: AptRotatorEmulator) -> list[tuple[int, bytes]]:
    out, buf = [], emu.take_output()
    while len(buf) >= 6:
        msg_id, n, dest, _src = struct.unpack_from("<HHBB", buf)
        size = 6 + (n if dest & 0x80 else 0)
        out.append((msg_id, buf[:size]))
        buf = buf[size:]
    return out


def test_emulator_60_degree_move_follows_the_trapezoid():
    clock = VirtualClock()
    emu = AptRotatorEmulator(clock)
    emu.feed(ENABLE)
    emu.feed(HOME)
    clock.advance(1.3)
    assert [m for m, _ in frames(emu)] == [0x0444]    # from 0°: the switch approach, 1.26 s
    emu.feed(move_abs(round(60 * STEPS)))
    t0 = clock.now_s()
    # v = 10 °/s, a = 10 °/s²: T = d/v + v/a = 6 + 1 = 7 s; 0.5 s in: a t²/2 = 1.25°
    clock.advance(0.5)
    assert emu.angle_deg() == pytest.approx(1.25, abs=1e-9)
    clock.advance(3.5 - 0.5)                                   # mid-move: 5° + 10°/s·2.5 s
    assert emu.angle_deg() == pytest.approx(30.0, abs=1e-9)
    assert emu.next_event_s() == pytest.approx(t0 + 7.0, abs=1e-9)
    clock.advance(3.4999)
    assert frames(emu) == []
    clock.advance(0.0002)
    got = frames(emu)
    assert [m for m, _ in got] == [0x0464]
    # MOVE_COMPLETED carries the status structure: chan, position, velocity, reserved, bits
    _chan, pos, velocity, _reserved, bits = struct.unpack_from("<HlhHL", got[0][1], 6)
    assert pos == 8192000 and velocity == 0 and bits & 0x400


def test_driver_eta_equals_emulator_time_and_world_angle():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?power_up_angle_deg=-12&key=apt-eta", clock)
    with pytest.raises(NotReady):
        stage.move_to(30.0)                                    # homing required after power-up
    t0 = clock.now_s()
    stage.home()
    # 5 °/s homing, then the switch approach (1° off and back: 2 × 2·√(1/10) s)
    assert clock.now_s() - t0 == pytest.approx(12 / 5 + 5 / 10 + 4 * 0.1 ** 0.5, abs=0.06)
    for a, b in ((0.0, 60.0), (60.0, 62.5), (62.5, 30.0)):
        t0 = clock.now_s()
        stage.move_to(b)
        assert clock.now_s() - t0 == pytest.approx(stage.estimate_move_time_s(a, b), abs=0.06)
        assert core.CONTEXT.instances["apt-eta"].angle_deg() == pytest.approx(b, abs=1e-5)
    stage.move_by(-5.0)
    assert stage.position_deg() == pytest.approx(25.0, abs=1e-5)


def test_hardware_limit_switch_through_the_emulator():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    # a K10CR1 has none: switches added to the emulator (counts up ends at the switch the
    # protocol calls "reverse": direction code 0x02 increases the counter)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-lim&limit_max_deg=170", clock,
                                  max_angle_deg=200.0)
    stage.home()
    with pytest.raises(DeviceError) as err:
        stage.move_to(175.0)
    assert err.value.code == "LIMIT"
    assert core.CONTEXT.instances["apt-lim"].angle_deg() == pytest.approx(170.0, abs=1e-6)
    assert stage.status()["limit_reverse"]
    stage.move_to(90.0)                                        # back off the switch
    assert not stage.status()["limit_reverse"]


def test_k10cr1_rotates_continuously_soft_limits_are_the_labs():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-cont", clock, max_angle_deg=200.0)
    stage.home()
    stage.move_to(185.0)                                        # past ±170°: no switch there
    assert core.CONTEXT.instances["apt-cont"].angle_deg() == pytest.approx(185.0, abs=1e-5)
    holder = AptRotationStage.open("sim://rotator-apt?key=apt-cont2", clock)  # ±170° config
    holder.home()
    with pytest.raises(DeviceError):
        holder.move_to(175.0)


def test_stall_is_caught_by_the_encoder_check():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-stall&faults=stall@2:0.5", clock)
    stage.home()
    stage.move_to(10.0)                                        # move 1: fine
    with pytest.raises(DeviceError) as err:
        stage.move_to(70.0)                                    # move 2 stalls half-way in time
    assert err.value.code == "POSITION"
    assert core.CONTEXT.instances["apt-stall"].angle_deg() == pytest.approx(40.0, abs=1e-4)


def test_power_blip_loses_homing_and_recovers():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-blip", clock)
    stage.home()
    stage.move_to(45.0)
    emu = core.CONTEXT.instances["apt-blip"]
    emu.faults.add("power-blip", at_count=emu.faults._counters["power-blip"] + 1)
    with pytest.raises(InstrumentError):
        stage.move_to(50.0)
    with pytest.raises(NotReady):                             # reconnected, reference lost
        stage.move_to(50.0)
    stage.home()
    stage.move_to(50.0)
    assert emu.angle_deg() == pytest.approx(50.0, abs=1e-5)


def test_auto_home_after_power_blip():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-auto&power_up_angle_deg=33", clock,
                                  auto_home=True)
    stage.move_to(20.0)
    assert core.CONTEXT.instances["apt-auto"].angle_deg() == pytest.approx(20.0, abs=1e-5)


def test_stop_while_moving():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-stop", clock)
    stage.home()
    stage.move_to(90.0, wait=False)
    clock.advance(2.0)
    assert stage.is_moving()
    t0 = clock.now_s()
    stage.stop(profiled=True)                                  # decelerates
    assert not stage.is_moving()
    assert clock.now_s() - t0 == pytest.approx(1.0, abs=0.06)  # 10 °/s at 10 °/s²: 1 s
    # 5° + 10 °/s · 1 s at the stop, then v²/2a = 5° more
    assert stage.position_deg() == pytest.approx(20.0, abs=1e-4)


def test_lost_keepalive_stops_pushes():
    clock = VirtualClock()
    emu = AptRotatorEmulator(clock)
    emu.feed(START_UPDATES)
    clock.advance(1.0)
    assert len(frames(emu)) == 10
    clock.advance(10.0)
    assert 35 <= len(frames(emu)) <= 45                        # stopped ~5 s after the last ack
    clock.advance(5.0)
    assert frames(emu) == []
    emu.feed(ACK)
    clock.advance(0.55)
    assert len(frames(emu)) == 5


def test_transport_disconnect_then_reconnect():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = AptRotationStage.open("sim://rotator-apt?key=apt-disc", clock)
    stage.home()
    emu = core.CONTEXT.instances["apt-disc"]
    emu.disconnect(3.0)
    with pytest.raises(InstrumentError):
        stage.position_deg()
    assert stage.position_deg() == pytest.approx(0.0)        # reopened and re-initialised


def test_served_on_a_pty_the_driver_drives_it_from_another_process():
    import os
    import select
    import subprocess
    import sys

    from normbox_lab.core.clock import RealClock

    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", "rotator-apt",
                             "--pty"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ))
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no endpoint printed"
        kind, _, path = proc.stdout.readline().decode().strip().partition(": ")
        assert kind == "pty"
        stage = AptRotationStage.open(path, RealClock(), command_timeout_s=5.0)
        assert stage.identify().model == "K10CR1"
        stage.home()                                    # at 0 already: homed at once
        stage.move_to(0.5)                              # 2·√(0.5/10) ≈ 0.45 s of real motion
        assert stage.position_deg() == pytest.approx(0.5, abs=1e-4)
        stage.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_implements_the_rotation_stage_role():
    from normbox_lab.core.capabilities import RotationStage

    stage, _ = scripted([])
    assert isinstance(stage, RotationStage)
