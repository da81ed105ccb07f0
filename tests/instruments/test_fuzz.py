"""Fuzzing every parser of untrusted bytes: mutated replies into each driver's real read path,
mutated lab configs, mutated brdf-json files.  Bounded and seeded: the default suite runs
`DEFAULT_N` inputs per parser (a few seconds each); the slow one runs 100 000 per parser.

The only acceptable outcomes are a valid result or a typed `NormboxError` (ProtocolError /
DeviceError / InstrumentTimeout naming the instrument and the bytes, ConfigError naming
file:line:field with a line > 0, DataError naming file and location).  Anything else — a
struct.error, OverflowError, UnicodeDecodeError, IndexError, a raw ValueError — is a defect.

Counts per parser are printed (``-s``):  nice -n 10 .venv/bin/python -m pytest -s -m slow
tests/instruments/test_fuzz.py
"""

from __future__ import annotations

import math
import random
import struct
from collections import Counter
from collections.abc import Callable

import numpy as np
import pytest
from fuzz import ReplyPort, mutate

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import ConfigError, NormboxError, ProtocolError
from normbox_lab.drivers.cs1000 import CS1000A
from normbox_lab.drivers.cs2000 import CS2000A
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.drivers.sphere import SphereLightSource

DEFAULT_N = 1500
SLOW_N = 100_000

# --- valid replies to mutate ----------------------------------------------------------------------
WL = np.arange(380.0, 781.0)
SPEC = 2e-3 * (1.0 + np.sin(WL / 37.0) ** 2)
CS1000_COLOUR = b"6.4182e-1,2.0000e2,1.0984e2,2.0000e2,3.5595e1,0.4475,0.4074,0.2559,0.5243,2856,+0.0012\n"
CS1000_LINE = (",".join(f"{v:.4e}" for v in SPEC[:28]) + "\n").encode()
CS2000_BLOCK = ("OK00," + ",".join(f"{v:.4e}" for v in SPEC[:100]) + "\n").encode()
CS2000_HEX = ("OK00," + ",".join(struct.pack(">f", v).hex().upper() for v in SPEC[:100])
              + "\n").encode()
CS2000_COLOUR = ("OK00," + ",".join(["1.2345e2"] * 24) + "\n").encode()
CS2000_COND = b"OK00,2,0,1000000,2,0,0,0,0\n"
ZABER_POS = b"@01 1 OK IDLE -- 12345\r\n"
ZABER_WARN = b"@01 1 OK IDLE WR 02 WR NI\r\n"


def _apt_frame(msg_id: int, data: bytes) -> bytes:
    return struct.pack("<HHBB", msg_id, len(data), 0x01 | 0x80, 0x50) + data


APT_STATUS = _apt_frame(0x0481, struct.pack("<HllL", 1, 13653, 13653, 0x400))
APT_VEL = _apt_frame(0x0415, struct.pack("<H3l", 1, 0, 1374, 21987328))
APT_INFO = _apt_frame(0x0006, struct.pack("<l8sH4B60sHHH", 55000123, b"K10CR1\0\0", 16,
                                          3, 0, 1, 0, b"\0" * 60, 1, 1, 1))


def _port_and_clock() -> tuple[ReplyPort, VirtualClock]:
    clock = VirtualClock()
    return ReplyPort([], clock), clock


# --- one input per parser -----------------------------------------------------------------------
def cs1000_ascii(rng: random.Random) -> None:
    d = CS1000A(*_port_and_clock(), attempts=1, command_timeout_s=1.0)
    d.remote = True
    which = rng.randrange(4)
    if which == 0:
        d.port.replies = [mutate(rng, CS1000_COLOUR)]
        d._data_values(d.exchange(b"&"), 11)
    elif which == 1:
        d.port.replies = [mutate(rng, CS1000_LINE)]
        d._data_values(d.exchange(b"&"), 28)
    elif which == 2:
        d.port.replies = [mutate(rng, b"OK,1.50\n") + mutate(rng, b"OK\n")]
        d._run_measurement()
    else:
        d.port.replies = [mutate(rng, b"OK,0,1,2.500\n")]
        d.status()


def cs1000_binary(rng: random.Random) -> None:
    d = CS1000A(*_port_and_clock(), data_format="binary", attempts=1,
                command_timeout_s=1.0)
    blocks = [struct.pack(f"<{n}f", *SPEC[i * 60:i * 60 + n])
              for i, n in enumerate((60, 60, 60, 60, 60, 60, 41))]
    k = rng.randrange(7)
    blocks[k] = mutate(rng, blocks[k])
    d.port.replies = [b"OK\n", *blocks]
    d._binary_pass(0, [6], lambda i, values, raw: None)


def _cs2000(rng: random.Random, fmt: str) -> None:
    d = CS2000A(*_port_and_clock(), data_format=fmt, attempts=1,
                command_timeout_s=1.0)
    d.remote = True
    d._button_off = True
    which = rng.randrange(6)
    if which == 0:
        cmd = f"MEDR,1,{int(fmt == 'hex')},1"
        d.port.replies = [mutate(rng, CS2000_HEX if fmt == "hex" else CS2000_BLOCK)]
        d._values(cmd, d.exchange(cmd.encode()), 100)
    elif which == 1:
        d.port.replies = [mutate(rng, CS2000_COLOUR)]
        d._values("MEDR,2,0,00", d.exchange(b"MEDR,2,0,00"), 24)
    elif which == 2:
        d.port.replies = [mutate(rng, CS2000_COND)]
        d.measurement_conditions_once()
    elif which == 3:
        d.port.replies = [mutate(rng, b"OK00,2,1,2\n")]
        d.read_speed()
    elif which == 4:
        d.port.replies = [mutate(rng, b"OK00,CS-2000A ,2,2000123\n")]
        d.identify()
    else:
        d.port.replies = [mutate(rng, b"OK00,003\n") + mutate(rng, b"OK00\n")]
        d._run_measurement()


def cs2000_ascii(rng: random.Random) -> None:
    _cs2000(rng, "ascii")


def cs2000_hex(rng: random.Random) -> None:
    _cs2000(rng, "hex")


def zaber(rng: random.Random) -> None:
    s = ZaberRotationStage(*_port_and_clock(), connect=False, attempts=1)
    which = rng.randrange(3)
    if which == 0:
        s.port.replies = [mutate(rng, ZABER_POS)]
        s.position_deg()
    elif which == 1:
        s.port.replies = [mutate(rng, ZABER_WARN)]
        s.warnings()
    else:
        s.port.replies = [mutate(rng, b"@01 1 OK BUSY -- 0\r\n")]
        s.is_moving()


def apt_frames(rng: random.Random) -> None:
    s = AptRotationStage(*_port_and_clock(), connect=False, attempts=1)
    frame, msgid = rng.choice([(APT_STATUS, 0x0481), (APT_VEL, 0x0415), (APT_INFO, 0x0006)])
    s.port.replies = [mutate(rng, frame)]
    if msgid == 0x0481:
        s.status()
    else:
        s._send(b"\x00" * 6)
        s._expect(msgid)


def sphere(rng: random.Random) -> None:
    lamp = SphereLightSource(*_port_and_clock(), attempts=1)
    which = rng.randrange(5)
    if which == 0:
        lamp.port.replies = [mutate(rng, b"STABLE\n"), b'0,"No error"\n']
        lamp.state()
    elif which == 1:
        lamp.port.replies = [mutate(rng, b"50.0\n")]
        lamp.level_percent()
    elif which == 2:
        lamp.port.replies = [mutate(rng, b"380,5,5,rel\n") + mutate(rng, b"0.1,0.2,0.3,0.4,0.5\n")]
        lamp.internal_spectrum()
    elif which == 3:
        lamp.port.replies = [mutate(rng, (",".join(["1.0"] * 25) + "\n").encode())]
        lamp.panel_map()
    else:
        lamp.port.replies = [mutate(rng, b"ERR -222\n"), mutate(rng, b'-222,"Data out of range"\n'),
                             b'0,"No error"\n']
        lamp.set_level_percent(50.0)


TOML_VALUES = ["1.5", '"x"', "[0, 1]", "true", "-1", "0", "1e400", "{ a = 1 }", "[]",
               '"sim://nowhere"', "nan", "inf", '[1, "a"]', "999999999999999999999", '""',
               "[30, 95]", "[[1]]", "2024-01-01", '"/dev/ttyUSB9"', "25", "1.0e-300"]


def lab_toml(rng: random.Random) -> None:
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config

    lines = SIM_CONFIG_TEMPLATE.splitlines()
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(lines))
        op = rng.randrange(7)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[rng.randrange(len(lines))])
        elif op == 2 and "=" in lines[i]:
            key = lines[i].split("=", 1)[0]
            lines[i] = f"{key}= {rng.choice(TOML_VALUES)}"
        elif op == 3:
            lines.insert(i + 1, rng.choice(["bogus = 1", "[bogus]", "[instruments.bogus]",
                                            "[protocols.reference-sweep]", "x.y = 2",
                                            "[instruments.radiometer.sub]"]))
        elif op == 4:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == 5:
            lines[i] = mutate(rng, lines[i].encode()).decode("utf-8", "replace")
        else:
            lines.insert(i, f"{rng.choice(['angles_deg', 'patches', 'repeats', 'baud', 'seed'])}"
                            f" = {rng.choice(TOML_VALUES)}")
    cfg = parse_config("\n".join(lines), "lab.toml")
    from normbox_lab.acquire import engine

    name = rng.choice(("reference-sweep", "repeatability", "brdf-inplane", "light-map"))
    engine.build_plan(name, cfg.protocol_defaults(name))


BRDF_JSON = (b'[{"wavelengths": [400, 500, 600]},\n'
             b' {"thetaIn": 30, "phiIn": 0, "thetaOut": 20, "phiOut": 180, '
             b'"spectrum": [0.1, 0.2, 0.3]},\n'
             b' {"thetaIn": 30, "phiIn": 0, "thetaOut": 40, "phiOut": 0, '
             b'"spectrum": [0.15, 0.25, 0.35]}]\n')


def brdf_json(rng: random.Random) -> None:
    from normbox_lab.acquire.importers import _decode_stream, parse_brdf_json

    parse_brdf_json(_decode_stream(mutate(rng, BRDF_JSON), "f.json"), "f.json", "m")


class _HostileSpectrometer:
    """A seabreeze-shaped device whose answers are wrong in random ways: short, long, NaN or
    non-numeric counts, finite counts beyond the 18-bit full scale, out-of-range dark pixels, or a SeaBreezeError (a USB drop)."""

    def __init__(self, inner, rng: random.Random, error: type) -> None:
        self._inner, self._rng, self._error = inner, rng, error

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def intensities(self, *a):
        good = np.asarray(self._inner.intensities(*a))
        return self._rng.choice([
            lambda: good, lambda: good[:-3], lambda: np.append(good, 1.0),
            lambda: np.where(np.arange(good.size) == 7, np.nan, good),
            lambda: ["x"] * good.size, lambda: np.inf * good,
            lambda: good * 1e30, lambda: good + 262144.0,       # finite, beyond the 18 bits
            lambda: (_ for _ in ()).throw(self._error("USB: device not found"))])()

    def integration_time_micros(self, us):
        if self._rng.random() < 0.2:
            raise self._error("USB: device not found")
        return self._inner.integration_time_micros(us)


def qepro_operations(rng: random.Random) -> None:
    from normbox_lab.drivers.qepro import QEPro
    from normbox_lab.sim import core
    from normbox_lab.sim import qepro as simq
    from normbox_lab.sim.transport import register_url_scheme

    register_url_scheme()
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    simq.device("qepro", clock=clock, light_arm=lambda: 0.0, detector_arm=lambda: 45.0)
    q = QEPro.open("sim://qepro", clock, reconnect_timeout_s=1.0)
    from seabreeze.spectrometers import SeaBreezeError

    q.spec = _HostileSpectrometer(q.spec, rng, SeaBreezeError)
    q._reopen = None if rng.random() < 0.5 else (lambda: q.spec)
    for _ in range(3):
        op = rng.randrange(3)
        if op == 0:
            acq = q.acquire()                   # data, or a typed error: never NaN counts
            assert np.all(np.isfinite(acq.counts)) and 0 <= acq.raw_counts.min() \
                and acq.raw_counts.max() <= 262143, "the driver handed on numbers as data"
        elif op == 1:
            q.set_integration_time_s(rng.choice([0.01, 0.1, 1.0]))
        else:
            q.intensities_counts()


PARSERS: dict[str, Callable[[random.Random], None]] = {
    "qepro-operations": qepro_operations,
    "brdf-json": brdf_json,
    "lab-toml": lab_toml,
    "cs1000a-ascii": cs1000_ascii, "cs1000a-binary": cs1000_binary,
    "cs2000a-ascii": cs2000_ascii, "cs2000a-hex": cs2000_hex, "zaber": zaber,
    "apt-frames": apt_frames, "sphere": sphere,
}


def run_fuzz(case: Callable[[random.Random], None], n: int, seed: int) -> Counter:
    """Run `n` inputs; count outcomes; the first untyped exception is re-raised with its seed."""
    outcomes: Counter = Counter()
    for i in range(n):
        rng = random.Random(seed * 1_000_003 + i)
        try:
            case(rng)
            outcomes["ok"] += 1
        except ConfigError as exc:
            assert exc.line > 0, f"input {i}: {exc}"
            outcomes[type(exc).__name__] += 1
        except NormboxError as exc:
            outcomes[type(exc).__name__] += 1
        except Exception as exc:           # the point of the test: nothing untyped
            raise AssertionError(f"input {i} (seed {seed}): untyped {type(exc).__name__}: "
                                 f"{exc}") from exc
    return outcomes


@pytest.mark.parametrize("name", sorted(PARSERS))
def test_fuzz_parser_raises_only_typed_errors(name):
    counts = run_fuzz(PARSERS[name], DEFAULT_N, seed=1)
    print(f"fuzz {name}: {DEFAULT_N} inputs, untyped 0, outcomes {dict(counts)}")
    assert sum(counts.values()) == DEFAULT_N
    assert counts["ok"] < DEFAULT_N           # the mutations do reach the parser


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PARSERS))
def test_fuzz_parser_100k(name):
    counts = run_fuzz(PARSERS[name], SLOW_N, seed=2)
    print(f"fuzz {name}: {SLOW_N} inputs, untyped 0, outcomes {dict(counts)}")
    assert sum(counts.values()) == SLOW_N


def test_mutator_makes_hex_fields_with_blanks_that_keep_their_length():
    """The CS-2000A case a looser check let through: ``12 34 56`` is 8 characters, but
    bytes.fromhex skips the blanks and gives 3 bytes.  The mutator makes such fields, and the
    hex parser answers each with a ProtocolError."""
    def fromhex_is_fooled(field: bytes) -> bool:
        try:
            return len(field) == 8 and len(bytes.fromhex(field.decode("latin-1"))) != 4
        except ValueError:
            return False

    rng = random.Random(3)
    sneaky = 0
    for _ in range(3000):
        reply = mutate(rng, CS2000_HEX)
        if any(fromhex_is_fooled(f) for f in reply.rstrip(b"\n").split(b",")[1:]):
            sneaky += 1
            d = CS2000A(*_port_and_clock(), data_format="hex", attempts=1)
            with pytest.raises(ProtocolError):
                d._values("MEDR,1,1,1", reply.rstrip(b"\n"), 100)
    assert sneaky >= 20


def test_mutator_is_seeded():
    a = [mutate(random.Random(5), CS1000_LINE) for _ in range(3)]
    b = [mutate(random.Random(5), CS1000_LINE) for _ in range(3)]
    assert a == b and not math.isnan(len(a[0]))


@pytest.mark.parametrize("url", ["/dev/ttyUSB9-absent", "sim://rotator-apt?faults=stall=2",
                                 "sim://nowhere"])
def test_opening_a_bad_port_is_an_instrument_error(url):
    from normbox_lab.core.errors import InstrumentError

    for cls in (AptRotationStage, ZaberRotationStage, SphereLightSource, CS1000A, CS2000A):
        with pytest.raises(InstrumentError, match="cannot open"):
            cls.open(url, VirtualClock())


@pytest.mark.parametrize("key", ["min_angle_deg", "time_scale", "box_inner_mm"])
def test_integers_beyond_float_range_are_config_errors(key):
    import re

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config

    text = re.sub(rf"^{key} = .*$", f"{key} = 1" + "0" * 400, SIM_CONFIG_TEMPLATE, count=1,
                  flags=re.MULTILINE)
    assert "0" * 400 in text
    with pytest.raises(ConfigError, match=key) as err:
        parse_config(text, "lab.toml")
    assert err.value.line > 0
