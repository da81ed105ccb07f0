"""CS-1000A: exact wire frames (scripted port), driver ↔ emulator, emulator rules, fuzzing."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from serial import SerialException
from wire import Exchange, ScriptedPort

from normbox_lab.core.capabilities import Spectroradiometer
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import (
    ConfigError,
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    OperatorAbort,
    ProtocolError,
)
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.drivers.cs1000 import CS1000A
from normbox_lab.drivers.radiometer_common import ybar_1nm
from normbox_lab.sim import core
from normbox_lab.sim.cs1000 import CS1000AEmulator
from normbox_lab.sim.transport import open_port

WL = RADIOMETER_WAVELENGTHS_NM
#: a known ramp (W·sr⁻¹·m⁻²·nm⁻¹) scaled so that 683·Σ L·ȳ = 100 cd/m², the Lv in the
#: colorimetric block below (the drivers check that the two agree)
SPECTRUM = (1.0 + (WL - 380.0) / 400.0) * 100.0 / (683.0 * float(np.sum(
    (1.0 + (WL - 380.0) / 400.0) * ybar_1nm())))
#: (x, y = 0.3595, 0.3525: the chromaticity of that ramp, which the drivers check too)
COLOUR_LINE = b"6.4182e-1,1.0000e2,1.0984e2,1.0000e2,3.5595e1,0.3595,0.3525,0.2559,0.5243,2856,+0.0012\n"


def spectral_lines(values: np.ndarray) -> list[bytes]:
    return [(",".join(f"{v:.4e}" for v in values[i:i + 28]) + "\n").encode()
            for i in range(0, 401, 28)]


def transfer_script(spectrum: np.ndarray = SPECTRUM, colour_line: bytes = COLOUR_LINE,
                    observer: int = 0) -> list[Exchange]:
    """The data transfer: every block is read twice (the drivers keep only blocks that two
    reads agree on): colorimetry twice, then the spectrum twice."""
    colour = [Exchange(f"BDR,1,{observer},0\n".encode(), b"OK\n"), Exchange(b"&\n", colour_line)]
    lines = ([Exchange(f"BDR,0,{observer},0\n".encode(), b"OK\n")]
             + [Exchange(b"&\n", line) for line in spectral_lines(spectrum)])
    return colour + colour + lines + lines


def measure_script(t: str = "1.50", spectrum: np.ndarray = SPECTRUM,
                   colour_line: bytes = COLOUR_LINE) -> list[Exchange]:
    return ([Exchange(b"MES,1\n", [(2.0, f"OK,{t}\n".encode()), (5.0, b"OK\n")])]
            + transfer_script(spectrum, colour_line))


def scripted(script: list[Exchange], **options) -> tuple[CS1000A, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(script, clock=clock)
    return CS1000A(port, clock, instrument_id="rad", **options), port


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


# --- exact frames, command by command ---------------------------------------------------------

def test_remote_on_off_frames():
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), Exchange(b"RMT,0\n", b"OK\n")])
    d.set_remote(True)
    assert d.remote
    d.set_remote(False)
    assert not d.remote
    port.assert_done()


def test_measure_frames_and_parsing():
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), *measure_script()])
    r = d.measure()
    port.assert_done()
    assert r.integration_time_s == 1.5
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM, rtol=6e-5)
    np.testing.assert_array_equal(r.wavelength_nm, WL)
    c = r.colorimetry
    assert (c.Le_W_sr_m2, c.Lv_cd_m2, c.X, c.Z) == (0.64182, 100.0, 109.84, 35.595)
    assert (c.x, c.y, c.u_prime, c.v_prime, c.cct_K, c.duv) == (0.3595, 0.3525, 0.2559, 0.5243,
                                                                 2856.0, 0.0012)
    assert d.port.clock.now_s() >= 5.0                  # waited for the final OK


def test_undefined_cct_is_nan():
    line = COLOUR_LINE.replace(b"2856,+0.0012", b"-9999,-9.9999")
    script = measure_script(colour_line=line)
    d, _port = scripted([Exchange(b"RMT,1\n", b"OK\n"), *script])
    c = d.measure().colorimetry
    assert np.isnan(c.cct_K) and np.isnan(c.duv)


def test_long_dark_measurement_waits_for_the_announced_time():
    """t = 60 s → the final OK 2·t later is still awaited (read timeout scaled to t)."""
    script = measure_script("60.00")
    script[0] = Exchange(b"MES,1\n", [(9.0, b"OK,60.00\n"), (9.0 + 120.0, b"OK\n")])
    d, _port = scripted([Exchange(b"RMT,1\n", b"OK\n"), *script])
    r = d.measure()
    assert r.integration_time_s == 60.0
    assert d.clock.now_s() >= 129.0


def test_observer_10_and_binary_frames():
    blocks = [struct.pack(f"<{n}f", *SPECTRUM[i:i + n])
              for i, n in zip(range(0, 401, 60), (60,) * 6 + (41,), strict=True)]
    colour = [Exchange(b"BDR,1,1,0\n", b"OK\n"), Exchange(b"&\n", COLOUR_LINE)]
    spectrum = [Exchange(b"BDR,0,1,1\n", b"OK\n")] + [Exchange(b"&\n", b) for b in blocks]
    script = ([Exchange(b"RMT,1\n", b"OK\n"),
               Exchange(b"MES,1\n", [(1.0, b"OK,0.10\n"), (1.2, b"OK\n")])]
              + colour * 2 + spectrum * 2)
    d, port = scripted(script, observer_deg=10, data_format="binary")
    r = d.measure()
    port.assert_done()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM, rtol=1e-6)


def test_abort_frames_when_idle():
    d, port = scripted([Exchange(b"MES,0\n", b"OK\n")])
    d.abort()
    port.assert_done()


@pytest.mark.parametrize(("mode", "time_s", "frame"), [
    ("auto", None, b"MMS,0,\n"), ("multi", 60.0, b"MMS,1,60.00\n"),
    ("auto-long", None, b"MMS,2,\n"), ("manual", 0.5, b"MMS,3,0.500\n")])
def test_time_mode_frames(mode, time_s, frame):
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), Exchange(frame, b"OK\n")])
    d.set_time_mode(mode, time_s)
    port.assert_done()
    assert d.time_mode == mode


def test_speed_and_status_frames():
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), Exchange(b"SPS,1\n", b"OK\n"),
                        Exchange(b"SPS,0\n", b"OK\n"), Exchange(b"SPR\n", b"OK,1\n"),
                        Exchange(b"STR\n", b"OK,3,1,0.500\n")])
    d.set_speed("fast")
    assert d.speed == "fast"
    d.set_speed("normal")
    assert d.read_speed() == "fast"
    s = d.status()
    assert (s["time_mode"], s["speed"], s["time_s"]) == ("manual", "fast", 0.5)
    port.assert_done()


def test_bad_arguments_are_config_errors():
    d, _ = scripted([])
    with pytest.raises(ConfigError):
        d.set_speed("ludicrous")
    with pytest.raises(ConfigError):
        d.set_time_mode("manual", 100.0)
    with pytest.raises(ConfigError):
        CS1000A.open("sim://cs1000a", VirtualClock(), baud=115200)


def test_device_error_carries_code_and_meaning():
    d, _port = scripted([Exchange(b"RMT,1\n", b"OK\n"),
                        Exchange(b"MES,1\n", [(3.0, b"ER10\n")])])
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER10" and "over" in e.value.meaning


def test_unknown_reply_is_protocol_error_with_raw_bytes():
    """Bounded attempts (3, and 3 more spared because the sync query (STR) is answered)."""
    d, port = scripted([Exchange(b"RMT,1\n", b"WHAT?\n"),
                        Exchange(b"STR\n", b"OK,0,0,1.000\n")] * 6)
    with pytest.raises(ProtocolError) as e:
        d.set_remote(True)
    assert e.value.raw == b"WHAT?"
    port.assert_done()


def test_busy_is_retried_then_succeeds():
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), Exchange(b"SPS,1\n", b"ER02\n"),
                        Exchange(b"SPS,1\n", b"OK\n")])
    d.set_speed("fast")
    port.assert_done()


def test_silence_is_a_bounded_timeout():
    """No reply within the timeout and the late window, and none to the sync query (STR)
    either: a typed timeout, without further attempts."""
    d, port = scripted([Exchange(b"RMT,1\n", b""), Exchange(b"STR\n", b"")])
    with pytest.raises(InstrumentTimeout):
        d.set_remote(True)
    assert d.clock.now_s() < 60.0
    port.assert_done()


def test_short_spectral_block_is_rejected_never_partial():
    """A block with 27 values instead of 28 never agrees with anything: the spectrum is read
    in passes (all blocks twice, then up to the block in doubt) and after ten a
    ProtocolError names it."""
    bad = spectral_lines(SPECTRUM)
    bad[3] = bad[3].rsplit(b",", 1)[0] + b"\n"
    select = Exchange(b"BDR,0,0,0\n", b"OK\n")
    whole = [select] + [Exchange(b"&\n", x) for x in bad]
    upto_bad = [select] + [Exchange(b"&\n", x) for x in bad[:4]]
    colour = [Exchange(b"BDR,1,0,0\n", b"OK\n"), Exchange(b"&\n", COLOUR_LINE)]
    d, port = scripted([Exchange(b"RMT,1\n", b"OK\n"), *measure_script()[:1], *colour * 2,
                        *whole * 2, *upto_bad * 8])
    with pytest.raises(ProtocolError, match="block 4 agree"):
        d.measure()
    port.assert_done()


def test_lost_link_reenters_remote_mode():
    script = [Exchange(b"RMT,1\n", b"OK\n"),
              Exchange(b"SPS,1\n", raises=SerialException("device disconnected")),
              Exchange(b"RMT,1\n", b"OK\n"), Exchange(b"SPS,1\n", b"OK\n")]
    d, port = scripted(script)
    d.set_speed("fast")
    port.assert_done()


def test_driver_satisfies_the_role():
    d, _ = scripted([])
    assert isinstance(d, Spectroradiometer)


# --- driver ↔ emulator --------------------------------------------------------------------------

def known_scene():
    return WL, SPECTRUM * 10.0


def emulator(**options) -> CS1000AEmulator:
    emu = CS1000AEmulator(core.CONTEXT.clock, **options)
    core.CONTEXT.instances["cs1000a"] = emu
    return emu


def test_end_to_end_noise_off_reproduces_the_scene_and_colour_science():
    import colour

    emulator(scene=known_scene, noise="off")
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock, baud=9600, instrument_id="rad")
    r = d.measure()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM * 10, rtol=6e-5)
    shape = colour.SpectralShape(380, 780, 1)
    sd = colour.SpectralDistribution(dict(zip(WL, SPECTRUM * 10, strict=True)))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    # colour divides by 100 when k is given (illuminant = 1): multiply back
    XYZ = colour.sd_to_XYZ(sd, cmfs, illuminant=colour.sd_ones(shape), k=683,
                           method="Integration") * 100
    c = r.colorimetry
    np.testing.assert_allclose([c.X, c.Y, c.Z], XYZ, rtol=2e-4)
    assert c.Lv_cd_m2 == pytest.approx(XYZ[1], rel=2e-4)
    assert c.Le_W_sr_m2 == pytest.approx(float(np.sum(SPECTRUM * 10)), rel=2e-4)
    xy = colour.XYZ_to_xy(XYZ)
    assert (c.x, c.y) == pytest.approx(tuple(xy), abs=6e-5)
    assert r.instrument_id == "rad"


def test_noise_on_stays_within_two_percent_and_is_seeded():
    flat = (WL, np.full(401, 0.01))
    emulator(scene=lambda: flat, seed=7)
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock)
    ratios = [d.measure().radiance_W_sr_m2_nm[100:300] / 0.01 for _ in range(4)]
    gains = [float(np.median(r)) for r in ratios]
    assert all(0.98 - 1e-4 <= g <= 1.02 + 1e-4 for g in gains)
    assert len({round(g, 5) for g in gains}) == 4            # scatter, not a constant
    emulator(scene=lambda: flat, seed=7)                    # power-cycled, same seed
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock)
    assert float(np.median(d.measure().radiance_W_sr_m2_nm[100:300] / 0.01)) \
        == pytest.approx(gains[0], rel=1e-4)


def test_wavelength_error_shifts_a_sharp_line_by_at_most_0_3_nm():
    line = (WL, np.exp(-0.5 * ((WL - 550.0) / 2.0) ** 2))
    emulator(scene=lambda: line, seed=3)
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock)
    for _ in range(3):
        L = d.measure().radiance_W_sr_m2_nm
        centroid = float(np.sum(WL * L) / np.sum(L))
        assert abs(centroid - 550.0) <= 0.3 + 1e-3


@pytest.mark.parametrize("lv", [500.0, 20.0, 1.0, 0.05])
def test_time_grows_in_the_dark_and_the_estimate_matches(lv):
    emu = emulator(scene=lambda: (WL, np.full(401, lv / 72983.0)), noise="off")
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock)
    d.set_remote(True)
    t0 = core.CONTEXT.clock.now_s()
    r = d.measure()
    took = core.CONTEXT.clock.now_s() - t0
    assert took == pytest.approx(d.estimate_measure_time_s(lv), rel=0.05, abs=0.3)
    assert emu.measure_time_s(lv) <= took
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(lv, rel=1e-3)


def test_estimate_is_monotonic_in_luminance():
    d, _ = scripted([])
    times = [d.estimate_measure_time_s(lv) for lv in (1e4, 100, 10, 1, 0.1, 0.001)]
    assert times == sorted(times) and times[-1] > 100


def test_over_range_is_a_device_error_and_the_instrument_recovers():
    bright = [(WL, np.full(401, 200.0))]                      # ~15 million cd/m²
    emulator(scene=lambda: bright[0])
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock)
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER10"
    bright[0] = (WL, np.full(401, 1e-4))
    assert d.measure().colorimetry.Lv_cd_m2 == pytest.approx(7.3, rel=0.05)


def test_world_radiance_is_used_when_no_scene():
    class World:
        def radiance_in_view(self):
            return np.array([300.0, 900.0]), np.array([0.02, 0.02])

    core.CONTEXT.world = World()
    d = CS1000A.open("sim://cs1000a?noise=off", core.CONTEXT.clock)
    np.testing.assert_allclose(d.measure().radiance_W_sr_m2_nm, 0.02, rtol=1e-4)


def test_default_spectrum_is_100_cd_m2_illuminant_a_like():
    d = CS1000A.open("sim://cs1000a?noise=off", core.CONTEXT.clock)
    c = d.measure().colorimetry
    assert c.Lv_cd_m2 == pytest.approx(100.0, rel=1e-3)
    assert c.cct_K == pytest.approx(2856, abs=2)


def test_binary_and_10_degree_end_to_end():
    emulator(scene=known_scene, noise="off")
    d = CS1000A.open("sim://cs1000a", core.CONTEXT.clock, data_format="binary", observer_deg=10)
    r = d.measure()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, SPECTRUM * 10, rtol=1e-6)
    assert r.colorimetry.X != pytest.approx(r.colorimetry.Lv_cd_m2 * 1.0, rel=1e-6)


def test_abort_from_another_thread_cancels_the_measurement():
    emu = emulator(scene=lambda: (WL, np.full(401, 1e-4)))     # dark: minutes

    class AbortingClock(VirtualClock):
        def sleep(self, duration_s):
            super().sleep(duration_s)
            if self.now_s() > 20.0:
                d.abort()                                     # as the engine thread would

    clock = AbortingClock()
    core.CONTEXT.clock = clock
    emu.clock = clock
    d = CS1000A.open("sim://cs1000a", clock)
    with pytest.raises(OperatorAbort):
        d.measure()
    assert b"MES,0" in emu.commands and emu.phase == "idle"
    assert clock.now_s() < 30.0


# --- emulator rules on the raw wire -----------------------------------------------------------------

def raw(url: str = "sim://cs1000a?noise=off"):
    return open_port(url, timeout=30)


def test_emulator_local_mode_refuses_and_buffer_rules():
    p = raw()
    p.write(b"STR\n")
    assert p.readline() == b"ER00\n"                     # local mode
    p.write(b"RMT,1\r\n")                                # a trailing CR is tolerated
    assert p.readline() == b"OK\n"
    p.write(b"BDR,0,0,0\n")
    assert p.readline() == b"ER20\n"                     # no data yet
    p.write(b"&\n")
    assert p.readline() == b"ER00\n"                     # nothing selected
    p.write(b"MMS,3,99\n")
    assert p.readline() == b"ER17\n"
    p.write(b"XYZ\n")
    assert p.readline() == b"ER00\n"


def test_emulator_refuses_commands_while_measuring_and_cancels():
    p = raw()
    p.write(b"RMT,1\n")
    p.readline()
    p.write(b"MES,1\n")
    p.write(b"STR\n")
    assert p.readline() == b"ER02\n"                     # refused during the pre-measurement
    assert p.readline().startswith(b"OK,")
    p.write(b"BDR,1,0,0\n")
    assert p.readline() == b"ER02\n"                     # refused while measuring
    p.write(b"MES,0\n")
    assert p.readline() == b"OK\n"
    p.timeout = 20
    assert p.readline() == b""                           # no final OK after a cancel
    p.write(b"BDR,1,0,0\n")
    assert p.readline() == b"ER20\n"                     # nothing in the buffer


def test_emulator_serial_line_time_at_baud():
    slow = CS1000AEmulator(VirtualClock(), baud=4800)
    fast = CS1000AEmulator(VirtualClock(), baud=19200)
    assert slow.line_time_s(401 * 10) == pytest.approx(4 * fast.line_time_s(401 * 10))
    assert slow.line_time_s(480) == pytest.approx(1.0)


def test_registered_under_cs1000a():
    assert "cs1000a" in core.known_devices()
    assert isinstance(core.create("cs1000a"), CS1000AEmulator)


# --- fuzzing: only typed errors escape -----------------------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=60))
def test_fuzz_parse_reply(data):
    d, _ = scripted([])
    try:
        fields = d.parse_reply(data)
    except (DeviceError, ProtocolError):
        return
    assert data.startswith(b"OK") and isinstance(fields, list)


line_bytes = st.one_of(
    st.binary(max_size=40).map(lambda b: b.replace(b"\n", b"") + b"\n"),
    st.sampled_from([b"OK\n", b"OK,1.00\n", b"ER10\n", b"OK,nan\n", b"OK,-3\n", b"", b"OK,1e9\n",
                     COLOUR_LINE, spectral_lines(SPECTRUM)[0], b"1,2,3\n", b"OK,1,2\n"]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(line_bytes, min_size=1, max_size=25))
def test_fuzz_measure_with_arbitrary_replies(replies):
    """Whatever the instrument answers, measure() returns a complete reading or raises a
    typed error; it never hangs."""

    class AnyPort(ScriptedPort):
        def write(self, data):
            reply = replies.pop(0) if replies else b""
            self._pending.append((self.clock.now_s() + 0.1, reply))
            return len(data)

    clock = VirtualClock()
    d = CS1000A(AnyPort([], clock=clock), clock, attempts=2)
    for call in (d.status, d.read_speed, d.measure):
        try:
            result = call()
        except InstrumentError:
            continue
        if call == d.measure:
            assert result.radiance_W_sr_m2_nm.shape == (401,)
            assert np.all(np.isfinite(result.radiance_W_sr_m2_nm))
    assert clock.now_s() < 3 * 3600


@settings(max_examples=80, deadline=None)
@given(st.lists(st.binary(max_size=20), max_size=8))
def test_fuzz_emulator_input_never_crashes_it(chunks):
    emu = CS1000AEmulator(VirtualClock(), noise="off")
    emu.feed(b"RMT,1\n")
    emu.clock.advance(1.0)
    for chunk in chunks:
        emu.feed(chunk + b"\n")
        emu.clock.advance(30.0)
        emu.poll()
    out = emu.take_output()
    assert out.startswith(b"OK\n")
    emu.feed(b"MES,0\nSTR\n")                    # still answering afterwards
    emu.clock.advance(1.0)
    assert emu.take_output().endswith(b"\n")
