"""Ways to reach an emulator: in-process pyserial URL, a pty, or a loopback TCP port."""

from __future__ import annotations

import os
import select
import socket
import sys
import tty
from typing import TextIO

import serial

from normbox_lab.core.clock import RealClock
from normbox_lab.sim import core


def register_url_scheme() -> None:
    """Make ``serial.serial_for_url("sim://cs1000a")`` reach the in-process emulators."""
    if "normbox_lab.sim" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("normbox_lab.sim")


def open_port(url: str, **kwargs) -> serial.SerialBase:
    """Open a real port (/dev/ttyUSB0, COM3), socket://host:port, or sim://DEVICE."""
    register_url_scheme()
    return serial.serial_for_url(url, **kwargs)


def _pump(emulator: core.Emulator, fd_read: int, fd_write_fn, wait_fds) -> bool:
    """Move bytes both ways once; False when the other end went away."""
    nxt = emulator.next_event_s()
    timeout = 0.05 if nxt is None else max(0.0, min(0.05, nxt - emulator.clock.now_s()))
    ready, _, _ = select.select(wait_fds, [], [], timeout)
    if fd_read in ready:
        try:
            data = os.read(fd_read, 4096)
        except OSError:
            data = b""
        if not data:
            return False
        emulator.feed(data)
    out = emulator.take_output()
    if out:
        fd_write_fn(out)
    return True


def serve_pty(device: str, faults: str = "", seed: int = 0, out: TextIO = sys.stdout,
              options: dict[str, str] | None = None) -> None:
    """Serve `device` on a new pseudo-terminal until interrupted."""
    emulator = core.create(device, clock=RealClock(), faults=faults, seed=seed,
                           **(options or {}))
    master, slave = os.openpty()
    tty.setraw(slave)
    print(f"pty: {os.ttyname(slave)}", file=out, flush=True)

    def write(data: bytes) -> None:
        os.write(master, data)

    try:
        while True:
            # A pty master reads EIO when no client has the slave open; keep serving.
            try:
                _pump(emulator, master, write, [master])
            except OSError:
                pass
    finally:
        os.close(master)
        os.close(slave)


def serve_tcp(device: str, host: str, port: int, faults: str = "", seed: int = 0,
              out: TextIO = sys.stdout, options: dict[str, str] | None = None) -> None:
    """Serve `device` on a loopback TCP port (one client at a time) until interrupted."""
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise ValueError(f"sim serve listens on loopback only, not {host!r}")
    emulator = core.create(device, clock=RealClock(), faults=faults, seed=seed,
                           **(options or {}))
    srv = socket.create_server((host, port))
    print(f"tcp: {host}:{srv.getsockname()[1]}", file=out, flush=True)
    try:
        while True:
            conn, _ = srv.accept()
            with conn:
                fd = conn.fileno()
                while _pump(emulator, fd, conn.sendall, [fd]):
                    pass
    finally:
        srv.close()
