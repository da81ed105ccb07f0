"""`normbox-lab sim serve` with the radiometer emulators, reached from this (another) process.

The served emulators run on the real clock; NORMBOX_LAB_SIM_TIME_FACTOR=0.05 shrinks every
simulated duration (pre-measurement, integration, line time) twenty-fold so each test takes a
few seconds, most of them the server importing colour-science.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
from contextlib import contextmanager

import numpy as np
import pytest
import serial

from normbox_lab.core.clock import RealClock

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs a pty")


@contextmanager
def serve(*args: str):
    env = dict(os.environ, NORMBOX_LAB_SIM_TIME_FACTOR="0.05")
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "the server printed no endpoint within 30 s"
        first = proc.stdout.readline().decode().strip()
        kind, _, where = first.partition(": ")
        assert kind in ("pty", "tcp"), first
        yield where
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def ask(port: serial.Serial, cmd: bytes) -> bytes:
    port.write(cmd + b"\n")
    line = port.readline()
    assert line.endswith(b"\n"), f"no complete reply to {cmd!r}: {line!r}"
    return line.rstrip(b"\r\n")


def test_plain_pyserial_client_measures_through_the_pty():
    with serve("cs1000a", "--pty") as path:
        assert path.startswith("/dev/")
        with serial.Serial(path, 9600, bytesize=8, parity="N", stopbits=1, timeout=15) as port:
            assert ask(port, b"RMT,1") == b"OK"
            first = ask(port, b"MES,1")
            assert first.startswith(b"OK,") and float(first[3:]) > 0
            assert port.readline() == b"OK\n"
            assert ask(port, b"BDR,1,0,0") == b"OK"
            colour_line = ask(port, b"&").split(b",")
            assert len(colour_line) == 11
            assert float(colour_line[1]) == pytest.approx(100.0, rel=0.03)   # the default
            assert ask(port, b"BDR,0,0,0") == b"OK"
            values = []
            for _ in range(15):
                values += [float(v) for v in ask(port, b"&").split(b",")]
            assert len(values) == 401 and min(values) > 0
            assert ask(port, b"RMT,0") == b"OK"


def test_driver_over_the_pty_on_the_real_clock():
    from normbox_lab.drivers.cs1000 import CS1000A

    with serve("cs1000a", "--pty", "--faults", "garble@1") as path:
        d = CS1000A.open(path, RealClock(), baud=9600)
        try:
            r = d.measure()                        # the garbled RMT,1 reply is retried
        finally:
            d.close()
        assert r.radiance_W_sr_m2_nm.shape == (401,)
        assert r.colorimetry.Lv_cd_m2 == pytest.approx(100.0, rel=0.03)


def test_cs2000a_driver_over_tcp():
    from normbox_lab.drivers.cs2000 import CS2000A

    with serve("cs2000a", "--tcp", "127.0.0.1:0") as where:
        d = CS2000A.open(f"socket://{where}", RealClock(), data_format="hex")
        try:
            assert d.identify().model == "CS-2000A"
            r = d.measure()
        finally:
            d.close()
        assert np.all(np.isfinite(r.radiance_W_sr_m2_nm))
        assert r.colorimetry.Lv_cd_m2 == pytest.approx(100.0, rel=0.03)
