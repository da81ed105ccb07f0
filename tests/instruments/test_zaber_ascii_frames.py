"""The rotator-zaber emulator against byte frames written from Zaber's ASCII Protocol Manual:
message ids, checksums, alerts, velocity / max / min moves and the settings a one-axis rotary
device has (virtual clock, no waiting)."""

from __future__ import annotations

import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim.rotator_zaber import STEPS_PER_DEG, ZaberRotatorEmulator, lrc


def ask(emu: ZaberRotatorEmulator, line: str) -> str:
    emu.feed(line.encode() + b"\n")
    return emu.take_output().decode()


def homed(clock: VirtualClock, **kw) -> ZaberRotatorEmulator:
    emu = ZaberRotatorEmulator(clock, **kw)
    ask(emu, "/1 1 home")
    clock.advance(60.0)
    ask(emu, "/1 1 warnings clear")
    return emu


def test_lrc_is_the_manuals_checksum():
    # the byte sum of the message (between '/' and ':') plus the checksum is 0 mod 256
    assert lrc("1 0 00 get pos") == f"{(-sum(b'1 0 00 get pos')) & 0xFF:02X}"
    assert (sum(b"0 0 00") + int(lrc("0 0 00"), 16)) % 256 == 0


def test_message_ids_are_echoed_in_every_reply():
    emu = ZaberRotatorEmulator(VirtualClock())
    assert ask(emu, "/1 0 00 get system.serial") == "@01 0 00 OK IDLE WR 33456\r\n"
    assert ask(emu, "/1 1 42 get pos") == "@01 1 42 OK IDLE WR 0\r\n"
    assert ask(emu, "/1 1 07 fly") == "@01 1 07 RJ IDLE WR BADCOMMAND\r\n"
    assert ask(emu, "/1 3 5 get pos") == "@01 3 5 RJ IDLE WR BADAXIS\r\n"
    assert ask(emu, "/1 1 100 get pos") == "@01 1 100 RJ IDLE WR BADMESSAGEID\r\n"
    assert ask(emu, "/0 0 12") == "@01 0 12 OK IDLE WR 0\r\n"       # detection broadcast


def test_checksums_accepted_checked_and_sent_on_request():
    emu = ZaberRotatorEmulator(VirtualClock())
    body = "1 0 03 get deviceid"
    assert ask(emu, f"/{body}:{lrc(body)}") == "@01 0 03 OK IDLE WR 30342\r\n"
    bad = f"{(int(lrc(body), 16) + 1) & 0xFF:02X}"
    assert ask(emu, f"/{body}:{bad}") == ""                          # corrupted: dropped
    assert ask(emu, "/1 set comm.checksum 1").startswith("@01 0 OK IDLE WR 0:")
    reply = ask(emu, "/1 1 get pos")
    text, _, cc = reply.strip().partition(":")
    assert text == "@01 1 OK IDLE WR 0" and cc == lrc(text[1:])


def test_device_and_axis_settings_of_a_one_axis_rotary_device():
    emu = ZaberRotatorEmulator(VirtualClock())
    expected = {"system.axiscount": "1", "resolution": "64", "peripheralid": "0",
                "deviceid": "30342", "version": "7.38", "version.build": "17220",
                "comm.alert": "0", "comm.checksum": "0", "limit.home.pos": "0",
                "system.access": "1"}
    for name, value in expected.items():
        assert ask(emu, f"/1 1 get {name}") == f"@01 1 OK IDLE WR {value}\r\n", name
    assert ask(emu, "/1 1 set resolution 128") == "@01 1 RJ IDLE WR BADDATA\r\n"   # read-only
    assert ask(emu, "/1 1 set comm.alert 2") == "@01 1 RJ IDLE WR BADDATA\r\n"
    assert ask(emu, "/1 1 get no.such.setting") == "@01 1 RJ IDLE WR BADCOMMAND\r\n"
    assert ask(emu, "/1 1 tools echo hello") == "@01 1 OK IDLE WR hello\r\n"


def test_alert_when_a_motion_ends():
    clock = VirtualClock()
    emu = homed(clock)
    assert ask(emu, "/1 set comm.alert 1") == "@01 0 OK IDLE -- 0\r\n"
    assert ask(emu, "/1 1 move abs 42667") == "@01 1 OK BUSY -- 0\r\n"      # 10°
    clock.advance(0.5)
    assert emu.take_output() == b""
    clock.advance(5.0)
    assert emu.take_output() == b"!01 1 IDLE --\r\n"
    assert ask(emu, "/1 1 move vel 1000") == "@01 1 OK BUSY -- 0\r\n"
    clock.advance(1.0)
    assert ask(emu, "/1 1 stop") == "@01 1 OK BUSY NI 0\r\n"             # decelerating
    clock.advance(0.05)
    assert emu.take_output() == b"!01 1 IDLE NI\r\n"
    assert ask(emu, "/1 1 move vel 1000") == "@01 1 OK BUSY NI 0\r\n"
    assert ask(emu, "/1 1 estop") == "@01 1 OK IDLE NI 0\r\n!01 1 IDLE NI\r\n"


def test_move_max_min_and_velocity():
    clock = VirtualClock()
    emu = homed(clock)
    ask(emu, f"/1 1 set limit.max {round(150 * STEPS_PER_DEG)}")
    ask(emu, f"/1 1 set limit.min {round(-150 * STEPS_PER_DEG)}")
    assert ask(emu, "/1 1 move max") == "@01 1 OK BUSY -- 0\r\n"
    clock.advance(30.0)
    assert ask(emu, "/1 1 get pos") == f"@01 1 OK IDLE -- {round(150 * STEPS_PER_DEG)}\r\n"
    assert ask(emu, "/1 1 move min") == "@01 1 OK BUSY -- 0\r\n"
    clock.advance(60.0)
    assert emu.angle_deg() == pytest.approx(-150.0, abs=1e-6)
    # constant velocity: 1 °/s in native units (µsteps/s × 1.6384) until stopped
    v = round(1.0 * STEPS_PER_DEG * 1.6384)
    assert ask(emu, f"/1 1 move vel {v}") == "@01 1 OK BUSY -- 0\r\n"
    clock.advance(10.0)
    assert ask(emu, "/1 1 stop") == "@01 1 OK BUSY NI 0\r\n"             # decelerating
    clock.advance(1.0)
    # 10 s at v less what the ramp-up costs, v²/(2a), plus the run-on of the stop, v²/(2a)
    v_deg_s = v / 1.6384 / STEPS_PER_DEG
    assert emu.angle_deg() == pytest.approx(-150.0 + 10.0 * v_deg_s, abs=1e-6)
    assert ask(emu, "/1 1 move vel 99999999") == "@01 1 RJ IDLE NI BADDATA\r\n"
    # a velocity run ends at the hardware limit switch: WL
    ask(emu, "/1 1 warnings clear")
    assert ask(emu, "/1 1 move vel -20000") == "@01 1 OK BUSY -- 0\r\n"
    clock.advance(600.0)
    assert ask(emu, "/1 1") == "@01 1 OK IDLE WL 0\r\n"
    assert emu.angle_deg() == pytest.approx(-170.0, abs=1e-6)


def test_moves_need_a_reference_but_velocity_does_not():
    clock = VirtualClock()
    emu = ZaberRotatorEmulator(clock)
    assert ask(emu, "/1 1 move max") == "@01 1 RJ IDLE WR BADDATA\r\n"
    assert ask(emu, "/1 1 move vel 1000") == "@01 1 OK BUSY WR 0\r\n"
    assert ask(emu, "/1 1 move sideways 3") == "@01 1 RJ BUSY WR BADCOMMAND\r\n"


def test_system_reset_loses_the_reference():
    clock = VirtualClock()
    emu = homed(clock)
    assert ask(emu, "/1 system reset") == "@01 0 OK IDLE -- 0\r\n"
    assert ask(emu, "/1 1 warnings") == "@01 1 OK IDLE WR 01 WR\r\n"
