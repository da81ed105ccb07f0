"""An emulator served on a pty or a loopback TCP port from a thread of the test process, on the
real clock (what `normbox-lab sim serve` does in its own process), for outside clients."""

from __future__ import annotations

import array
import contextlib
import fcntl
import termios
import threading
from collections.abc import Iterator

from serial.urlhandler import protocol_socket

from normbox_lab.core.clock import RealClock
from normbox_lab.sim import core, serve

NO_WORLD = object()


@contextlib.contextmanager
def served(device: str, transport: str, **options: str) -> Iterator[serve.TcpServer |
                                                                  serve.PtyServer]:
    """Yield the running server (`.url` for pyserial, `.path` for a pty, `.emulator`);
    `transport` is "pty", "tcp" (``socket://``) or "rfc2217" (``rfc2217://``)."""
    # not the process-wide world another test may have left in `core.CONTEXT`: with a world
    # that has nothing to say, the radiometers see their default light
    emulator = core.create(device, clock=RealClock(), world=NO_WORLD, **options)
    emulator.prepare()
    server = serve.PtyServer(emulator) if transport == "pty" else \
        serve.TcpServer(emulator, "127.0.0.1", 0, rfc2217=transport == "rfc2217")
    stop = threading.Event()
    thread = threading.Thread(target=server.serve, args=(stop,), daemon=True)
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join(timeout=5)


def tcp_port(server: serve.TcpServer) -> int:
    return int(server.endpoint.rsplit(":", 1)[1])


class CountingSocketSerial(protocol_socket.Serial):
    """pyserial's ``socket://`` port, except that `in_waiting` counts the bytes waiting.

    pyserial's own socket port reports 1 whenever anything is waiting, so a client that empties
    its input with ``read_all()`` (colour-specio does, before each read-out) takes one byte and
    leaves the rest of the line behind; a serial port reports the full count.
    """

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            return 0
        count = array.array("i", [0])
        fcntl.ioctl(self._socket, termios.FIONREAD, count)
        return count[0]
