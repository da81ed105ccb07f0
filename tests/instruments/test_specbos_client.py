"""A lab script written from the specbos firmware manual, not from our driver, drives the
served specbos1211 emulator with plain pyserial over a pty and over TCP (``socket://``), on
the real clock — the way the public clients [JETI-SB1211] do it:

- identify (``*IDN?``) and read the predefined range (``*PARA:WAVBEG?`` / ``WAVEND?``);
- the one-shot ``*MEAS:SPRAD <tint> <av> <format>`` with format 7, read as MATLAB's
  ``jetimeas`` reads it: n + 2 CR-terminated lines, the first two skipped, then
  ``<nm><TAB><value>``;
- the configured sequence: ``*CONF:…`` (ACK each), ``*INIT`` (ACK, then BEL at the end),
  ``*FETCH:XYZ`` (``X: …`` lines) and ``*FETCH:SPRAD`` (two header lines, values, an empty
  line), as Argyll's specbos client does;
- a refused setting (NAK) and ``*STAT:ERR?`` → ``Error Code: 10``.
Nothing of normbox_lab's driver is imported."""

from __future__ import annotations

import numpy as np
import pytest
import serial
from served import served

from normbox_lab.sim.radiometer_common import colorimetry, default_spectrum

ACK, NAK, BEL = b"\x06", b"\x15", b"\x07"


def _open(server, transport: str) -> serial.SerialBase:
    if transport == "pty":
        return serial.Serial(server.path, 921600, timeout=5)
    return serial.serial_for_url(server.url, timeout=5)


def _query(port: serial.SerialBase, cmd: bytes) -> str:
    port.write(cmd + b"\r")
    line = port.read_until(b"\r")
    assert line.endswith(b"\r"), (cmd, line)
    return line[:-1].decode("ascii")


def _setting(port: serial.SerialBase, cmd: bytes) -> bytes:
    port.write(cmd + b"\r")
    return port.read(1)


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_a_manual_written_script_measures_the_light(transport):
    wl_truth, radiance = default_spectrum()        # what the emulator sees: 2856 K, 100 cd/m²
    truth = colorimetry(radiance)
    with served("specbos1211", transport, noise="off", time_factor="0.05") as server:
        port = _open(server, transport)
        try:
            port.reset_input_buffer()
            assert _query(port, b"*IDN?") == "JETI_SB1211"
            start = float(_query(port, b"*PARA:WAVBEG?").split(":")[1])
            end = float(_query(port, b"*PARA:WAVEND?").split(":")[1])
            assert (start, end) == (380.0, 780.0)

            # jetimeas: *MEAS:SPRAD 0 1 7 (adaptive time, one measurement, nm<TAB>value)
            assert _setting(port, b"*CONF:WRAN 380 780 5") == ACK
            n = len(range(380, 781, 5))
            port.write(b"*MEAS:SPRAD 0 1 7\r")
            lines = [port.read_until(b"\r") for _ in range(n + 2)]
            assert lines[0].startswith(ACK + BEL)           # accepted, measured, then the data
            rows = [line.rstrip(b"\r").split(b"\t") for line in lines[2:]]
            nm = np.array([float(w) for w, _ in rows])
            value = np.array([float(v) for _, v in rows])
            assert np.array_equal(nm, np.arange(380.0, 781.0, 5.0))
            assert np.allclose(value, np.interp(nm, wl_truth, radiance), rtol=1e-5)
            assert port.read_until(b"\r") == b"\r"          # the block's empty last line

            # Argyll-style: configure, *INIT, then fetch XYZ and the spectrum (1 nm)
            for cmd in (b"*CONF:WRAN 380 780 1", b"*CONF:FUNC 6", b"*CONF:FORM 4",
                        b"*CONF:AVER 1", b"*CONTR:LASER 0"):
                assert _setting(port, cmd) == ACK, cmd
            port.write(b"*INIT\r")
            assert port.read(1) == ACK
            assert port.read(1) == BEL
            port.write(b"*FETCH:XYZ\r")
            xyz = [float(port.read_until(b"\r").decode().split(":")[1]) for _ in "XYZ"]
            assert xyz == pytest.approx([truth["X"], truth["Y"], truth["Z"]], rel=1e-5)
            port.write(b"*FETCH:SPRAD\r")
            block = [port.read_until(b"\r").rstrip(b"\r") for _ in range(2 + 401 + 1)]
            assert block[1] == b"wran: 380 780 1" and block[-1] == b""
            assert float(block[0].split(b":")[1]) == pytest.approx(200.0)   # tint, ms
            assert np.allclose([float(v) for v in block[2:-1]], radiance, rtol=1e-5)

            # a refused setting: NAK, and the instrument says why
            assert _setting(port, b"*CONF:AVER 0") == NAK
            assert _query(port, b"*STAT:ERR?") == "Error Code: 10"
        finally:
            port.close()


def test_lab_discover_finds_it_from_its_registry_entry():
    """`lab discover` knows the model only from its registry entry (the bytes, the bauds, the
    driver's parse function): a served specbos on a pty is identified, serial number and all."""
    from normbox_lab.acquire import discover

    with served("specbos1211", "pty", noise="off") as server:
        [finding] = discover.discover([server.path], scan_serial=False, usb=False)
        assert (finding.status, finding.driver) == ("found", "specbos1211")
        assert (finding.identity.model, finding.serial_number, finding.identity.firmware) == \
            ("specbos 1211", "123456", "3.8.1")
        assert server.emulator.data is None           # identified, never measured
