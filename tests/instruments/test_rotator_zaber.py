"""Zaber ASCII rotation stage: exact lines, emulator mechanics, faults."""

from __future__ import annotations

import pytest
from wire import Exchange, ScriptedPort

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady, ProtocolError
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.sim import core
from normbox_lab.sim.rotator_zaber import ZaberRotatorEmulator

STEPS = 1 / 0.000234375        # 4266.67 µsteps/°
SPEED = round(10 * STEPS * 1.6384)            # 10 °/s  → 69905
ACCEL = round(20 * STEPS * 1.6384 / 10000)    # 20 °/s² → 14


def ok(data: str | int = 0, status: str = "IDLE", flag: str = "--") -> bytes:
    return f"@01 1 OK {status} {flag} {data}\r\n".encode()


CONNECT = [
    Exchange(b"/1 get deviceid\n", b"@01 0 OK IDLE -- 30342\r\n"),
    Exchange(b"/1 get system.serial\n", b"@01 0 OK IDLE -- 33456\r\n"),
    Exchange(b"/1 get version\n", b"@01 0 OK IDLE -- 7.38\r\n"),
    Exchange(b"/1 1 get maxspeed\n", ok(SPEED)),
    Exchange(b"/1 1 get accel\n", ok(ACCEL)),
]


def scripted(script: list[Exchange], **options) -> tuple[ZaberRotationStage, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(CONNECT + script, clock=clock, timeout=0.05)
    return ZaberRotationStage(port, clock, **options), port


def sim_stage(key: str, query: str = "", **options) -> tuple[ZaberRotationStage, ZaberRotatorEmulator]:
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    stage = ZaberRotationStage.open(f"sim://rotator-zaber?key={key}{query}", clock, **options)
    return stage, core.CONTEXT.instances[key]


# --- exact lines ---------------------------------------------------------------------------------

def test_connect_reads_identity_and_profile():
    stage, port = scripted([])
    ident = stage.identify()
    assert (ident.serial_number, ident.firmware, ident.extra["deviceid"]) == ("33456", "7.38", "30342")
    assert stage.max_velocity_deg_s == pytest.approx(10.0, rel=1e-5)
    assert stage.acceleration_deg_s2 == pytest.approx(ACCEL / 1.6384 * 10000 / STEPS)
    port.assert_done()


def test_move_abs_lines_poll_until_idle_and_check_encoder():
    n = round(60 * STEPS)
    assert n == 256000
    stage, port = scripted([
        Exchange(b"/1 1 warnings\n", ok("00")),                          # homed? (no WR)
        Exchange(b"/1 1 get pos\n", ok(0)),                              # from where (ETA)
        Exchange(b"/1 1 warnings clear\n", ok("01 NI", flag="NI")),
        Exchange(b"/1 1 move abs 256000\n", ok(0, "BUSY")),
        Exchange(b"/1 1\n", ok(0, "BUSY")),                              # at the ETA: still busy
        Exchange(b"/1 1\n", ok(0)),                                      # next poll: idle
        Exchange(b"/1 1 get encoder.pos\n", ok(256000)),
    ])
    t0 = stage.clock.now_s()
    stage.move_to(60.0)
    eta = stage.estimate_move_time_s(0.0, 60.0)
    assert stage.clock.now_s() - t0 == pytest.approx(eta + stage.poll_s, abs=1e-9)
    port.assert_done()


def test_home_stop_status_lines():
    stage, port = scripted([
        Exchange(b"/1 1 warnings clear\n", ok("01 WR", flag="WR")),
        Exchange(b"/1 1 home\n", ok(0, "BUSY", "WR")),
        Exchange(b"/1 1\n", ok(0, "BUSY", "WR")),
        Exchange(b"/1 1\n", ok(0)),
        Exchange(b"/1 1 get encoder.pos\n", ok(0)),
        Exchange(b"/1 1 stop\n", ok(0, flag="NI")),
        Exchange(b"/1 1\n", ok(0)),                    # stop waits until at rest
        Exchange(b"/1 1\n", ok(0)),
        Exchange(b"/1 1 warnings\n", ok("00")),
        Exchange(b"/1 1 get pos\n", ok(-4267)),
    ])
    stage.home()
    stage.stop(profiled=True)
    st = stage.status()
    assert st["homed"] and not st["moving"] and st["position_deg"] == pytest.approx(-4267 / STEPS)
    port.assert_done()


def test_rejected_command_raises_device_error_with_reason():
    stage, port = scripted([Exchange(b"/1 1 warnings\n", ok("00")),
                            Exchange(b"/1 1 get pos\n", ok(0)),
                            Exchange(b"/1 1 warnings clear\n", ok("00")),
                            Exchange(b"/1 1 move abs 42667\n", b"@01 1 RJ IDLE -- BADDATA\r\n")])
    with pytest.raises(DeviceError) as err:
        stage.move_to(10.0)
    assert err.value.code == "BADDATA"
    port.assert_done()


def test_not_homed_flag_means_not_ready():
    stage, port = scripted([Exchange(b"/1 1 warnings\n", ok("01 WR", flag="WR"))])
    with pytest.raises(NotReady):
        stage.move_to(10.0)
    port.assert_done()


def test_stall_flag_after_move_raises():
    stage, port = scripted([
        Exchange(b"/1 1 warnings\n", ok("00")), Exchange(b"/1 1 get pos\n", ok(0)),
        Exchange(b"/1 1 warnings clear\n", ok("00")),
        Exchange(b"/1 1 move abs 42667\n", ok(0, "BUSY")),
        Exchange(b"/1 1\n", ok(0, flag="FS")),
        Exchange(b"/1 1 warnings clear\n", ok("01 FS", flag="FS")),
    ])
    with pytest.raises(DeviceError) as err:
        stage.move_to(10.0)
    assert err.value.code == "FS"
    port.assert_done()


def test_info_and_alert_lines_are_skipped_garbage_is_a_protocol_error():
    stage, port = scripted([
        Exchange(b"/1 1 get pos\n", b"#01 1 some info\r\n!01 1 IDLE --\r\n" + ok(100)),
        Exchange(b"/1 1 get pos\n", b"@0x garbage\r\n"),
    ])
    assert stage.position_deg() == pytest.approx(100 / STEPS)
    with pytest.raises(ProtocolError):
        stage.position_deg()
    port.assert_done()


# --- emulator ------------------------------------------------------------------------------------

def ask(emu: ZaberRotatorEmulator, line: str) -> str:
    emu.feed(line.encode() + b"\n")
    return emu.take_output().decode()


def test_emulator_replies_and_rejections():
    clock = VirtualClock()
    emu = ZaberRotatorEmulator(clock)
    assert ask(emu, "/1 1") == "@01 1 OK IDLE WR 0\r\n"                 # power-up: no reference
    assert ask(emu, "/1 1 move abs 1000") == "@01 1 RJ IDLE WR BADDATA\r\n"
    assert ask(emu, "/1 1 fly") == "@01 1 RJ IDLE WR BADCOMMAND\r\n"
    assert ask(emu, "/1 2 get pos") == "@01 2 RJ IDLE WR BADAXIS\r\n"
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE WR 01 WR\r\n"
    assert ask(emu, "/1 1 home") == "@01 1 OK BUSY WR 0\r\n"             # already at home:
    assert emu.next_event_s() > 0.3                 # the switch approach takes time from 0° too
    clock.advance(2.0)
    assert ask(emu, "/1 1") == "@01 1 OK IDLE -- 0\r\n"
    assert ask(emu, "/1 1 move abs 99999999") == "@01 1 RJ IDLE -- BADDATA\r\n"
    assert ask(emu, "/1 1 move abs 256000") == "@01 1 OK BUSY -- 0\r\n"
    assert ask(emu, "/2 1 get pos") == ""                                 # another device


def test_emulator_60_degree_move_timing():
    clock = VirtualClock()
    emu = ZaberRotatorEmulator(clock)
    ask(emu, "/1 1 home")
    clock.advance(5.0)                                  # homing from 0°: the switch approach
    t0 = clock.now_s()
    ask(emu, "/1 1 move abs 256000")
    v = SPEED / 1.6384 / STEPS
    a = ACCEL / (1.6384 / 10000) / STEPS
    expected = 60 / v + v / a                                             # d ≥ v²/a
    assert emu.next_event_s() - t0 == pytest.approx(expected, abs=1e-9)
    clock.advance(expected - 1e-6)
    assert "BUSY" in ask(emu, "/1 1")
    clock.advance(2e-6)
    assert ask(emu, "/1 1 get pos") == "@01 1 OK IDLE -- 256000\r\n"
    assert emu.angle_deg() == pytest.approx(60.0)


def test_driver_against_emulator_eta_homing_and_world_angle():
    stage, emu = sim_stage("z-eta", "&power_up_angle_deg=25")
    assert not stage.is_homed()
    with pytest.raises(NotReady):
        stage.move_to(10.0)
    stage.home()
    assert stage.is_homed() and emu.angle_deg() == pytest.approx(0.0)
    for a, b in ((0.0, -80.0), (-80.0, -79.0), (-79.0, 40.0)):
        t0 = stage.clock.now_s()
        stage.move_to(b)
        took = stage.clock.now_s() - t0
        assert stage.estimate_move_time_s(a, b) - 1e-3 <= took <= stage.estimate_move_time_s(a, b) + 0.101
        assert emu.angle_deg() == pytest.approx(b, abs=1e-3)


def test_travel_range_ends_at_the_switches():
    stage, emu = sim_stage("z-range", max_angle_deg=179.0)
    stage.home()
    assert stage._command("get limit.max").data == str(round(170 / 0.000234375))
    with pytest.raises(DeviceError) as err:
        stage.move_to(175.0)                          # beyond limit.max: refused, no motion
    assert err.value.code == "BADDATA" and emu.angle_deg() == pytest.approx(0.0)
    reply = stage._command("move max")
    assert reply.ok
    stage.wait_idle(60.0)
    assert emu.angle_deg() == pytest.approx(170.0, abs=1e-3)      # at the switch, no WL
    assert stage._command("").flag == "--"


def test_limit_switch_trips_wl():
    # the firmware range set beyond the switch (limit.max 180°): a move trips it
    stage, emu = sim_stage("z-lim", "&travel_max_deg=180", max_angle_deg=179.0)
    stage.home()
    with pytest.raises(DeviceError) as err:
        stage.move_to(175.0)
    assert err.value.code == "WL"
    assert emu.angle_deg() == pytest.approx(170.0, abs=1e-6)


def test_stall_fault_stops_the_axis():
    stage, emu = sim_stage("z-stall", "&faults=stall@1:0.25")
    stage.home()
    with pytest.raises(DeviceError) as err:
        stage.move_to(80.0)
    assert err.value.code == "FS"
    assert 0.0 < emu.angle_deg() < 80.0
    stage.move_to(80.0)                                                   # next move is fine
    assert emu.angle_deg() == pytest.approx(80.0, abs=1e-3)


def test_power_blip_loses_reference_and_recovers():
    stage, emu = sim_stage("z-blip")
    stage.home()
    stage.move_to(30.0)
    emu.faults.add("power-blip", at_count=emu.faults._counters["power-blip"] + 1)
    with pytest.raises(InstrumentError):
        stage.move_to(40.0)
    with pytest.raises(NotReady):
        stage.move_to(40.0)
    stage.home()
    stage.move_to(40.0)
    assert emu.angle_deg() == pytest.approx(40.0, abs=1e-3)


def test_stop_interrupts_a_move():
    stage, emu = sim_stage("z-stop")
    stage.home()
    stage.move_to(90.0, wait=False)
    stage.clock.sleep(1.0)
    assert stage.is_moving()
    angle_at_stop = emu.angle_deg()
    t0 = stage.clock.now_s()
    stage.stop(profiled=True)                     # decelerates: 10 °/s at 20 °/s², 0.5 s
    assert not stage.is_moving()
    assert 0.45 <= stage.clock.now_s() - t0 <= 0.7
    # then v²/2a = 2.5° more (the stop reaches the device a serial line-time after the read)
    assert emu.angle_deg() - angle_at_stop == pytest.approx(10.0 ** 2 / (2 * 20.0), abs=0.05)
    assert stage.position_deg() == pytest.approx(emu.angle_deg(), abs=1e-3)


def test_served_on_tcp_a_plain_socket_client_and_the_driver_drive_it():
    import os
    import select
    import socket
    import subprocess
    import sys

    from normbox_lab.core.clock import RealClock

    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", "rotator-zaber",
                             "--tcp", "127.0.0.1:0"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=dict(os.environ))
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no endpoint printed"
        kind, _, where = proc.stdout.readline().decode().strip().partition(": ")
        assert kind == "tcp"
        host, _, port = where.partition(":")
        with socket.create_connection((host, int(port)), timeout=5) as s:
            s.sendall(b"/1 1 get pos\n")
            assert s.makefile("rb").readline() == b"@01 1 OK IDLE WR 0\r\n"
        stage = ZaberRotationStage.open(f"socket://{where}", RealClock(), command_timeout_s=5.0)
        stage.home()
        stage.move_to(0.5)
        assert stage.position_deg() == pytest.approx(0.5, abs=1e-3)
        stage.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
