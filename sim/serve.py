"""Serving one emulator to outside programs: a pseudo-terminal or a loopback TCP port.

The emulator runs on the real clock and is serviced continuously, whether or not a client is
attached: its motions finish, its measurements end, and what it says while nobody listens is
lost (as on a serial cable with no computer at the other end).  A new TCP connection, or a
client opening the pty, starts from a clean line: nothing said before it came reaches it, as
with a freshly opened serial port, and neither does what the emulator would still have said to
the client before (`Emulator.new_client`: the replies of a measurement that client started).
One TCP client at a time; a second connection is closed at once.

Linux ptys cannot carry modem lines (RTS/DTR ioctls fail on them), so clients that set or
pulse RTS/DTR (Thorlabs APT clients do) should use the TCP endpoint through pyserial's
``socket://HOST:PORT`` URL.  pyserial's ``socket://`` port reports at most 1 byte in
`in_waiting`, so a client that empties its input with ``read_all()`` (colour-specio does)
leaves the rest of a line behind; with ``rfc2217=True`` the port speaks RFC 2217 (*Telnet Com
Port Control Option*, IETF 1997; pyserial's own `serial.rfc2217.PortManager` on this side) and clients use
``rfc2217://HOST:PORT``, whose `in_waiting` counts every byte, and whose baud rate, framing and
modem-line settings are accepted (and, as over USB, do not matter to the emulator).

    server = TcpServer(emulator, "127.0.0.1", 0)      # or PtyServer(emulator)
    print(server.endpoint)                            # "tcp: 127.0.0.1:40123"
    server.serve(stop_event)                          # until stop_event is set

`serve_until_signalled(server)` is what `normbox-lab sim serve` runs: it serves until SIGTERM
or SIGINT, closes the endpoint and ends the process at once (within a poll interval, 20 ms):
tearing down the emulator's libraries (colour-science for the radiometers) took seconds.
"""

from __future__ import annotations

import os
import select
import signal
import socket
import sys
import threading
import tty

import serial
from serial.rfc2217 import PortManager

from normbox_lab.sim import core
from normbox_lab.sim.protocol_sim import ModemLinesOn

LOOPBACK_FAMILIES = {"127.0.0.1": socket.AF_INET, "localhost": socket.AF_INET,
                     "::1": socket.AF_INET6}
POLL_S = 0.02


class EndpointError(ValueError):
    """A --tcp endpoint that cannot be served (malformed, not loopback, port out of range)."""


def parse_tcp_endpoint(text: str) -> tuple[str, int]:
    """``127.0.0.1:PORT``, ``localhost:PORT``, ``::1:PORT`` or ``[::1]:PORT`` → (host, port)."""
    host, sep, port_text = text.strip().rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host:
        raise EndpointError(f"--tcp wants HOST:PORT, got {text!r}")
    if host not in LOOPBACK_FAMILIES:
        raise EndpointError(f"sim serve listens on loopback only (127.0.0.1, localhost, ::1), "
                            f"not {host!r}")
    # ASCII digits, at most 5 (str.isdigit() is true for "٣", which int() reads as 3; a
    # 5000-digit port would hit Python's 4300-digit conversion limit)
    if not (port_text.isascii() and port_text.isdigit() and len(port_text) <= 5) \
            or not 0 <= int(port_text) <= 65535:
        raise EndpointError(f"--tcp port must be 0..65535, got {port_text!r}")
    return host, int(port_text)


def _timeout_s(emulator: core.Emulator) -> float:
    nxt = emulator.next_event_s()
    if nxt is None:
        return POLL_S
    return max(0.0, min(POLL_S, nxt - emulator.clock.now_s()))


class _LineSettings(ModemLinesOn, serial.SerialBase):
    """The serial settings an RFC 2217 client sets (baud rate, framing, flow control, RTS/DTR,
    break): kept and read back, as `PortManager` needs; the emulator ignores them (as over
    USB).  Modem inputs read CTS, DSR and CD on, RI off."""

    def __init__(self) -> None:
        super().__init__()                       # no port: never "opened"

    def reset_input_buffer(self) -> None: ...
    def reset_output_buffer(self) -> None: ...


class _SocketWriter:
    """`PortManager`'s connection: Telnet negotiation and notifications to the client."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn

    def write(self, data: bytes) -> None:
        try:
            self.conn.sendall(data)
        except OSError:
            pass                                 # the client left: the step notices


class _Server:
    """Serves until `stop` is set: `step()` moves bytes (at most POLL_S), `close()` ends."""

    def serve(self, stop: threading.Event | None = None) -> None:
        stop = stop or threading.Event()
        try:
            while not stop.is_set():
                self.step()
        finally:
            self.close()

    def step(self) -> None:  # pragma: no cover - per endpoint
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - per endpoint
        raise NotImplementedError


class TcpServer(_Server):
    def __init__(self, emulator: core.Emulator, host: str, port: int, *,
                 rfc2217: bool = False) -> None:
        self.emulator = emulator
        self.rfc2217 = rfc2217
        self._manager: PortManager | None = None
        family = LOOPBACK_FAMILIES.get(host)
        if family is None:
            raise EndpointError(f"sim serve listens on loopback only, not {host!r}")
        try:
            self.listener = socket.create_server((host, port), family=family)
        except OSError as exc:
            raise EndpointError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") \
                from exc
        bound_port = self.listener.getsockname()[1]
        shown = f"[{host}]" if family == socket.AF_INET6 else host
        self.url = f"{'rfc2217' if rfc2217 else 'socket'}://{shown}:{bound_port}"
        self.endpoint = f"tcp: {shown}:{bound_port}"
        self.client: socket.socket | None = None

    def _drop_client(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
            self._manager = None

    def close(self) -> None:
        self._drop_client()
        self.listener.close()

    def step(self) -> None:
        """Wait for bytes or the emulator's next event (at most POLL_S), then move bytes."""
        emu = self.emulator
        fds = [self.listener] + ([self.client] if self.client is not None else [])
        ready, _, _ = select.select(fds, [], [], _timeout_s(emu))
        if self.client is not None and self.client in ready:
            try:
                data = self.client.recv(4096)
            except OSError:
                data = b""
            if not data:
                self._drop_client()              # the client hung up
            else:
                if self._manager is not None:    # Telnet / RFC 2217 commands taken out
                    data = b"".join(self._manager.filter(data))
                if data:
                    emu.feed(data)
        if self.listener in ready:
            conn, _ = self.listener.accept()
            if self.client is None:
                emu.new_client()             # said, or still to say, to the one before: lost
                self.client = conn
                if self.rfc2217:
                    self._manager = PortManager(_LineSettings(), _SocketWriter(conn))
            else:
                conn.close()                 # one client at a time
        out = emu.take_output()
        if out and self._manager is not None:
            out = b"".join(self._manager.escape(out))
        if out and self.client is not None:
            try:
                self.client.sendall(out)
            except OSError:
                self._drop_client()


class PtyServer(_Server):
    """A pseudo-terminal whose slave end is left to the client: while nobody has it open, the
    master reads EIO, and what the emulator says is lost; a client that opens it starts from a
    clean line."""

    def __init__(self, emulator: core.Emulator) -> None:
        self.emulator = emulator
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(self.master, False)
        self.url = self.path
        self.endpoint = f"pty: {self.path}"
        self.client_present = False

    def close(self) -> None:
        os.close(self.master)

    def step(self) -> None:
        emu = self.emulator
        timeout = _timeout_s(emu)
        ready, _, _ = select.select([self.master], [], [], timeout)
        present, data = True, b""
        if ready:
            try:
                data = os.read(self.master, 4096)
            except BlockingIOError:
                pass
            except OSError:            # EIO: no client has the slave open
                present = False
        if present and not self.client_present:
            emu.new_client()           # said, or still to say, to the one before: lost
        self.client_present = present
        if data:
            emu.feed(data)
        out = emu.take_output()
        if not present:
            threading.Event().wait(timeout)    # EIO is always "ready": do not spin
            return
        if out:
            try:
                os.write(self.master, out)
            except OSError:            # buffer full or the client just left: lost
                pass


def serve_until_signalled(server: TcpServer | PtyServer) -> None:
    """Serve until SIGTERM or SIGINT, close the endpoint, then end the process at once (no
    interpreter teardown: nothing is left to write, and unloading colour-science and numpy
    took the radiometers 1–6 s).  Returns only when serving ends otherwise."""
    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, _stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        server.serve(stop)
    finally:
        if stop.is_set():
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
