"""pylablib's ``Thorlabs.KinesisMotor`` (an outside client, GPL, dev extra only) drives the
rotator-apt (K10CR1) emulator: connect (it pulses RTS), home, re-home with ``force=True`` from
40°, a continuous "+" jog, stop.

pylablib opens a port through pyserial's ``serial_for_url`` when told the backend:
``KinesisMotor(("serial", URL))``.  A Linux pty takes no modem-control ioctl (TIOCMBIS:
ENOTTY), so pylablib's RTS pulse fails on ``sim serve rotator-apt --pty``; an RFC 2217 or plain
TCP port carries it (``sim serve rotator-apt --tcp 127.0.0.1:PORT`` then
``("serial", "rfc2217://127.0.0.1:PORT")`` or ``("serial", "socket://127.0.0.1:PORT")``)."""

from __future__ import annotations

import time

import pytest
from served import served

kinesis = pytest.importorskip("pylablib.devices.Thorlabs",
                              reason="pylablib (dev extra, GPL) is not installed")

STEPS_PER_DEG = 409600 / 3
FAST = {"max_velocity_deg_s": "200", "acceleration_deg_s2": "2000",
        "home_velocity_deg_s": "200", "power_up_angle_deg": "40"}


@pytest.mark.parametrize("transport", ["rfc2217", "tcp"])
def test_pylablib_rehomes_for_real_and_jogs_the_documented_way(transport):
    with served("rotator-apt", transport, **FAST) as server:
        motor = kinesis.KinesisMotor(("serial", server.url), scale="K10CR1")
        try:
            assert motor.get_device_info()[:2] == (55123456, "K10CR1")
            assert motor.get_scale()[0] == pytest.approx(STEPS_PER_DEG)
            motor.home(sync=True, force=True)
            assert "homed" in motor.get_status() and motor.get_position() == 0
            motor.move_to(40.0)
            motor.wait_move()
            assert server.emulator.angle_deg() == pytest.approx(40.0, abs=1e-4)
            # a forced re-home really goes back to the switch (homed bit cleared meanwhile)
            motor.home(sync=True, force=True)
            assert server.emulator.angle_deg() == pytest.approx(0.0, abs=1e-6)
            assert motor.get_position() == 0 and "homed" in motor.get_status()
            # "+" (pylablib sends direction code 2) turns the rotor towards positive angles
            motor.jog("+", kind="continuous")
            deadline = time.monotonic() + 5.0        # the served emulator runs in real time
            while server.emulator.angle_deg() < 5.5 and time.monotonic() < deadline:
                motor.get_status()                   # a round trip each, no sleeping
            # pylablib names bit 0x20 "moving_fw" (towards positive), 0x10 "moving_bk"
            assert "moving_fw" in motor.get_status()
            motor.stop(sync=True)
            assert server.emulator.angle_deg() > 5.0
            assert motor.get_position() == pytest.approx(server.emulator.angle_deg(), abs=1e-3)
        finally:
            motor.close()


def test_pylablib_on_a_pty_fails_on_the_rts_pulse():
    with served("rotator-apt", "pty", **FAST) as server, pytest.raises(OSError):
        kinesis.KinesisMotor(("serial", server.path), scale="K10CR1")
