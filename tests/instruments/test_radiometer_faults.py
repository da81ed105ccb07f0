"""Fault injection against both radiometer drivers, through the `sim://` URL and the Python API.

Transport kinds (sim.core): no-reply, late-reply, garble, truncate, disconnect.  Device kinds
(the emulators): device-error, busy, over-range.  For each: the driver recovers (bounded) and
returns a reading equal to the scene, or raises a typed error — never hangs, never returns a
partial spectrum.

Reply numbers (``kind@n``) of one measurement after opening:
  CS-1000A: 1 RMT,1 · 2 OK,<t> · 3 OK (end) · 4 BDR · 5 colorimetry · 6 BDR · 7–21 spectrum
  CS-2000A: 1 RMTS,2 · 2 MSWE,0 · 3 OK00,ttt · 4 OK00 (end) · 5–8 MEDR,1 · 9 MEDR,2 · 10 MEDR,0
"""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError, InstrumentTimeout
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.drivers.cs1000 import CS1000A
from normbox_lab.drivers.cs2000 import CS2000A
from normbox_lab.sim import core

WL = RADIOMETER_WAVELENGTHS_NM
TRUTH = 2e-3 * (1.0 + np.sin(WL / 37.0) ** 2)       # ~ 200 cd/m²
MODELS = {
    "cs1000a": (CS1000A, {"end": 3, "first": 2, "data": 10, "remote": "RMT,1"}),
    "cs2000a": (CS2000A, {"end": 4, "first": 3, "data": 6, "remote": "RMTS,2"}),
}


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


def open_driver(model: str, faults: str = "", **url_options):
    cls, _ = MODELS[model]
    opts = "".join(f"&{k}={v}" for k, v in url_options.items())
    emu = core.instance(model, scene=lambda: (WL, TRUTH), noise="off", faults=faults, seed=1,
                        **url_options)
    driver = cls.open(f"sim://{model}?faults={faults}&noise=off{opts}", core.CONTEXT.clock)
    return driver, emu


def assert_truth(reading) -> None:
    assert reading.radiance_W_sr_m2_nm.shape == (401,)
    np.testing.assert_allclose(reading.radiance_W_sr_m2_nm, TRUTH, rtol=6e-5)


def elapsed() -> float:
    return core.CONTEXT.clock.now_s()


models = pytest.mark.parametrize("model", sorted(MODELS))


@models
@pytest.mark.parametrize("which", ["first", "end", "data"])
def test_no_reply_is_retried(model, which):
    n = MODELS[model][1][which]
    d, emu = open_driver(model, f"no-reply@{n}")
    assert_truth(d.measure())
    assert emu.faults.log == [f"no-reply#{n}"]
    assert elapsed() < 120


@models
@pytest.mark.parametrize("delay_s", [3.0, 40.0])
def test_late_reply_is_absorbed_or_retried(model, delay_s):
    n = MODELS[model][1]["data"]
    d, emu = open_driver(model, f"late-reply@{n}:{delay_s}")
    assert_truth(d.measure())
    assert emu.faults.log == [f"late-reply#{n}"]
    assert_truth(d.measure())                  # the stale late reply does not poison the next


@models
def test_garbled_status_reply_is_retried(model):
    d, emu = open_driver(model, "garble@1")     # the remote-mode reply
    assert_truth(d.measure())
    assert emu.commands.count(MODELS[model][1]["remote"].encode()) == 2


@models
def test_garbled_everything_is_a_typed_error_in_bounded_time(model):
    d, _ = open_driver(model, "garble=1.0")
    with pytest.raises(InstrumentError):
        d.measure()
    assert elapsed() < 600


@models
@pytest.mark.parametrize("which", ["first", "data"])
def test_truncated_reply_is_never_a_partial_spectrum(model, which):
    n = MODELS[model][1][which]
    d, emu = open_driver(model, f"truncate@{n}")
    assert_truth(d.measure())
    assert emu.faults.log == [f"truncate#{n}"]


@models
def test_random_truncation_complete_or_typed(model):
    # 15 % of the 21 replies of a CS-1000A measurement cut short: a whole transfer survives
    # about one time in ten, so several measurements are needed for one complete reading
    d, _ = open_driver(model, "truncate=0.15")
    ok = 0
    for _ in range(8):
        try:
            assert_truth(d.measure())
            ok += 1
        except InstrumentError:
            pass
    assert ok >= 1
    assert elapsed() < 8 * 600


@models
def test_device_error_reply_is_typed_with_meaning(model):
    d, _ = open_driver(model, "device-error=1.0:81")
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER81" and e.value.meaning == "shutter malfunction"


@models
def test_busy_is_waited_out(model):
    d, emu = open_driver(model, "busy@3")
    assert_truth(d.measure())
    assert emu.faults.log == ["busy#3"]


@models
def test_persistently_busy_gives_up(model):
    d, _ = open_driver(model, "busy=1.0")
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER02"
    assert elapsed() < 60


@models
def test_over_range_once(model):
    d, _ = open_driver(model, "over-range@1")
    with pytest.raises(DeviceError) as e:
        d.measure()
    assert e.value.code == "ER10"
    assert_truth(d.measure())


@models
@pytest.mark.parametrize("which", ["first", "end", "data"])
def test_disconnect_then_reconnect_reenters_remote_mode(model, which):
    """The link drops for 3 s (the instrument power-blips back to local mode, no data):
    the driver waits, reopens, enters remote mode again and measures again."""
    n = MODELS[model][1][which]
    d, emu = open_driver(model, f"disconnect@{n}:3")
    assert_truth(d.measure())
    assert emu.faults.log == [f"disconnect#{n}"]
    remote = MODELS[model][1]["remote"].encode()
    assert emu.commands.count(remote) == 2
    assert emu.remote


@models
def test_disconnect_for_good_is_a_timeout(model):
    d, _ = open_driver(model, "disconnect@2:100000")
    with pytest.raises(InstrumentTimeout):
        d.measure()
    assert elapsed() < 600


@models
def test_silent_instrument_is_a_timeout(model):
    d, _ = open_driver(model, "no-reply=1.0")
    with pytest.raises(InstrumentTimeout):
        d.measure()
    assert elapsed() < 600


@models
def test_python_api_arms_faults_on_a_live_emulator(model):
    d, emu = open_driver(model)
    assert_truth(d.measure())
    emu.faults.add("busy", probability=1.0)
    with pytest.raises(DeviceError):
        d.measure()
    emu.faults.clear("busy")
    assert_truth(d.measure())


@models
def test_mixed_random_faults_never_return_wrong_length_data(model):
    d, _ = open_driver(model, "no-reply=0.03,truncate=0.03,late-reply=0.05:20,busy=0.05")
    for _ in range(3):
        try:
            assert_truth(d.measure())
        except InstrumentError:
            pass
    assert elapsed() < 3 * 900


@models
def test_recover_after_an_interrupted_measurement(model):
    """The engine's recover() hook: cancel whatever runs and re-enter remote mode."""
    d, emu = open_driver(model)
    d.set_remote(True)
    d.port.write(b"MES,1\n" if model == "cs1000a" else b"MEAS,1\n")   # left running
    d.recover()
    assert emu.phase in ("idle", "measuring")
    assert_truth(d.measure())


@models
def test_faults_from_the_url_alone(model):
    """No emulator prepared: `sim://MODEL?faults=…` creates it with those faults."""
    cls, _ = MODELS[model]
    d = cls.open(f"sim://{model}?faults=no-reply@2,busy@3&noise=off", core.CONTEXT.clock)
    r = d.measure()
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(100.0, rel=1e-3)   # the default spectrum
    assert core.instance(model).faults.log == ["no-reply#2", "busy#3"]


@models
def test_the_lab_assembly_opens_the_driver_on_the_analytic_world(model):
    """As `build_lab` does it: config options (baud, …) through `open`, the world's radiance
    through `sim://`, the ETA from the same timing model as the emulator."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.sim import labsim as labmod

    text = SIM_CONFIG_TEMPLATE.replace('driver = "cs1000a"', f'driver = "{model}"') \
        .replace('port = "sim://cs1000a"', f'port = "sim://{model}?noise=off"')
    if model == "cs2000a":
        text = text.replace("baud = 9600 ", "baud = 115200 ")
    lab = labmod.build_lab(parse_config(text), world="analytic")
    lab.world.place_patch(19)                     # white
    lab.world.set_sample_angle(30.0)
    rad = lab.instrument("radiometer")
    assert type(rad) is MODELS[model][0]
    lv = lab.world.luminance_cd_m2(19, 30.0)
    t0 = lab.clock.now_s()
    r = rad.measure()
    took = lab.clock.now_s() - t0
    _, truth = lab.world.radiance_in_view()
    np.testing.assert_allclose(r.radiance_W_sr_m2_nm, truth, rtol=1e-4, atol=1e-9)
    assert r.colorimetry.Lv_cd_m2 == pytest.approx(lv, rel=0.02)
    assert took == pytest.approx(rad.estimate_measure_time_s(lv), rel=0.1)
    lab.close()
