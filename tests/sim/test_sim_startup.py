"""Emulators and the CLI start at once.

- Every emulator `sim serve` offers is served in its own process and an outside client (a
  plain socket on ``--tcp``, or pyserial on the pty of the plain ``normbox-lab sim serve``)
  gets its first reply, and its first spectrum, well within 5 s; the served process never
  imported colour-science, matplotlib, pandas or scipy (it reports its modules at SIGTERM).
- The colorimetric tables the emulators ship equal what colour-science computes now, and the
  correlated colour temperature from them agrees with colour-science's Ohno (2013).
- `normbox-lab --help` imports no command module and nothing heavy.

Bounds are generous (a loaded 2-core machine must pass); the figures themselves come from
``python tests/sim/test_sim_startup.py``, which prints wall and CPU seconds per emulator (the table
in docs/simulation-testing.md).  No test sleeps: every wait is a blocking read with a deadline.
"""

from __future__ import annotations

import math
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

#: what a served emulator must never have imported (colour-science pulls in the other three)
HEAVY = ("colour", "matplotlib", "pandas", "scipy", "mitsuba", "drjit", "xarray", "textual")
#: how long an outside client waits for a reply (a client that gives up after 5 s)
CLIENT_WAIT_S = 5.0
#: how long a process may take to print its endpoint line on a loaded machine before the test
#: calls it hung (the figures, not this bound, show how fast it is)
ENDPOINT_WAIT_S = 60.0


@dataclass(frozen=True)
class Step:
    """One exchange: send `send`, read until `end` has come `count` times (or `length` bytes)."""
    send: bytes
    end: bytes = b"\n"
    count: int = 1
    length: int = 0
    spectrum: bool = False          # this reply carries the first spectrum

    def complete(self, got: bytes) -> bool:
        return len(got) >= self.length if self.length else got.count(self.end) >= self.count


@dataclass(frozen=True)
class Script:
    steps: tuple[Step, ...]
    first_reply: bytes                 # the exact first reply
    options: tuple[str, ...] = ()      # --option K=V
    check: tuple[tuple[int, str], ...] = field(default=())   # (step, regex its reply matches)


APT_REQ_INFO = bytes([0x05, 0x00, 0x00, 0x00, 0x50, 0x01])   # MGMSG_HW_REQ_INFO to the stage
FAST = ("time_factor=0.01",)   # the radiometers' measurement on a 100× faster clock

SCRIPTS: dict[str, Script] = {
    "cs1000a": Script(
        (Step(b"RMT,1\n"), Step(b"MES,1\n", count=2), Step(b"BDR,0,0,0\n"),
         Step(b"&\n", spectrum=True), Step(b"BDR,1,0,0\n"), Step(b"&\n")),
        b"OK\n", FAST,
        # 28 spectral values; T of the default 2856 K Planckian light from the shipped tables
        ((3, r"^(\d\.\d{4}e-?\d+,){27}\d\.\d{4}e-?\d+\n$"), (5, r",285[5-7],[+-]0\.000\d\n$"))),
    "cs2000a": Script(
        (Step(b"RMTS,1\n"), Step(b"MEAS,1\n", count=2), Step(b"MEDR,1,0,1\n", spectrum=True),
         Step(b"MEDR,2,0,00\n")),
        b"OK00\n", FAST, ((2, r"^OK00(,\d\.\d{4}e-?\d+){100}\n$"),)),
    "specbos1211": Script(
        (Step(b"*IDN?\r", b"\r"), Step(b"*INIT\r", b"\x07"),
         Step(b"*FETCH:SPRAD\r", b"\r", count=404, spectrum=True), Step(b"*FETCH:XYZ\r", b"\r", 3)),
        b"JETI_SB1211\r", FAST, ((2, r"\r780\t\d\.\d{5}e[+-]\d\d\r\r$"),)),
    "rotator-apt": Script((Step(APT_REQ_INFO, length=90), Step(APT_REQ_INFO, length=90)),
                          b"\x06\x00\x54\x00\x81\x50"),
    "rotator-zaber": Script((Step(b"/\n"), Step(b"/get pos\n")), b"@01 0 OK IDLE WR 0\r\n"),
    "sphere": Script(
        (Step(b"*IDN?\n"), Step(b"OUTP ON\n"), Step(b"MEAS:SPEC?\n", count=2, spectrum=True)),
        b"Image Engineering (placeholder protocol),LE7-4x,LE7-SIM-0001,0.1-sim\n", (),
        ((2, r"^380,1,401,REL\n(0\.\d{5},){400}0\.\d{5}\n$"),)),
}

#: runs `normbox-lab sim serve` as the command does, except that SIGTERM ends serving with one
#: line naming the heavy packages the process has imported by then (what it served included)
SERVE_AND_REPORT = """\
import os, signal, sys, threading
from normbox_lab.sim import serve

def serve_then_report(server):
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    server.serve(stop)
    loaded = sorted({name.split(".")[0] for name in sys.modules} & set(sys.argv[1].split(",")))
    print("HEAVY", ",".join(loaded), flush=True)
    os._exit(0)

serve.serve_until_signalled = serve_then_report
from normbox_lab.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _read_line(fd: int, deadline: float) -> bytes:
    """One line from a pipe (raw reads, so select sees every byte), by `deadline`."""
    got = b""
    while not got.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise TimeoutError(f"no line by the deadline (got {got!r})")
        chunk = os.read(fd, 1)
        if not chunk:
            raise EOFError(f"the process closed its output (got {got!r})")
        got += chunk
    return got


def _exchange(conn: socket.socket, step: Step, wait_s: float) -> tuple[bytes, float]:
    """Send `step.send`, read its reply within `wait_s`: (reply, seconds it took)."""
    t0 = time.monotonic()
    deadline = t0 + wait_s
    conn.sendall(step.send)
    got = b""
    while not step.complete(got):
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"{step.send!r}: no full reply within {wait_s} s (got {got!r})")
        conn.settimeout(left)
        try:
            chunk = conn.recv(65536)
        except TimeoutError:
            continue
        if not chunk:
            raise EOFError(f"{step.send!r}: the emulator hung up (got {got!r})")
        got += chunk
    return got, time.monotonic() - t0


@dataclass
class Served:
    """One served emulator's figures (seconds since the process was started, unless said)."""
    device: str
    endpoint_s: float = math.nan        # the endpoint line
    first_reply_s: float = math.nan     # the first reply, client connected at the endpoint line
    first_spectrum_s: float = math.nan  # the first spectrum (radiometers: measured first)
    first_round_s: float = math.nan     # the whole script, first time
    second_round_s: float = math.nan    # the whole script again
    cpu_s: float = math.nan             # user + sys of the served process, start to SIGTERM
    heavy: str = "?"
    replies: list[bytes] = field(default_factory=list)


def serve_and_talk(device: str, wait_s: float = CLIENT_WAIT_S) -> Served:
    """Serve `device` on a loopback TCP port in a new process, run its script twice as an
    outside client, end it with SIGTERM."""
    script = SCRIPTS[device]
    opts = [a for o in script.options for a in ("--option", o)]
    out = Served(device)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", SERVE_AND_REPORT, ",".join(HEAVY), "sim",
                             "serve", device, "--tcp", "127.0.0.1:0", *opts],
                            stdout=subprocess.PIPE)
    try:
        fd = proc.stdout.fileno()
        line = _read_line(fd, t0 + ENDPOINT_WAIT_S).decode()
        out.endpoint_s = time.monotonic() - t0
        assert line.startswith("tcp: 127.0.0.1:"), line
        with socket.create_connection(("127.0.0.1", int(line.rsplit(":", 1)[1])),
                                      timeout=wait_s) as conn:
            for round_ in (1, 2):
                r0 = time.monotonic()
                for i, step in enumerate(script.steps):
                    reply, _ = _exchange(conn, step, wait_s)
                    if round_ == 1:
                        out.replies.append(reply)
                        if i == 0:
                            out.first_reply_s = time.monotonic() - t0
                        if step.spectrum:
                            out.first_spectrum_s = time.monotonic() - t0
                took = time.monotonic() - r0
                if round_ == 1:
                    out.first_round_s = took
                else:
                    out.second_round_s = took
        proc.send_signal(signal.SIGTERM)
        out.heavy = _read_line(fd, time.monotonic() + ENDPOINT_WAIT_S).decode().strip()
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.cpu_s = usage.ru_utime + usage.ru_stime
    finally:
        if proc.returncode is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    return out


@pytest.mark.parametrize("device", sorted(SCRIPTS))
def test_a_served_emulator_answers_an_outside_client_at_once_without_heavy_imports(device):
    served = serve_and_talk(device)
    script = SCRIPTS[device]
    assert served.replies[0].startswith(script.first_reply)
    for step, pattern in script.check:
        assert re.search(pattern, served.replies[step].decode("latin-1")), \
            (step, served.replies[step][-120:])
    # every exchange, the first included, came within the client's 5 s (raised otherwise);
    # nothing heavy was imported to serve the script twice
    assert served.heavy == "HEAVY", served.heavy
    assert served.cpu_s > 0


def test_every_served_device_has_a_script():
    from normbox_lab.sim.core import EMULATORS

    assert set(SCRIPTS) == set(EMULATORS)


@pytest.mark.parametrize("device, first, spectrum", [
    ("sphere", b"*IDN?\n", b"MEAS:SPEC?\n"),
    ("cs1000a", b"RMT,1\n", None),
])
def test_the_plain_command_on_a_pty_answers_pyserial_within_5_s(device, first, spectrum):
    """What a user saw: `normbox-lab sim serve DEVICE --pty` and a pyserial client that
    waits 5 s; the sphere's first ``MEAS:SPEC?`` included."""
    import serial

    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", device,
                             "--pty"], stdout=subprocess.PIPE)
    try:
        line = _read_line(proc.stdout.fileno(), t0 + ENDPOINT_WAIT_S).decode()
        assert line.startswith("pty: /dev/"), line
        with serial.Serial(line.split(": ", 1)[1].strip(), timeout=CLIENT_WAIT_S) as port:
            port.write(first)
            reply = port.readline()
            assert reply.endswith(b"\n") and not reply.startswith(b"ER"), reply
            if spectrum is not None:
                port.write(spectrum)
                header, values = port.readline(), port.readline()
                assert header == b"380,1,401,REL\n"
                assert values.endswith(b"\n") and values.count(b",") == 400
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        proc.stdout.close()


# --- the shipped tables ----------------------------------------------------------------------

def test_the_shipped_tables_equal_colour_science():
    from normbox_lab.sim import colour_tables

    assert colour_tables.TABLES_PATH.is_file()
    assert colour_tables.differences() == []
    t = colour_tables.tables()
    assert t.cmfs_2deg.shape == t.cmfs_10deg.shape == (401, 3)
    # the 2° ȳ peaks at 555 nm with 1.0; D65 is 100 at 560 nm
    assert int(np.argmax(t.cmfs_2deg[:, 1])) + 380 == 555
    assert t.d65[180] == pytest.approx(100.0)


def test_a_normal_install_carries_the_tables(tmp_path):
    """setuptools' build_py (what a wheel and a normal install contain) copies the data file
    into normbox_lab/sim/data/, and the installed module finds it there."""
    root = Path(__file__).resolve().parents[2]
    src = tmp_path / "src"
    src.mkdir()
    for name in ("setup.py", "pyproject.toml", "README.md"):
        (src / name).write_bytes((root / name).read_bytes())
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("normbox_lab", "sim", "drivers", "protocols"):
        shutil.copytree(root / folder, src / folder, ignore=ignore)
    subprocess.run([sys.executable, "setup.py", "-q", "build_py", "-d", str(tmp_path / "lib")],
                   cwd=src, check=True, capture_output=True)
    shipped = tmp_path / "lib" / "normbox_lab" / "sim" / "data" / "colorimetry_tables.npz"
    assert shipped.read_bytes() == (root / "sim" / "data" / "colorimetry_tables.npz").read_bytes()
    code = ("import sys\n"
            "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f)]\n"
            "from normbox_lab.sim import colour_tables\n"
            "print(colour_tables.TABLES_PATH, colour_tables.tables().planckian_table.shape)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, check=True, text=True,
                         capture_output=True, env={**os.environ, "PYTHONPATH": str(tmp_path / "lib")}
                         ).stdout
    assert out.startswith(str(shipped)) and "(6849, 3)" in out


def test_a_changed_table_is_seen(tmp_path):
    from normbox_lab.sim import colour_tables

    fresh = colour_tables.build_tables()
    fresh["d65"] = fresh["d65"] * (1 + 1e-9)
    np.savez(tmp_path / "t.npz", **fresh)
    assert [d.split(":")[0] for d in colour_tables.differences(tmp_path / "t.npz")] == ["d65"]


def test_cct_from_the_shipped_table_agrees_with_colour_ohno2013():
    """Random chromaticities over what the instruments report (1000–99 999 K, |Δuv| ≤ 0.1)."""
    import colour

    from normbox_lab.sim.colour_tables import uv_to_cct_ohno2013

    rng = np.random.default_rng(34)
    n = 400
    T = np.exp(rng.uniform(math.log(1000.0), math.log(99999.0), n))
    duv = rng.uniform(-0.1, 0.1, n)
    uv = colour.temperature.CCT_to_uv_Ohno2013(np.stack([T, duv], axis=1))
    with warnings.catch_warnings():          # colour warns at the table's ends
        warnings.simplefilter("ignore")
        expected = colour.temperature.uv_to_CCT_Ohno2013(uv)
    got = np.array([uv_to_cct_ohno2013(u, v) for u, v in uv])
    assert np.max(np.abs(got[:, 0] - expected[:, 0])) < 1e-3          # K
    assert np.max(np.abs(got[:, 1] - expected[:, 1])) < 1e-9
    # and the method recovers what the chromaticities were made from
    assert np.max(np.abs(got[:, 0] - T) / T) < 1e-3


def test_the_colorimetry_block_is_what_colour_science_gives():
    """The 11-value block of a random smooth spectrum, 2° and 10°, against colour-science's
    own CMFs and Ohno (2013)."""
    import colour

    from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM as wl
    from normbox_lab.sim.radiometer_common import colorimetry

    rng = np.random.default_rng(7)
    L = 1e-3 * (1.2 + np.sin(wl / rng.uniform(20, 90) + rng.uniform(0, 6)))
    for deg, name in ((2, "CIE 1931 2 Degree Standard Observer"),
                      (10, "CIE 1964 10 Degree Standard Observer")):
        c = colour.MSDS_CMFS[name]
        cm = np.stack([np.interp(wl, c.wavelengths, c.values[:, i]) for i in range(3)], 1)
        X, Y, Z = 683.0 * (L[:, None] * cm).sum(axis=0)
        block = colorimetry(L, deg)
        assert (block["X"], block["Y"], block["Z"]) == pytest.approx((X, Y, Z), rel=1e-12)
        u, v = 4 * X / (X + 15 * Y + 3 * Z), 6 * Y / (X + 15 * Y + 3 * Z)
        T, duv = colour.temperature.uv_to_CCT_Ohno2013(np.array([u, v]))
        assert block["T"] == pytest.approx(T, abs=1e-6)
        assert block["duv"] == pytest.approx(duv, abs=1e-12)


# --- the CLI ---------------------------------------------------------------------------------

def test_help_imports_no_command_module_and_lists_every_command():
    code = ("import sys\n"
            "from normbox_lab.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('LOADED', sorted(m for m in sys.modules if m.startswith("
            "('numpy', 'normbox_lab.commands.', 'normbox_lab.sim', 'colour', 'matplotlib'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "LOADED []" in out
    from normbox_lab.cli import COMMANDS

    for name, _, _ in COMMANDS:
        assert re.search(rf"^    {name} ", out, re.MULTILINE), name


def test_the_help_lines_are_those_the_command_modules_register():
    import argparse

    from normbox_lab.cli import COMMANDS, build_parser

    full = build_parser()
    sub = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    registered = [(a.dest, a.help) for a in sub._choices_actions]
    assert registered == [(name, help_text) for name, _, help_text in COMMANDS]


def test_a_command_line_imports_only_its_command_module():
    code = ("import sys\n"
            "from normbox_lab.cli import main\n"
            "try:\n    main(['sim', 'serve', '--help'])\nexcept SystemExit:\n    pass\n"
            "print('LOADED', sorted(m for m in sys.modules "
            "if m.startswith('normbox_lab.commands.')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "cs1000a, cs2000a" in out
    assert "LOADED ['normbox_lab.commands.sim']" in out


def test_a_misspelt_command_is_still_refused_with_the_choices(capsys):
    from normbox_lab.cli import main

    with pytest.raises(SystemExit) as info:
        main(["simm", "serve"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'simm'" in err and "'sim'" in err


# --- the figures (python tests/sim/test_sim_startup.py) ------------------------------------------

def _help_figures(n: int = 5) -> tuple[float, float]:
    """Median wall and CPU seconds of `python -m normbox_lab --help` over n runs."""
    walls, cpus = [], []
    for _ in range(n):
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "--help"],
                                stdout=subprocess.DEVNULL)
        _, _, usage = os.wait4(proc.pid, 0)
        proc.returncode = 0
        walls.append(time.monotonic() - t0)
        cpus.append(usage.ru_utime + usage.ru_stime)
    return float(np.median(walls)), float(np.median(cpus))


def plain_start(device: str) -> tuple[float, float]:
    """`python -m normbox_lab sim serve DEVICE --pty`, ended by SIGTERM as soon as it printed
    its pty line: (wall seconds to the line, CPU seconds of the process)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", device,
                             "--pty"], stdout=subprocess.PIPE)
    try:
        line = _read_line(proc.stdout.fileno(), t0 + ENDPOINT_WAIT_S)
        wall = time.monotonic() - t0
        assert line.startswith(b"pty: "), line
        proc.send_signal(signal.SIGTERM)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
    finally:
        if proc.returncode is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    return wall, usage.ru_utime + usage.ru_stime


def main() -> None:
    load = os.getloadavg()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, "
          f"load {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    print(f"{'device':<14} {'endpoint':>8} {'1st reply':>9} {'1st spectrum':>12} "
          f"{'round 1':>8} {'round 2':>8} {'CPU':>6}  heavy modules")
    for device in sorted(SCRIPTS):
        s = serve_and_talk(device)
        spec = f"{s.first_spectrum_s:12.2f}" if not math.isnan(s.first_spectrum_s) else \
            f"{'—':>12}"
        print(f"{device:<14} {s.endpoint_s:8.2f} {s.first_reply_s:9.2f} {spec} "
              f"{s.first_round_s:8.3f} {s.second_round_s:8.3f} {s.cpu_s:6.2f}  "
              f"{s.heavy.removeprefix('HEAVY').strip() or 'none'}")
    for device in sorted(SCRIPTS):
        wall, cpu = plain_start(device)
        print(f"normbox-lab sim serve {device} --pty: pty line after {wall:.2f} s, "
              f"{cpu:.2f} s CPU (start to SIGTERM)")
    wall, cpu = _help_figures()
    print(f"normbox-lab --help: {wall:.2f} s wall, {cpu:.2f} s CPU (median of 5)")


if __name__ == "__main__":
    main()
