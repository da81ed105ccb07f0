"""Reaching an emulator in-process: the ``sim://`` pyserial URL scheme (a pty or a loopback TCP
port: `normbox_lab.sim.serve`)."""

from __future__ import annotations

import serial


def register_url_scheme() -> None:
    """Make ``serial.serial_for_url("sim://cs1000a")`` reach the in-process emulators."""
    if "normbox_lab.sim" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("normbox_lab.sim")


def open_port(url: str, **kwargs) -> serial.SerialBase:
    """Open a real port (/dev/ttyUSB0, COM3), socket://host:port, or sim://DEVICE."""
    register_url_scheme()
    return serial.serial_for_url(url, **kwargs)
