"""CS-2000A: exact wire frames (scripted port), driver ↔ emulator, emulator rules, fuzzing."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from wire import Exchange, ScriptedPort

from normbox_lab.core.capabilities import Spectroradiometer
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import (
    ConfigError,
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    ProtocolError,
)
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.drivers.cs2000 import CS2000A, ERRORS
from normbox_lab.drivers.radiometer_common import ybar_1nm
from normbox_lab.sim import core
from normbox_lab.sim.cs2000 import CS2000AEmulator, fmt_hex, fmt_lv
from normbox_lab.sim.transport import open_port

WL = RADIOMETER_WAVELENGTHS_NM
#: a known ramp (W·sr⁻¹·m⁻²·nm⁻¹) scaled so that 683·Σ L·ȳ = 100 cd/m², the Lv in the
#: colorimetric block below (the drivers check that the two agree)
SPECTRUM = (1.0 + (WL - 380.0) / 400.0) * 100.0 / (683.0 * float(np.sum(
    (1.0 + (WL - 380.0) / 400.0) * ybar_1nm())))
#: (x, y = 0.3595, 0.3525: the chromaticity of that ramp, which the drivers check too)
COLOUR_24 = ("6.4182e-1,100.000,1.0984e2,1.0000e2,3.5595e1,0.3595,0.3525,0.2559,0.5243,2856,"
             "+0.0012,-9.9e9,-9.9e9,1.1721e2,1.0547e2,3.7138e1,0.4511,0.4059,0.2589,0.5242,2789,"
             "-0.0010,-9.9e9,-9.9e9")
CONDITIONS = b"OK00,0,0,001000000,0,0,0,0,00\n"
BLOCKS = ((1, 0, 100), (2, 100, 200), (3, 200, 300), (4, 300, 401))


def block_reply(lo: int, hi: int, hexfmt: bool = False, delim: bytes = b"\n") -> bytes:
    vals = SPECTRUM[lo:hi]
    text = ",".join(fmt_hex(v) if hexfmt else f"{v:.4e}" for v in vals)
    return f"OK00,{text}".encode() + delim


def remote_script(delim: bytes = b"\n") -> list[Exchange]:
    return [Exchange(b"RMTS,2" + delim, b"OK00" + delim), Exchange(b"MSWE,0" + delim,
                                                                   b"OK00" + delim)]


def transfer_script(hexfmt: bool = False, delim: bytes = b"\n") -> list[Exchange]:
    """One read of the buffer: spectral blocks 1–4, colorimetry, conditions."""
    f = b"1" if hexfmt else b"0"
    colour = COLOUR_24 if not hexfmt else ",".join(
        fmt_hex(float(x)) for x in COLOUR_24.split(","))
    return ([Exchange(b"MEDR,1," + f + b"," + str(b).encode() + delim,
                      block_reply(lo, hi, hexfmt, delim)) for b, lo, hi in BLOCKS]
            + [Exchange(b"MEDR,2," + f + b",00" + delim, f"OK00,{colour}".encode() + delim),
               Exchange(b"MEDR,0,0,1" + delim, CONDITIONS.replace(b"\n", delim))])


def measure_script(hexfmt: bool = False, delim: bytes = b"\n", ttt: int = 2) -> list[Exchange]:
    """MEAS,1 and its two replies, then the buffer read twice (the drivers keep only blocks
    that two reads agree on)."""
    return ([Exchange(b"MEAS,1" + delim, [(3.0, f"OK00,{ttt:03d}".encode() + delim),
                                          (3.0 + ttt, b"OK00" + delim)])]
            + transfer_script(hexfmt, delim) * 2)


IDDR = Exchange(b"IDDR\n", b"OK00,CS-2000A ,2,2000123\n")


def scripted(script: list[Exchange], **options) -> tuple[CS2000A, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(script, clock=clock)
    return CS2000A(port, clock, instrument_id="rad", **options), port


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


# --- exact frames ------------------------------------------------------------------------------

def test_remote_prefers_rmts_2_and_turns_the_button_off():
    d, port = scripted([*remote_script(), Exchange(b"RMTS,0\n", b"OK00\n")])
    d.set_remote(True)
    assert d.remote_level == 2
    d.set_remote(False)
    port.assert_done()


def test_remote_falls_back_to_rmts_1_on_old_firmware():
    d, port = scripted([Exchange(b"RMTS,2\n", b"ER17\n"), Exchange(b"RMTS,1\n", b"OK00\n"),
                        Exchange(b"MSWE,0\n", b"OK00\n")])
    d.set_remote(True)
    assert d.remote_level == 1
    port.assert_done()


def test_identify_frames():
    d, port = scripted([*remote_script(), Exchange(b"IDDR\n", b"OK00,CS-2000A ,2,1234567\n")])
    ident = d.identify()
    assert (ident.model, ident.serial_number, ident.extra["variation"]) == \
        ("CS-2000A", "1234567", "CS-2000A")
    port.assert_done()


@pytest.mark.parametrize(("mode", "kw", "frame"), [
    ("normal", {}, b"SPMS,0,2\n"), ("fast", {"nd": "off"}, b"SPMS,1,0\n"),
    ("multi-normal", {"time_s": 16}, b"SPMS,2,16,2\n"),
    ("manual", {"time_s": 0.5, "nd": "on"}, b"SPMS,3,500000,1\n"),
    ("multi-fast", {"time_s": 3, "nd": "on"}, b"SPMS,4,3,1\n")])
def test_speed_frames(mode, kw, frame):
    d, port = scripted([*remote_script(), Exchange(frame, b"OK00\n")])
    d.set_speed(mode, **kw)
    port.assert_done()
    assert d.speed == mode


@pytest.mark.parametrize(("reply", "expected"), [
    (b"OK00,0,2\n", {"speed": "normal", "nd": "auto"}),
    (b"OK00,2,04,2\n", {"speed": "multi-normal", "time_s": 4.0, "nd": "auto"}),
    (b"OK00,3,000033333,0\n", {"speed": "manual", "time_s": 0.033333, "nd": "off"})])
def test_speed_read_frames(reply, expected):
    d, port = scripted([*remote_script(), Exchange(b"SPMR\n", reply)])
    assert d.read_speed() == expected
    port.assert_done()


@pytest.mark.parametrize("hexfmt", [False, True])
def test_measure_frames_ascii_and_hex(hexfmt):
    d, port = scripted([*remote_script(), *measure_script(hexfmt)],
                       data_format="hex" if hexfmt else "ascii")
    r = d.measure()
    port.assert_done()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM, rtol=6e-5)
    c = r.colorimetry
    assert c.Lv_cd_m2 == pytest.approx(100.0) and c.cct_K == pytest.approx(2856)
    assert c.duv == pytest.approx(0.0012, abs=1e-7)
    assert r.integration_time_s == 1.0
    assert r.metadata["measurement_time_s"] == 2
    assert r.metadata["colorimetry_10deg"]["X10"] == pytest.approx(117.21, rel=1e-6)
    assert d.clock.now_s() >= 5.0


def test_crlf_delimiter_is_used_and_answered():
    d, port = scripted([*remote_script(b"\r\n"), *measure_script(delim=b"\r\n")],
                       delimiter="\r\n")
    np.testing.assert_allclose(d.measure().radiance_W_sr_m2_nm, SPECTRUM, rtol=6e-5)
    port.assert_done()


def test_long_measurement_242_s():
    d, _port = scripted([*remote_script(), *measure_script(ttt=242)])
    d.measure()
    assert d.clock.now_s() >= 245.0


def test_abort_idle_frames_and_er17_tolerated():
    d, port = scripted([Exchange(b"MEAS,0\n", b"ER17\n")])
    d.abort()
    port.assert_done()


def test_conditions_frames():
    d, port = scripted([*remote_script(), Exchange(b"MEDR,0,0,1\n", CONDITIONS)])
    assert d.measurement_conditions()["integration_time_us"] == 1_000_000
    port.assert_done()


@pytest.mark.parametrize("code", sorted(set(ERRORS) - {"ER00", "ER02", "ER20"}))
def test_every_error_code_has_a_meaning(code):
    """(ER00, ER02 and ER20 lead to recovery: see test_radiometer_faults.py.)"""
    d, _ = scripted([*remote_script(), Exchange(b"MEAS,1\n", [(2.0, code.encode() + b"\n")])])
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == code and e.value.meaning == ERRORS[code]


def test_unknown_reply_is_protocol_error_with_raw():
    """Bounded attempts (3, and 3 more spared because the sync query (IDDR) is answered)."""
    d, port = scripted([Exchange(b"RMTS,2\n", b"OK01\n"), IDDR] * 6)
    with pytest.raises(ProtocolError) as e:
        d.set_remote(True)
    assert e.value.raw == b"OK01"
    port.assert_done()


def test_wrong_value_count_is_rejected():
    """Block 1 with 99 values, every time: each pass ends there, the line is checked with
    IDDR (the sync query), and after ten passes it is a ProtocolError naming the block."""
    script = measure_script()
    bad = Exchange(b"MEDR,1,0,1\n", block_reply(0, 99))
    d, port = scripted([*remote_script(), script[0], *[bad, IDDR] * 10])
    with pytest.raises(ProtocolError, match="block 1 agree"):
        d.measure()
    port.assert_done()


def test_bad_arguments():
    d, _ = scripted([])
    with pytest.raises(ConfigError):
        d.set_speed("multi-normal", time_s=30)
    with pytest.raises(ConfigError):
        d.set_speed("manual", time_s=0.5, nd="auto")
    with pytest.raises(ConfigError):
        CS2000A(ScriptedPort([]), VirtualClock(), data_format="binary")


def test_role():
    d, _ = scripted([])
    assert isinstance(d, Spectroradiometer)


# --- driver ↔ emulator ----------------------------------------------------------------------------

def emulator(**options) -> CS2000AEmulator:
    emu = CS2000AEmulator(core.CONTEXT.clock, **options)
    core.CONTEXT.instances["cs2000a"] = emu
    return emu


@pytest.mark.parametrize("fmt", ["ascii", "hex"])
def test_end_to_end_reproduces_the_scene(fmt):
    emulator(scene=lambda: (WL, SPECTRUM * 10), noise="off")
    d = CS2000A.open("sim://cs2000a", core.CONTEXT.clock, instrument_id="rad", data_format=fmt)
    r = d.measure()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM * 10,
                               rtol=6e-5 if fmt == "ascii" else 1e-6)
    Y = 683 * float(np.sum(SPECTRUM * 10 * _ybar()))
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(Y, rel=1e-4)
    assert d.identify().serial_number == "2000123"


def _ybar():
    import colour

    c = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return np.interp(WL, c.wavelengths, c.values[:, 1])


@pytest.mark.parametrize(("lv", "speed"), [(1000.0, "normal"), (4.7, "normal"), (4.7, "fast"),
                                           (0.1, "normal")])
def test_time_model_and_estimate(lv, speed):
    emu = emulator(scene=lambda: (WL, np.full(401, lv / 72983.0)), noise="off")
    d = CS2000A.open("sim://cs2000a", core.CONTEXT.clock)
    d.set_speed(speed)
    t0 = core.CONTEXT.clock.now_s()
    r = d.measure()
    took = core.CONTEXT.clock.now_s() - t0
    assert took == pytest.approx(d.estimate_measure_time_s(lv), rel=0.03, abs=0.2)
    assert took >= emu.measure_time_s(lv)
    assert r.metadata["measurement_time_s"] == min(242, max(2, int(np.ceil(
        (50 if speed == "fast" else 200) / r.colorimetry.Lv_cd_m2 - 1e-9))))


def test_rmts_2_spares_the_flash_and_old_firmware_falls_back():
    emu = emulator()
    d = CS2000A.open("sim://cs2000a", core.CONTEXT.clock)
    d.set_speed("fast")
    assert emu.remote == 2 and emu.flash_writes == 0
    old = emulator(firmware="1.01.0000")
    d = CS2000A.open("sim://cs2000a", core.CONTEXT.clock)
    d.set_speed("fast")
    assert old.remote == 1 and old.flash_writes == 2          # MSWE,0 and SPMS
    assert old.commands[:3] == [b"RMTS,2", b"RMTS,1", b"MSWE,0"]


def test_over_range_er10():
    emulator(scene=lambda: (WL, np.full(401, 1000.0)))       # ~73 million cd/m²
    d = CS2000A.open("sim://cs2000a", core.CONTEXT.clock)
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER10"


# --- emulator rules on the raw wire --------------------------------------------------------------------

def test_emulator_key_mode_delimiters_and_buffer():
    p = open_port("sim://cs2000a?noise=off", timeout=30)
    p.write(b"IDDR\r\n")
    assert p.read_until(b"\r\n") == b"ER00\r\n"          # key mode; reply uses CR+LF
    p.write(b"RMTS,1\r")
    assert p.read_until(b"\r") == b"OK00\r"              # CR in, CR out
    p.write(b"MEDR,1,0,1\n")
    assert p.readline() == b"ER20\n"                     # no data
    p.write(b"MEDR,1,0,5\n")
    assert p.readline() == b"ER17\n"
    p.write(b"MEAS,0\n")
    assert p.readline() == b"ER17\n"                     # nothing to cancel
    p.write(b"MEDR,1,0\n")
    assert p.readline() == b"ER00\n"                     # wrong parameter count


def test_emulator_measurement_rules():
    p = open_port("sim://cs2000a?noise=off", timeout=30)
    p.write(b"RMTS,1\n")
    p.readline()
    p.write(b"MEAS,1\n")
    p.write(b"SPMR\n")                                   # during pre-measurement: ignored
    first = p.readline()
    assert first.startswith(b"OK00,") and len(first) == len(b"OK00,002\n")
    p.write(b"SPMR\n")
    assert p.readline() == b"ER00\n"
    p.write(b"MEAS,1\n")
    assert p.readline() == b"ER17\n"
    assert p.readline() == b"OK00\n"                     # the measurement ends
    for b in (1, 2, 3, 4):
        p.write(f"MEDR,1,0,{b}\n".encode())
        line = p.readline()
        assert len(line.split(b",")) == (102 if b == 4 else 101)
        assert len(line) == 5 + (101 if b == 4 else 100) * 10
    p.write(b"MEDR,2,0,00\n")
    assert len(p.readline().split(b",")) == 25
    p.write(b"MEAS,1\n")
    p.readline()
    p.write(b"MEAS,0\n")
    assert p.readline() == b"OK00\n"
    p.timeout = 30
    assert p.readline() == b""                           # no final reply after a cancel
    p.write(b"MEDR,2,0,101\n")
    assert p.readline() == b"ER20\n"


def test_emulator_mswe_1_clears_the_buffer_after_reading():
    p = open_port("sim://cs2000a?noise=off", timeout=30)
    for cmd in (b"RMTS,2\n", b"MSWE,1\n"):
        p.write(cmd)
        assert p.readline() == b"OK00\n"
    p.write(b"MEAS,1\n")
    p.readline()
    p.readline()
    p.write(b"MEDR,2,0,02\n")
    assert p.readline().count(b",") == 3                  # x, y, Lv
    p.write(b"MEDR,1,0,1\n")
    assert p.readline() == b"ER20\n"                     # cleared after one colorimetric set


def test_number_shapes():
    assert fmt_lv(123.456) == "123.46" and fmt_lv(1.23456) == "1.2346"
    assert fmt_lv(0.00001) == "0.0000" and fmt_lv(12345.6) == "12346"
    assert fmt_lv(2_500_000) == "2.50e+6"
    assert fmt_hex(1.0) == "3F800000" and fmt_hex(float("nan")) == "D1BA43B6"
    assert struct.unpack(">f", bytes.fromhex("D1BA43B6"))[0] == pytest.approx(-9.999999e10,
                                                                                rel=1e-6)


# --- fuzzing ------------------------------------------------------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=60))
def test_fuzz_parse_reply(data):
    d, _ = scripted([])
    try:
        d.parse_reply(data)
    except (DeviceError, ProtocolError):
        return
    assert data.startswith(b"OK00")


line_bytes = st.one_of(
    st.binary(max_size=40).map(lambda b: b.replace(b"\n", b"") + b"\n"),
    st.sampled_from([b"OK00\n", b"OK00,002\n", b"ER10\n", b"OK00,xyz\n", b"OK00,-3\n", b"",
                     block_reply(0, 100), block_reply(300, 401, True), CONDITIONS,
                     f"OK00,{COLOUR_24}\n".encode(), b"OK00,1,2\n", b"OK00,CS-2000A ,2,1\n"]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(line_bytes, min_size=1, max_size=20), st.sampled_from(["ascii", "hex"]))
def test_fuzz_every_call_with_arbitrary_replies(replies, fmt):
    class AnyPort(ScriptedPort):
        def write(self, data):
            self._pending.append((self.clock.now_s() + 0.1, replies.pop(0) if replies else b""))
            return len(data)

    clock = VirtualClock()
    d = CS2000A(AnyPort([], clock=clock), clock, attempts=2, data_format=fmt)
    for call in (d.identify, d.read_speed, d.measurement_conditions, d.measure):
        try:
            result = call()
        except InstrumentError:
            continue
        if call == d.measure:
            assert result.radiance_W_sr_m2_nm.shape == (401,)
            assert np.all(np.isfinite(result.radiance_W_sr_m2_nm))
    assert clock.now_s() < 4 * 3600


def test_hex_field_with_blanks_is_a_protocol_error_never_a_struct_error():
    """``12 34 56`` has the 8 characters of a hex float, but bytes.fromhex skips the blanks
    and gives 3 bytes (struct.error before).  Strictly 8 hex digits, else ProtocolError; the
    block is read again each pass and never agrees."""
    fields = [fmt_hex(v) for v in SPECTRUM[0:100]]
    fields[17] = "12 34 56"
    bad = Exchange(b"MEDR,1,1,1\n", ("OK00," + ",".join(fields) + "\n").encode())
    d, port = scripted([*remote_script(), measure_script(hexfmt=True)[0], *[bad, IDDR] * 10],
                       data_format="hex")
    with pytest.raises(ProtocolError, match="block 1 agree"):
        d.measure()
    port.assert_done()


def test_silence_is_bounded():
    """No reply to RMTS,2 within the timeout and the late window, none to the sync query:
    a typed timeout at once."""
    d, port = scripted([Exchange(b"RMTS,2\n", b""), Exchange(b"IDDR\n", b"")])
    with pytest.raises(InstrumentTimeout):
        d.set_remote(True)
    assert d.clock.now_s() < 60
    port.assert_done()


@settings(max_examples=80, deadline=None)
@given(st.lists(st.binary(max_size=20), max_size=8))
def test_fuzz_emulator_input_never_crashes_it(chunks):
    emu = CS2000AEmulator(VirtualClock(), noise="off")
    emu.feed(b"RMTS,1\n")
    emu.clock.advance(1.0)
    for chunk in chunks:
        emu.feed(chunk + b"\n")
        emu.clock.advance(300.0)
        emu.poll()
    assert emu.take_output().startswith(b"OK00\n")
    emu.clock.advance(300.0)
    emu.feed(b"SPMR\n")
    emu.clock.advance(1.0)
    assert emu.take_output().endswith(b"\n")


def test_abort_from_another_thread_cancels_the_measurement():
    from normbox_lab.core.errors import OperatorAbort

    emu = emulator(scene=lambda: (WL, np.full(401, 1e-5)))      # dark: ttt = 242 s

    class AbortingClock(VirtualClock):
        def sleep(self, duration_s):
            super().sleep(duration_s)
            if self.now_s() > 30.0:
                d.abort()                                      # as the engine thread would

    clock = AbortingClock()
    core.CONTEXT.clock = clock
    emu.clock = clock
    d = CS2000A.open("sim://cs2000a", clock)
    d.set_speed("normal")                     # the factory default (Multi-Integ 1 s) is short
    with pytest.raises(OperatorAbort):
        d.measure()
    assert emu.commands[-1] == b"MEAS,0" and emu.phase == "idle"
    assert clock.now_s() < 40.0


def test_emulator_crlf_split_across_writes_is_one_delimiter():
    p = open_port("sim://cs2000a", timeout=5)
    p.write(b"RMTS,1\r")
    p.write(b"\n")
    assert p.read_until(b"\r\n") == b"OK00\r\n"
    p.write(b"RMTS,1\r")
    assert p.read_until(b"\r") == b"OK00\r"          # a lone CR, answered after a short wait
    p.timeout = 1
    assert p.read(10) == b""
