"""JETI specbos 1211: exact wire frames (scripted port), driver ↔ emulator, emulator rules,
faults, the registries' entries."""

from __future__ import annotations

import random

import numpy as np
import pytest
from fuzz import ReplyPort, mutate
from test_fuzz import run_fuzz
from wire import Exchange, ScriptedPort

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.registry import DRIVERS, driver_class, drivers_for
from normbox_lab.core.capabilities import Recoverable, Spectroradiometer
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import ConfigError, DeviceError, InstrumentError, ProtocolError
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.drivers.radiometer_common import cmfs_1nm
from normbox_lab.drivers.specbos import Specbos1211, parse_identification
from normbox_lab.sim import core
from normbox_lab.sim.radiometer_common import default_spectrum
from normbox_lab.sim.specbos import ACK, BEL, NAK, SpecbosEmulator, adaptive_tint_ms
from normbox_lab.sim.transport import register_url_scheme

WL = RADIOMETER_WAVELENGTHS_NM
#: a ramp scaled to Lv = 100 cd/m², and its X, Y, Z (the driver checks that they agree)
RAMP = 1.0 + (WL - 380.0) / 400.0
SPECTRUM = RAMP * 100.0 / (683.0 * float(np.sum(RAMP * cmfs_1nm()[:, 1])))
XYZ = 683.0 * (SPECTRUM[:, None] * cmfs_1nm()).sum(axis=0)
CONFIGURE = [Exchange(cmd, ACK) for cmd in (
    b"*CONF:WRAN 380 780 1\r", b"*CONF:AVER 1\r", b"*CONF:EXPO 1\r", b"*CONF:MAXTIN 60000\r",
    b"*CONF:FORM 4\r")]


def spectral_block(values: np.ndarray = SPECTRUM, tint_ms: float = 200.0) -> bytes:
    rows = "".join(f"{v:.5e}\r" for v in values)
    return f"tint[ms]: {tint_ms:.3f}\rwran: 380 780 1\r{rows}\r".encode()


XYZ_BLOCK = "X: {:.5e}\rY: {:.5e}\rZ: {:.5e}\r".format(*XYZ).encode()
TRANSFER = [Exchange(b"*FETCH:SPRAD\r", spectral_block()), Exchange(b"*FETCH:XYZ\r", XYZ_BLOCK)]
INIT = Exchange(b"*INIT\r", [(0.01, ACK), (1.8, BEL)])


def scripted(script: list[Exchange], **options) -> tuple[Specbos1211, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(script, clock=clock)
    return Specbos1211(port, clock, instrument_id="rad", **options), port


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    register_url_scheme()
    yield
    core.CONTEXT.reset()


# --- exact frames ------------------------------------------------------------------------------

def test_measure_frames_configure_init_and_two_agreeing_reads():
    d, port = scripted([*CONFIGURE, INIT, *TRANSFER, *TRANSFER])
    with port:
        r = d.measure()
    assert np.allclose(r.radiance_W_sr_m2_nm, SPECTRUM, rtol=1e-5)
    assert r.integration_time_s == pytest.approx(0.2)
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(100.0, rel=1e-5)
    assert (r.colorimetry.x, r.colorimetry.y) == pytest.approx(
        (XYZ[0] / XYZ.sum(), XYZ[1] / XYZ.sum()), abs=1e-6)
    assert r.colorimetry.Le_W_sr_m2 == pytest.approx(float(SPECTRUM.sum()), rel=1e-5)
    assert r.metadata["model"] == "specbos 1211" and d.line_faults == 0


def test_identify_frames():
    d, port = scripted([Exchange(b"*IDN?\r", b"JETI_SB1211\r"),
                        Exchange(b"*PARA:SERNO?\r", b"serial number: 4711\r"),
                        Exchange(b"*VERS?\r", b"3.8.1\r")])
    with port:
        ident = d.identify()
    assert (ident.model, ident.serial_number, ident.firmware) == ("specbos 1211", "4711", "3.8.1")


def test_fast_caps_the_adaptive_time_at_five_seconds():
    frames = [Exchange(c.expect.replace(b"60000", b"5000"), ACK) for c in CONFIGURE]
    d, port = scripted(frames)
    with port:
        d.set_speed("fast")
        d.set_remote(True)
    assert frames[3].expect == b"*CONF:MAXTIN 5000\r"
    with pytest.raises(ConfigError):
        d.set_speed("turbo")


def test_a_nak_is_the_device_error_stat_err_names():
    d, port = scripted([Exchange(b"*CONF:WRAN 380 780 1\r", NAK),
                        Exchange(b"*STAT:ERR?\r", b"Error Code: 21\r")])
    with port, pytest.raises(DeviceError) as info:
        d.set_remote(True)
    assert info.value.code == 21 and "configuration argument" in info.value.meaning


def test_overexposure_ends_the_measurement_with_error_120():
    d, port = scripted([*CONFIGURE, Exchange(b"*INIT\r", [(0.01, ACK), (1.0, NAK)]),
                        Exchange(b"*STAT:ERR?\r", b"Error Code: 120\r")])
    with port, pytest.raises(DeviceError) as info:
        d.measure()
    assert info.value.code == 120


def test_disagreeing_reads_are_read_again_after_a_sync():
    """The second read of the spectrum differs in one digit: the line is synchronised with
    *IDN? and only the spectrum is read again; the reading is the two that agree."""
    changed = SPECTRUM.copy()
    changed[200] *= 1.5
    d, port = scripted([*CONFIGURE, INIT, *TRANSFER,
                        Exchange(b"*FETCH:SPRAD\r", spectral_block(changed)), TRANSFER[1],
                        Exchange(b"*IDN?\r", b"JETI_SB1211\r"), TRANSFER[0]])
    with port:
        r = d.measure()
    assert np.allclose(r.radiance_W_sr_m2_nm, SPECTRUM, rtol=1e-5) and d.line_faults >= 1


def test_a_block_whose_lines_do_not_add_up_is_a_protocol_error():
    d, _ = scripted([])
    lines = spectral_block().split(b"\r")[:-1]
    with pytest.raises(ProtocolError, match="wavelength range"):
        d._parse_spectrum([lines[0], b"wran: 380 780 5", *lines[2:]])
    with pytest.raises(ProtocolError, match="where 381 belongs"):
        d._parse_spectrum([*lines[:3], b"382\t1.0e-3", *lines[4:]])
    values = d._parse_spectrum([*lines[:2], *(b"%d\t%.5e" % (w, v) for w, v in zip(
        WL, SPECTRUM, strict=True)), b""])[1]                      # nm<TAB>value is read too
    assert np.allclose(values, SPECTRUM, rtol=1e-5)


def test_identification_for_lab_discover():
    replies = [b"\x15", b"JETI_SB1211", b"serial number: 4711", b"3.8.1"]
    ident = parse_identification(replies)
    assert (ident.model, ident.serial_number, ident.firmware) == ("specbos 1211", "4711", "3.8.1")
    assert parse_identification([b"", b"OK00,CS-2000A ,2,1", b"", b""]) is None


def _fuzz_case(rng: random.Random) -> None:
    """One mutated answer into the driver's real read path."""
    clock = VirtualClock()
    d = Specbos1211(ReplyPort([], clock), clock, attempts=1, command_timeout_s=1.0)
    which = rng.randrange(4)
    if which == 0:
        d.port.replies = [mutate(rng, spectral_block())]
        d._parse_spectrum(d._fetch(b"*FETCH:SPRAD", 2 + 401 + 1))
    elif which == 1:
        d.port.replies = [mutate(rng, XYZ_BLOCK)]
        d._parse_xyz(d._fetch(b"*FETCH:XYZ", 3))
    elif which == 2:
        d.port.replies = [mutate(rng, ACK + BEL)]
        d._run_measurement()
    else:
        d.port.replies = [mutate(rng, b"JETI_SB1211\r")]
        d.query("*IDN?", "JETI_SB")


def test_fuzzed_answers_end_in_a_result_or_a_typed_error():
    counts = run_fuzz(_fuzz_case, 600, seed=11)
    assert sum(counts.values()) == 600 and counts["ok"] < 600 and counts["ProtocolError"] > 0


# --- driver against the emulator ---------------------------------------------------------------

def test_driver_against_emulator_measures_the_light_in_its_modelled_time():
    clock = core.CONTEXT.clock
    d = Specbos1211.open("sim://specbos1211?noise=off", clock)
    emu = core.CONTEXT.instances["specbos1211"]
    assert isinstance(d, Spectroradiometer) and isinstance(d, Recoverable)
    t0 = clock.now_s()
    r = d.measure()
    took_s = clock.now_s() - t0
    _, truth = default_spectrum()
    assert np.allclose(r.radiance_W_sr_m2_nm, truth, rtol=2e-5, atol=1e-12)
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(100.0, rel=1e-4)
    assert r.integration_time_s == pytest.approx(adaptive_tint_ms(100.0) / 1000.0)
    assert took_s == pytest.approx(d.estimate_measure_time_s(100.0), rel=0.01)
    assert emu.measure_time_s(100.0) == pytest.approx(1.0 + 2 * 0.2 + 0.2)
    assert d.identify().serial_number == "123456"


@pytest.mark.parametrize("faults", ["garble=0.2", "late-reply=0.2:12", "truncate=0.15",
                                    "no-reply=0.05", "disconnect@4:3"])
def test_faults_end_in_the_right_reading_or_a_typed_error(faults):
    clock = core.CONTEXT.clock
    d = Specbos1211.open(f"sim://specbos1211?noise=off&seed=5&faults={faults}", clock)
    _, truth = default_spectrum()
    good = 0
    for _ in range(6):
        try:
            r = d.measure()
        except InstrumentError:
            continue
        assert np.allclose(r.radiance_W_sr_m2_nm, truth, rtol=2e-5, atol=1e-12)
        good += 1
    assert good >= 4 and d.line_faults > 0


def test_device_faults_are_typed():
    clock = core.CONTEXT.clock
    d = Specbos1211.open("sim://specbos1211?noise=off&faults=over-range@1", clock)
    with pytest.raises(DeviceError) as info:
        d.measure()
    assert info.value.code == 120
    d.measure()                                         # the next one is fine
    core.CONTEXT.reset(VirtualClock())
    d = Specbos1211.open("sim://specbos1211?faults=device-error@2:170", core.CONTEXT.clock)
    with pytest.raises(DeviceError) as info:
        d.measure()
    assert info.value.code == 170


# --- emulator rules ------------------------------------------------------------------------------

def _talk(emu: SpecbosEmulator, clock: VirtualClock, cmd: bytes, wait_s: float = 0.1) -> bytes:
    emu.feed(cmd + b"\r")
    clock.advance(wait_s)
    return emu.take_output()


def test_emulator_answers_as_the_command_set_says():
    clock = VirtualClock()
    emu = SpecbosEmulator(clock, noise="off")
    assert _talk(emu, clock, b"*idn?") == b"JETI_SB1211\r"             # case-insensitive
    assert _talk(emu, clock, b"*PARA:WAVBEG?") == b"Predefined start wave: 380\r"
    assert _talk(emu, clock, b"*FETCH:SPRAD") == NAK                     # no data yet
    assert _talk(emu, clock, b"*STAT:ERR?") == b"Error Code: 138\r"
    assert _talk(emu, clock, b"*STAT:ERR?") == b"Error Code: 0\r"       # read clears it
    assert _talk(emu, clock, b"*CONF:AVER 0") == NAK
    assert _talk(emu, clock, b"*STAT:ERR?") == b"Error Code: 10\r"
    assert _talk(emu, clock, b"*CONF:WRAN 380 780 7") == NAK               # 400 nm not in 7s
    assert _talk(emu, clock, b"*STAT:ERR?") == b"Error Code: 12\r"
    assert _talk(emu, clock, b"*CONF:WRAN 400 700 5") == ACK
    assert _talk(emu, clock, b"*CONF:WRAN?") == b"wran: 400 700 5\r"
    assert _talk(emu, clock, b"*BOGUS") == NAK
    # a measurement: ACK at once, BEL at the modelled end; meanwhile only *BREAK, *IDN?,
    # *STAT:ERR? are answered
    assert _talk(emu, clock, b"*INIT", 0.05) == ACK
    assert _talk(emu, clock, b"*FETCH:XYZ", 0.05) == NAK
    assert _talk(emu, clock, b"*IDN?", 0.05) == b"JETI_SB1211\r"
    assert _talk(emu, clock, b"*STAT:ERR?", 2.0) == b"Error Code: 4\r"
    clock.advance(0.1)
    assert emu.take_output() == BEL                    # 1.6 s: adaptation + 2 × 0.2 s + 0.2 s
    block = _talk(emu, clock, b"*FETCH:SPRAD").split(b"\r")
    assert block[:2] == [b"tint[ms]: 200.000", b"wran: 400 700 5"] and block[-2:] == [b"", b""]
    rows = [line.split(b"\t") for line in block[2:-2]]
    assert [int(w) for w, _ in rows] == list(range(400, 701, 5))          # format 7 by default
    _, truth = default_spectrum()
    assert np.allclose([float(v) for _, v in rows], truth[20:321:5], rtol=1e-5)


def test_break_stops_a_measurement_with_scan_break():
    clock = VirtualClock()
    emu = SpecbosEmulator(clock, noise="off")
    assert _talk(emu, clock, b"*INIT", 0.05) == ACK
    assert _talk(emu, clock, b"*BREAK", 5.0) == NAK + ACK
    assert _talk(emu, clock, b"*STAT:ERR?") == b"Error Code: 147\r"
    assert emu.data is None


def test_a_power_blip_restores_the_configuration():
    clock = VirtualClock()
    emu = SpecbosEmulator(clock, noise="off")
    assert _talk(emu, clock, b"*CONF:AVER 5") == ACK
    emu.disconnect(1.0)
    clock.advance(1.5)
    assert _talk(emu, clock, b"*CONF:AVER?") == b"aver: 1\r"


# --- the registries ------------------------------------------------------------------------------

def test_one_entry_each_makes_it_a_lab_radiometer():
    assert "specbos1211" in drivers_for("radiometer") and "specbos1211" in core.devices_for(
        "radiometer")
    assert driver_class("specbos1211") is Specbos1211
    assert core.emulator_class("specbos1211") is SpecbosEmulator
    text = SIM_CONFIG_TEMPLATE.replace('driver = "cs1000a"', 'driver = "specbos1211"', 1) \
        .replace('port = "sim://cs1000a"', 'port = "sim://specbos1211"', 1)
    with pytest.raises(ConfigError, match=r"must be one of \(921600, 115200, 38400\)"):
        parse_config(text, "lab.toml")                               # the template's 9600
    cfg = parse_config(text.replace("baud = 9600", "baud = 921600", 1))
    assert cfg.instruments["radiometer"].driver == "specbos1211"
    assert DRIVERS["specbos1211"].baud_rates[0] == 921600


def _sweep(tmp_path, driver: str, baud: int) -> dict[str, np.ndarray]:
    """A reference sweep (30°, 90° × patches 1, 19) in a simulated lab on the analytic world
    with `driver` as the radiometer (noise off): key → stored radiance."""
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store
    from normbox_lab.sim import labsim

    text = SIM_CONFIG_TEMPLATE.replace('driver = "cs1000a"', f'driver = "{driver}"', 1) \
        .replace('port = "sim://cs1000a"', f'port = "sim://{driver}?noise=off"', 1) \
        .replace("baud = 9600 ", f"baud = {baud} ", 1)
    core.CONTEXT.reset(VirtualClock())
    lab = labsim.build_lab(parse_config(text), world="analytic")
    try:
        assert type(lab.instrument("radiometer")) is driver_class(driver)
        with Store(tmp_path / f"{driver}.sqlite") as store:
            plan = eng.build_plan("reference-sweep", {"angles_deg": [30, 90],
                                                      "patches": [1, 19]}, lab)
            res = eng.Engine(lab, store, plan).run()
            assert res.status == "done" and res.done == 4
            keys = ("a30/p01", "a30/p19", "a90/p01", "a90/p19")
            return {k: store.reading(res.run_id, k).arrays["radiance_W_sr_m2_nm"] for k in keys}
    finally:
        lab.close()


def test_a_simulated_lab_with_a_specbos_runs_a_reference_sweep(tmp_path):
    """The lab assembly opens it from the config (registry entry, options through `open`) and
    the engine runs a reference sweep with it: every stored reading equals the CS-1000A's of
    the same sweep to 0.1 % (both emulators report the world's radiance with the noise off;
    the CS-1000A's wire has 5 digits, and the two measure at different moments of the
    world's lamp)."""
    specbos = _sweep(tmp_path, "specbos1211", 921600)
    reference = _sweep(tmp_path, "cs1000a", 9600)
    for key, radiance in reference.items():
        np.testing.assert_allclose(specbos[key], radiance, rtol=1e-3, atol=1e-12, err_msg=key)
    assert specbos["a30/p19"].max() > 1.5 * specbos["a30/p01"].max() > 0   # white, dark skin
