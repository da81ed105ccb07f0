"""`sim serve`: endpoints (IPv6 loopback, bad ones refused with one line and exit 2), a TCP
emulator that is serviced while nobody is connected, and a clean line for each new client."""

from __future__ import annotations

import os
import socket
import tty

import pytest

from normbox_lab.cli import main
from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim import core, serve
from normbox_lab.sim.rotator_zaber import ZaberRotatorEmulator


@pytest.mark.parametrize("endpoint, message", [
    ("127.0.0.1:99999", "port must be 0..65535"),
    ("garbage", "wants HOST:PORT"),
    ("127.0.0.1:http", "port must be 0..65535"),
    ("10.1.2.3:5000", "loopback only"),
])
def test_bad_endpoints_are_refused_with_one_line_and_exit_2(endpoint, message, capsys):
    assert main(["sim", "serve", "rotator-zaber", "--tcp", endpoint]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1 and message in err and "Traceback" not in err


def test_port_in_use_is_one_line_too(capsys):
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        assert main(["sim", "serve", "rotator-zaber", "--tcp", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"cannot listen on 127.0.0.1:{port}" in err


def test_endpoint_parsing():
    assert serve.parse_tcp_endpoint("::1:0") == ("::1", 0)
    assert serve.parse_tcp_endpoint("[::1]:4001") == ("::1", 4001)
    assert serve.parse_tcp_endpoint("localhost:65535") == ("localhost", 65535)


def _pump_until(server: serve.TcpServer, conn: socket.socket, want: bytes,
                clock: VirtualClock | None = None, steps: int = 200) -> bytes:
    """Step the server until `conn` has received a reply ending in `want` (or `steps` passed);
    with `clock`, the virtual clock moves 50 ms a step (the replies' line time)."""
    got = b""
    for _ in range(steps):
        if clock is not None:
            clock.advance(0.05)
        server.step()
        try:
            got += conn.recv(4096)
        except BlockingIOError:
            pass
        if got.endswith(want):
            return got
    return got


@pytest.mark.skipif(not socket.has_ipv6, reason="this host has no IPv6 stack")
def test_ipv6_loopback_serves():
    emu = ZaberRotatorEmulator(VirtualClock())
    server = serve.TcpServer(emu, "::1", 0)
    assert server.endpoint.startswith("tcp: [::1]:") and server.url.startswith("socket://[::1]:")
    port = int(server.endpoint.rsplit(":", 1)[1])
    with socket.create_connection(("::1", port), timeout=5) as conn:
        conn.setblocking(False)
        server.step()                                   # accept
        conn.sendall(b"/1 1 get pos\n")
        assert _pump_until(server, conn, b"\r\n") == b"@01 1 OK IDLE WR 0\r\n"
    server.listener.close()


def test_serviced_without_a_client_and_each_client_starts_clean():
    clock = VirtualClock()
    emu = ZaberRotatorEmulator(clock)
    server = serve.TcpServer(emu, "127.0.0.1", 0)
    port = int(server.endpoint.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=5) as first:
        server.step()
        # a velocity run (an alert will end it), and leave without reading anything
        first.sendall(b"/1 set comm.alert 1\n/1 1 move vel 5000\n/1 1 get pos\n")
        server.step()
    for _ in range(3):
        server.step()                                   # notices the hang-up
    assert server.client is None
    clock.advance(300.0)                                # 0.7 °/s: ends at the limit switch
    server.step()                                       # nobody listens: the alert is lost
    assert emu.angle_deg() == pytest.approx(170.0)
    assert not emu.axis.moving
    with socket.create_connection(("127.0.0.1", port), timeout=5) as second:
        second.setblocking(False)
        server.step()
        second.sendall(b"/1 1 tools echo fresh\n")
        assert _pump_until(server, second, b"\r\n") == b"@01 1 OK IDLE WL fresh\r\n"
        # one client at a time: a second connection is closed at once
        with socket.create_connection(("127.0.0.1", port), timeout=5) as third:
            server.step()
            assert third.recv(16) == b""
    server.listener.close()


def test_serve_help_says_ptys_cannot_carry_modem_lines(capsys):
    with pytest.raises(SystemExit):
        main(["sim", "serve", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "ptys cannot carry RTS/DTR" in out and "socket://HOST:PORT" in out
    assert "--tcp ::1:0" in out


def test_the_colour_tables_are_loaded_before_the_endpoint_line(monkeypatch, capsys):
    from normbox_lab.sim import colour_tables
    from normbox_lab.sim.cs2000 import CS2000AEmulator

    events = []
    colour_tables.tables.cache_clear()
    real_prepare = CS2000AEmulator.prepare

    def prepare(self):
        real_prepare(self)
        loaded = colour_tables.tables.cache_info().currsize      # 1: read from the file
        events.append(("prepared", loaded, capsys.readouterr().out))

    monkeypatch.setattr(CS2000AEmulator, "prepare", prepare)
    monkeypatch.setattr(serve.TcpServer, "serve", lambda self, stop=None: events.append(
        ("served", capsys.readouterr().out)))
    assert main(["sim", "serve", "cs2000a", "--tcp", "127.0.0.1:0"]) == 0
    (tag, loaded, out_then), (tag2, out_later) = events
    assert (tag, loaded, out_then) == ("prepared", 1, "")     # nothing printed yet
    assert tag2 == "served" and out_later.startswith("tcp: 127.0.0.1:")



@pytest.mark.slow
def test_latency_command_prints_the_ratio_last(capsys):
    # a served CS-2000A on the real clock, cold start (≈ 10 s here): format, not speed
    assert main(["sim", "latency", "cs2000a"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("cs2000a: endpoint line after ")
    assert lines[-1].startswith("ratio ") and float(lines[-1].split()[1]) > 0


def _read_pty_until(server: serve.PtyServer, fd: int, want: bytes) -> bytes:
    got = b""
    for _ in range(200):
        server.step()
        try:
            got += os.read(fd, 4096)
        except BlockingIOError:
            pass
        if got.endswith(want):
            return got
    return got


def _open_pty_client(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    return fd


def test_pty_serviced_without_a_client_and_each_client_starts_clean():
    clock = VirtualClock()
    emu = ZaberRotatorEmulator(clock)
    server = serve.PtyServer(emu)
    try:
        server.step()
        assert not server.client_present
        first = _open_pty_client(server.path)
        os.write(first, b"/1 set comm.alert 1\n/1 1 move vel 5000\n")
        for _ in range(3):
            server.step()
        os.close(first)                                # leaves without reading
        for _ in range(3):
            server.step()
        assert not server.client_present
        clock.advance(300.0)                           # the run ends at the limit switch:
        server.step()                                  # its alert is lost
        assert emu.angle_deg() == pytest.approx(170.0)
        second = _open_pty_client(server.path)
        os.write(second, b"/1 1 tools echo fresh\n")
        assert _read_pty_until(server, second, b"\r\n") == b"@01 1 OK IDLE WL fresh\r\n"
        os.close(second)
    finally:
        os.close(server.master)


@pytest.mark.parametrize("device", core.devices_for("radiometer"))
def test_a_new_client_never_gets_the_replies_of_a_measurement_the_last_one_started(device):
    """The first client starts a measurement and leaves before its replies (``OK,1.01`` /
    ``OK``; ``OK00,002`` / ``OK00``; ACK / BEL); a client that connects while it runs must not
    receive them: its first command gets exactly its own reply.  Every radiometer of the
    emulator registry, with the bytes it names (`latency_script`)."""
    clock = VirtualClock()
    emu = core.create(device, clock=clock, world=object(), noise="off")
    remote, remote_end, measure, _, _ = type(emu).latency_script
    server = serve.TcpServer(emu, "127.0.0.1", 0)
    port = int(server.endpoint.rsplit(":", 1)[1])
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as first:
            first.setblocking(False)
            server.step()
            first.sendall(remote)
            ok = _pump_until(server, first, remote_end, clock, 100)
            assert ok.endswith(remote_end) and len(ok) > len(remote_end)
            first.sendall(measure)
            for _ in range(3):
                server.step()
        for _ in range(3):
            server.step()                               # notices the hang-up
        assert server.client is None and emu.phase != "idle"     # still measuring
        with socket.create_connection(("127.0.0.1", port), timeout=5) as second:
            second.setblocking(False)
            server.step()
            clock.advance(60.0)                         # the measurement would end now
            server.step()
            second.sendall(remote)
            assert _pump_until(server, second, ok, clock, 100) == ok
            clock.advance(60.0)
            assert _pump_until(server, second, b"never", clock, 100) == b""     # nothing more came
    finally:
        server.listener.close()


def test_rfc2217_port_counts_every_waiting_byte_where_socket_counts_one():
    """Why `--rfc2217` exists: pyserial's socket:// port reports at most 1 byte waiting, so
    a read_all() client takes one byte of a reply; rfc2217:// reports them all."""
    import time

    import serial
    from served import served

    reply = b"OK00,CS-2000A ,2,2000123\n"
    counts = {}
    for transport in ("tcp", "rfc2217"):
        with served("cs2000a", transport, noise="off") as server:
            port = serial.serial_for_url(server.url, baudrate=115200, timeout=2)
            try:
                port.write(b"RMTS,1\n")
                assert port.read_until(b"\n") == b"OK00\n"
                port.write(b"IDDR\n")
                deadline = time.monotonic() + 5
                if transport == "tcp":               # peek until the whole reply has arrived
                    port._socket.settimeout(5)
                    while len(port._socket.recv(4096, socket.MSG_PEEK)) < len(reply) \
                            and time.monotonic() < deadline:
                        pass
                else:                                # the RFC 2217 client's reader thread
                    while port.in_waiting < len(reply) and time.monotonic() < deadline:
                        pass
                counts[transport] = port.in_waiting
                assert port.read_until(b"\n") == reply
            finally:
                port.close()
    assert counts == {"tcp": 1, "rfc2217": len(reply)}


@pytest.mark.parametrize(("device", "where"), [
    ("cs1000a", "--tcp"), ("cs2000a", "--tcp"), ("cs2000a", "--pty"), ("sphere", "--tcp"),
    ("cs2000a", "--rfc2217")])
def test_served_emulator_exits_within_half_a_second_of_sigterm(device, where):
    """A real `sim serve` process, a client connected and a measurement running (for the
    radiometers): from SIGTERM to the process gone ≤ 0.5 s (a bound measured with
    time.monotonic; before, unloading colour-science took the radiometers 1–6 s)."""
    import signal
    import subprocess
    import sys
    import time

    import serial

    args = {"--tcp": ["--tcp", "127.0.0.1:0"], "--pty": ["--pty"],
            "--rfc2217": ["--tcp", "127.0.0.1:0", "--rfc2217"]}[where]
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", device,
                             *args], stdout=subprocess.PIPE, text=True)
    try:
        kind, _, address = proc.stdout.readline().strip().partition(": ")
        url = address if kind == "pty" else \
            f"{'rfc2217' if where == '--rfc2217' else 'socket'}://{address}"
        client = serial.serial_for_url(url, timeout=2)
        if device.startswith("cs"):
            remote, measure = (b"RMT,1\n", b"MES,1\n") if device == "cs1000a" else \
                (b"RMTS,1\n", b"MEAS,1\n")
            client.write(remote)
            assert client.read_until(b"\n").startswith(b"OK")
            client.write(measure)                      # still measuring at the signal
        else:
            client.write(b"*IDN?\n")
            assert client.read_until(b"\n")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=10)
        took_s = time.monotonic() - t0
        client.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert rc == 0
    assert took_s <= 0.5, f"{device} {where}: {took_s:.3f} s from SIGTERM to exit"
