"""Zaber's own Motion Library (zaber-motion, ASCII) drives the rotator-zaber emulator over a pty
and over TCP: detection, identification data, homing, absolute / velocity / max / min moves,
position and warnings, settings, checksummed replies and alerts.  Offline: devices are detected
without the online device database (unidentified device, native units)."""

from __future__ import annotations

import threading

import pytest
from served import served, tcp_port

zaber_motion = pytest.importorskip(
    "zaber_motion", reason="zaber-motion (dev extra) is not installed")
from zaber_motion import Units
from zaber_motion.ascii import Connection

STEPS_PER_DEG = 1.0 / 0.000234375
# fast mechanics (900 °/s, 9000 °/s²) so the library's real-time polling stays short
FAST = {"max_velocity_deg_s": "900", "acceleration_deg_s2": "9000"}


def _open(server, transport: str) -> Connection:
    if transport == "pty":
        return Connection.open_serial_port(server.path)
    return Connection.open_tcp("127.0.0.1", tcp_port(server))


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_ordinary_workflow(transport):
    with served("rotator-zaber", transport, **FAST) as server, _open(server, transport) as conn:
        alerts = []
        three_alerts = threading.Event()

        def on_alert(alert) -> None:       # called on the library's own thread
            alerts.append(alert)
            if len(alerts) >= 3:
                three_alerts.set()

        conn.alert.subscribe(on_alert)
        # (identify_devices=True needs Zaber's online device database: not reachable here)
        devices = conn.detect_devices(identify_devices=False)
        assert [d.device_address for d in devices] == [1]
        device = devices[0]
        axis = device.get_axis(1)
        # identification data the library asks for, answered with the message id echoed
        assert device.generic_command("get deviceid").data == "30342"
        assert device.generic_command("get system.serial").data == "33456"
        assert device.generic_command("get system.axiscount").data == "1"
        assert axis.settings.get("resolution") == 64
        assert axis.settings.get("peripheralid") == 0
        # what the library and Zaber Launcher ask besides: answered, never BADCOMMAND
        assert device.generic_command("get comm.packet.size.max").data == "80"
        assert float(device.generic_command("get system.current").data) > 0
        assert axis.settings.get("driver.current.run") == 25
        assert axis.settings.get("knob.enable") == 1
        assert device.generic_command("identify").reply_flag == "OK"

        assert not axis.is_homed()
        axis.home()
        assert axis.is_homed()
        target = round(30.0 * STEPS_PER_DEG)
        axis.move_absolute(target, Units.NATIVE)
        assert axis.get_position(Units.NATIVE) == target
        assert server.emulator.angle_deg() == pytest.approx(30.0, abs=1e-3)
        assert axis.warnings.get_flags() == set()

        # checksummed replies from now on, and alerts at the end of every motion
        device.generic_command("set comm.checksum 1")
        device.generic_command("set comm.alert 1")
        # the travel range as the device reports it ends at the limit switches (±170°)
        assert axis.settings.get("limit.max", Units.NATIVE) == round(170 * STEPS_PER_DEG)
        axis.move_max()
        assert axis.get_position(Units.NATIVE) == round(170 * STEPS_PER_DEG)
        assert server.emulator.angle_deg() == pytest.approx(170.0, abs=1e-3)
        axis.move_min()
        assert axis.get_position(Units.NATIVE) == round(-170 * STEPS_PER_DEG)
        assert server.emulator.angle_deg() == pytest.approx(-170.0, abs=1e-3)
        assert axis.warnings.get_flags() == set()                      # no WL on the way

        speed = round(axis.settings.get("maxspeed", Units.NATIVE) / 10)
        axis.move_velocity(speed, Units.NATIVE)
        assert axis.is_busy()
        axis.stop()
        assert not axis.is_busy()
        assert axis.get_position(Units.NATIVE) > round(-170 * STEPS_PER_DEG)
        assert three_alerts.wait(timeout=5.0)
        assert [(a.device_address, a.axis_number, a.status) for a in alerts[:3]] == \
            [(1, 1, "IDLE")] * 3

        reply = device.generic_command("fly away", check_errors=False)
        assert (reply.reply_flag, reply.data) == ("RJ", "BADCOMMAND")
