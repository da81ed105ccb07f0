"""`normbox-lab lab discover` against the emulators served the way hardware appears: ptys and
loopback TCP (what `sim serve` does), the QE Pro on the emulated USB bus; plus a port that
answers garbage, a busy port and two instruments of the same model."""

from __future__ import annotations

import contextlib
import errno
import os
import threading

import pytest
import serial
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo
from served import served

from normbox_lab.acquire import discover, registry
from normbox_lab.acquire.config import load_config, parse_config
from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim import core


@contextlib.contextmanager
def garbage_pty():
    """A pty whose other end answers every write with bytes no instrument sends."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    stop = threading.Event()

    def answer() -> None:
        import select

        while not stop.is_set():
            ready, _, _ = select.select([master], [], [], 0.05)
            if ready:
                try:
                    os.read(master, 4096)
                    os.write(master, b"\xff\x13garbage\x00\x81")
                except OSError:
                    return

    t = threading.Thread(target=answer, daemon=True)
    t.start()
    try:
        yield path
    finally:
        stop.set()
        t.join(timeout=2)
        os.close(master)
        os.close(slave)


@pytest.fixture(scope="module")
def lab():
    """Every serial instrument served (pty or TCP), two Zaber stages of one model, a port
    answering garbage, a busy port (held open exclusively), the QE Pro on emulated USB."""
    from normbox_lab.sim.usb import emulated_usb

    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)          # no QE Pro of another test left on the bus
    with contextlib.ExitStack() as stack:
        servers = {
            "cs1000a": stack.enter_context(served("cs1000a", "pty")),
            "cs2000a": stack.enter_context(served("cs2000a", "tcp")),
            "apt": stack.enter_context(served("rotator-apt", "tcp", serial_number="55000001")),
            "zaber-a": stack.enter_context(served("rotator-zaber", "pty", serial_number="33001")),
            "zaber-b": stack.enter_context(served("rotator-zaber", "pty", serial_number="33002")),
            "sphere": stack.enter_context(served("sphere", "tcp")),
            "busy": stack.enter_context(served("sphere", "pty")),
        }
        holder = serial.Serial(servers["busy"].path, exclusive=True)   # another program
        stack.callback(holder.close)
        garbage = stack.enter_context(garbage_pty())
        backend = stack.enter_context(emulated_usb("qepro", clock=clock,
                                                   serial_number="QEP-USB-0042"))
        endpoints = [servers[k].url for k in ("cs1000a", "cs2000a", "apt", "zaber-a",
                                              "zaber-b", "sphere", "busy")] + [garbage]
        findings = discover.discover(endpoints, scan_serial=False, usb=True,
                                     usb_backend="pyseabreeze", pyusb_backend=backend,
                                     timeout_s=0.5)
        yield servers, garbage, findings


def _by_port(findings):
    return {f.port: f for f in findings}


def test_discover_identifies_every_served_instrument(lab):
    servers, garbage, findings = lab
    got = {f.port: (f.status, f.driver, f.identity.model if f.identity else "",
                    f.serial_number) for f in findings}
    assert got[servers["cs1000a"].url] == ("found", "cs1000a", "CS-1000A", "")
    assert got[servers["cs2000a"].url] == ("found", "cs2000a", "CS-2000A", "2000123")
    assert got[servers["apt"].url] == ("found", "apt-k10cr1", "K10CR1", "55000001")
    # two stages of one model: told apart by their serial numbers
    assert got[servers["zaber-a"].url] == ("found", "zaber", "X-RSW60A", "33001")
    assert got[servers["zaber-b"].url] == ("found", "zaber", "X-RSW60A", "33002")
    assert got[servers["sphere"].url] == ("found", "sphere-scpi", "LE7-4x", "LE7-SIM-0001")
    assert got["usb:QEP-USB-0042"] == ("found", "qepro", "QE Pro", "QEP-USB-0042")
    assert got[garbage][0] == "unknown"
    assert got[servers["busy"].url][0] == "busy"


def test_table_lists_instruments_unknowns_and_busy_ports_in_one_line_each(lab):
    servers, garbage, findings = lab
    text = discover.format_table(findings)
    lines = text.splitlines()
    assert lines[0].split() == ["PORT", "INSTRUMENT", "MODEL", "SERIAL", "FIRMWARE", "DRIVER"]
    row = next(line for line in lines if line.startswith(servers["apt"].url))
    assert row.split() == [servers["apt"].url, "rotation-stage", "K10CR1", "55000001", "1.3.0",
                           "apt-k10cr1"]
    assert any(line.split()[:2] == [garbage, "unknown"] for line in lines)
    busy = [line for line in lines if line.startswith(servers["busy"].url)]
    assert len(busy) == 1 and "busy: another program holds" in busy[0]
    assert "Traceback" not in text


def test_discover_sends_nothing_that_moves_switches_or_measures(lab):
    servers, _, _ = lab
    for key in ("apt", "zaber-a", "zaber-b"):
        axis = servers[key].emulator.axis
        assert axis.homed is False and axis.motion is None, key
    assert servers["sphere"].emulator.on is False
    cs1000 = servers["cs1000a"].emulator
    assert (cs1000.remote, cs1000.phase, cs1000.data) == (False, "idle", None)   # RMT,0 sent
    cs2000 = servers["cs2000a"].emulator
    assert (cs2000.remote, cs2000.phase) == (0, "idle")


def test_guarded_port_refuses_bytes_no_identification_declares():
    port = discover.GuardedPort(serial.serial_for_url("loop://"), discover.allowed_bytes())
    port.write(b"*IDN?\n")
    for command in (b"MES,1\n", b"OUTP ON\n", b"/1 home\n", b"\x43\x04\x01\x00\x50\x01"):
        with pytest.raises(discover.ProbeRefused):
            port.write(command)
    port.close()


def test_no_ascii_probe_can_frame_an_apt_message():
    """An ASCII probe reaching an APT controller is read as 6-byte headers at any alignment
    (no byte has the long-message bit 0x80): every id it could form is at least 0x0A0A (an LF
    or CR as its high byte), above every message of the K10CR1 subset (≤ 0x0492), the motion
    ones (home 0x0443, move 0x0448/0x0453, velocity 0x0457, jog 0x046A) included."""
    stream = b"".join(ex.send for e in registry.DRIVERS.values()
                      if e.identification is not None and not e.identification.binary
                      for ex in e.identification.exchanges)
    assert stream and max(stream) < 0x80
    ids = {int.from_bytes(stream[i:i + 2], "little") for i in range(len(stream) - 1)}
    assert min(ids) >= 0x0A0A


def test_port_problems_are_one_line_and_name_the_dialout_group():
    status, line = discover.port_problem(
        serial.SerialException(errno.EACCES, "could not open port /dev/ttyUSB0: [Errno 13] "
                               "Permission denied: '/dev/ttyUSB0'"), "/dev/ttyUSB0")
    assert status == "denied" and "dialout" in line and "\n" not in line
    status, line = discover.port_problem(
        serial.SerialException(errno.EAGAIN, "Could not exclusively lock port /dev/ttyUSB1"),
        "/dev/ttyUSB1")
    assert status == "busy"


def _usb_port(info_path: str, serial_number: str, interface: str = "1.0") -> ListPortInfo:
    info = ListPortInfo(info_path, skip_link_detection=True)
    info.vid, info.pid, info.serial_number = 0x0403, 0x6001, serial_number
    info.location = f"1-1.2:{interface}"
    info.description = "FT232R USB UART"
    info.hwid = info.usb_info()
    return info


def test_written_config_names_usb_adapters_by_serial_and_reopens_them(tmp_path, monkeypatch):
    """Two Zaber stages behind FTDI adapters: the config names them hwgrep://SER=…, which
    pyserial resolves to the right port however the device paths are numbered."""
    with served("rotator-zaber", "pty", serial_number="33001") as a, \
            served("rotator-zaber", "pty", serial_number="33002") as b, \
            served("rotator-apt", "tcp") as apt, served("cs1000a", "tcp") as rad, \
            served("sphere", "tcp") as sph:
        ports = [_usb_port(b.path, "FTB0002"), _usb_port(a.path, "FTA0001")]
        monkeypatch.setattr(list_ports, "comports", lambda include_links=False: ports)
        findings = discover.discover([apt.url, rad.url, sph.url], usb=False, timeout_s=0.5)
        path = discover.write_lab_config(findings, tmp_path / "lab.toml")
        config = load_config(path)
        arms = {r: config.instruments[r] for r in ("gonio_light_arm", "gonio_detector_arm")}
        assert {r: (i.port, i.serial_number) for r, i in arms.items()} == {
            "gonio_light_arm": (r"hwgrep://SER=FTA0001\b", "33001"),
            "gonio_detector_arm": (r"hwgrep://SER=FTB0002\b", "33002")}
        assert config.instruments["rotator"].driver == "apt-k10cr1"
        assert config.instruments["radiometer"].options == {"baud": 9600}
        # the stable key reaches the instrument with that serial number
        from normbox_lab.acquire.lab import build_lab

        lab = build_lab(config)
        try:
            assert lab.instrument("gonio_detector_arm").identify().serial_number == "33002"
        finally:
            lab.close()


def test_several_ports_of_one_adapter_are_told_apart_by_interface():
    c1 = discover.Candidate("/dev/ttyUSB0", 0x0403, 0x6011, "FT4X", "1-1:1.0")
    c2 = discover.Candidate("/dev/ttyUSB1", 0x0403, 0x6011, "FT4X", "1-1:1.1")
    found = [discover.Finding(c.url, "found", candidate=c) for c in (c1, c2)]
    discover._stable_ports(found)
    assert [f.stable_port for f in found] == [r"hwgrep://SER=FT4X\b.*LOCATION=[^ ]*:1\.0\b",
                                               r"hwgrep://SER=FT4X\b.*LOCATION=[^ ]*:1\.1\b"]


def test_a_lab_without_a_sphere_is_not_written(lab, tmp_path):
    _, _, findings = lab
    no_sphere = [f for f in findings if f.driver != "sphere-scpi"]
    with pytest.raises(Exception, match="not found: sphere"):
        discover.write_lab_config(no_sphere, tmp_path / "lab.toml")
    assert not (tmp_path / "lab.toml").exists()


def test_written_config_assigns_roles_and_loads(lab):
    servers, _, findings = lab
    text = discover.lab_config_text(findings)
    config = parse_config(text, "lab.toml")
    assert {r: (i.driver, i.port) for r, i in config.instruments.items()} == {
        "radiometer": ("cs1000a", servers["cs1000a"].url),
        "rotator": ("apt-k10cr1", servers["apt"].url),
        "sphere": ("sphere-scpi", servers["sphere"].url),
        "gonio_light_arm": ("zaber", servers["zaber-a"].url),
        "gonio_detector_arm": ("zaber", servers["zaber-b"].url),
        "spectrometer": ("qepro", "usb:QEP-USB-0042")}
    assert config.instruments["spectrometer"].options == {
        "backend": "pyseabreeze", "pyusb_backend": "normbox_emulated"}
    assert config.simulated is False
    assert "# also found, no role: cs2000a CS-2000A 2000123" in text


def warm(sphere_server) -> None:
    """The sphere has been on for hours (a lab switches it on in the morning)."""
    emu = sphere_server.emulator
    emu.on, emu.on_since_s = True, emu.clock.now_s() - 36_000.0


def test_written_config_runs_a_sweep_unchanged(tmp_path):
    """discover → lab.toml → `run reference-sweep` on it, not one line edited: every reading
    stored, the instruments recorded with the serial numbers discover found."""
    from normbox_lab.acquire.session import open_run
    from normbox_lab.acquire.store import Store

    with served("cs2000a", "pty", time_factor="0.02") as rad, \
            served("rotator-apt", "tcp") as rot, served("sphere", "tcp") as sph:
        warm(sph)
        findings = discover.discover([rad.url, rot.url, sph.url], scan_serial=False, usb=False,
                                     timeout_s=0.5)
        path = discover.write_lab_config(findings, tmp_path / "lab.toml")
        text_before = path.read_text()
        with Store(tmp_path / "s.sqlite") as store, open_run(
                "reference-sweep", store=store, config=load_config(path),
                params={"angles_deg": [30, 35], "patches": [1, 19]},
                operator=lambda request: request.choices[0]) as opened:
            result = opened.run()
            assert (result.status, result.done, result.planned) == ("done", 4, 4)
            assert sorted(store.keys(result.run_id)) == ["a30/p01", "a30/p19", "a35/p01",
                                                     "a35/p19"]
            serials = {i["role"]: i["identity"]["serial_number"]
                       for i in store.instruments(result.run_id)}
            assert serials == {"radiometer": "2000123", "rotator": "55123456",
                               "sphere": "LE7-SIM-0001"}
        assert path.read_text() == text_before


def test_cli_discover_prints_the_table_and_writes_a_config_that_loads(tmp_path, capsys):
    from normbox_lab import cli

    with served("cs1000a", "tcp") as rad, served("rotator-apt", "tcp") as rot, \
            served("sphere", "tcp") as sph:
        path = tmp_path / "lab.toml"
        rc = cli.main(["lab", "discover", rad.url, rot.url, sph.url, "--no-scan", "--no-usb",
                       "--timeout-s", "0.5", "--write", str(path)])
        out = capsys.readouterr().out.splitlines()
        assert rc == 0
        assert out[0].split() == ["PORT", "INSTRUMENT", "MODEL", "SERIAL", "FIRMWARE", "DRIVER"]
        assert [line.split()[2] for line in out[1:4]] == ["CS-1000A", "K10CR1", "LE7-4x"]
        assert out[4].startswith("3 instrument(s) found on 3 port(s) in ")
        assert out[5] == f"wrote {path}: check it with `normbox-lab lab check --lab {path}`"
        assert set(load_config(path).instruments) == {"radiometer", "rotator", "sphere"}
        # a second --write without --force refuses to overwrite the lab's config
        rc = cli.main(["lab", "discover", rad.url, rot.url, sph.url, "--no-scan", "--no-usb",
                       "--timeout-s", "0.5", "--write", str(path)])
        assert rc == 2 and "exists already" in capsys.readouterr().err
