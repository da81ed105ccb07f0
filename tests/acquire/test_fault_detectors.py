"""Faults real instruments show, each modelled in its emulator and caught by its detector,
and the fault registry every emulator declares.

Radiometers (CS-1000A, CS-2000A, specbos 1211 through `RadiometerOptics.observe(faults)`):
``stale-data`` (a data block repeating the previous measurement) → quality gate
``identical-spectrum``; ``lost-digit`` (one band loses its leading digit in every transfer) and
``zero-block`` (adjacent bands read 0) → the driver's plausibility (a 1 nm step a 5 nm bandwidth
cannot make) → `ImplausibleData`; ``negative`` (a dark over-subtracted) → quality gate
``radiance-negative``.  QE Pro: ``dead-pixel`` → `DeviceError("PIXEL")`, ``overflow`` (a count
beyond 18 bits) → `ProtocolError`, a plateau → `DeviceError("PLATEAU")`.  Undetectable
without more hardware, modelled and bounded in docs/fault-behaviour.md: the sphere's
``monitor-stuck`` and a Zaber stage's ``slip``.
"""

from __future__ import annotations

import random

import numpy as np
import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, ImplausibleData, ProtocolError
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.drivers.cs1000 import CS1000A
from normbox_lab.drivers.cs2000 import CS2000A
from normbox_lab.sim import core

WL = RADIOMETER_WAVELENGTHS_NM
TRUTH = 2e-3 * (1.0 + np.sin(WL / 37.0) ** 2)       # ~ 200 cd/m², smooth
DRIVERS = {"cs1000a": CS1000A, "cs2000a": CS2000A}
models = pytest.mark.parametrize("model", sorted(DRIVERS))


@pytest.fixture(autouse=True)
def fresh_sim():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


def open_driver(model: str, faults: str, noise: str = "on"):
    emu = core.instance(model, scene=lambda: (WL, TRUTH), noise=noise, faults=faults, seed=3)
    return DRIVERS[model].open(f"sim://{model}?faults={faults}&noise={noise}",
                               core.CONTEXT.clock), emu


# --- the registry ----------------------------------------------------------------------------

def test_every_emulator_declares_every_fault_it_injects_with_a_range():
    table = core.fault_table()
    assert {"cs1000a", "cs2000a", "specbos1211", "rotator-apt", "rotator-zaber", "sphere",
            "qepro"} <= set(table)
    for kinds in table.values():
        for name, k in kinds.items():
            assert k.kind == name and k.mode in ("=", "@") and k.means and k.detector, k
            lo, hi = k.value_range
            assert 0 < lo < hi, k
            if k.mode == "=":
                assert hi == 1.0, k                  # a rate runs up to every opportunity
            if k.param_range is not None and k.param_scale in ("log", "log-int"):
                assert k.param_range[0] > 0, k
    # the emulators' own lists of names are the registry's
    for name in core.EMULATORS:
        cls = core.emulator_class(name)
        if cls is not None:
            assert set(cls.device_faults) <= set(table[name])


def test_draws_cover_the_whole_range_both_ends_and_decades():
    k = core.fault_table("qepro")["qepro"]["dark-drift"]            # 1 … 1e5 counts/s, log
    rng = random.Random(5)
    params = [k.draw_param(rng) for _ in range(2000)]
    assert min(params) == 1.0 and max(params) == 1e5
    decades = {int(np.floor(np.log10(p))) for p in params if 1 < p < 1e5}
    assert decades == {0, 1, 2, 3, 4}                              # every decade drawn
    rates = [core.TRANSPORT_FAULT_KINDS[0].draw_value(rng) for _ in range(2000)]
    assert min(rates) == 1e-3 and max(rates) == 1.0
    assert sum(r < 0.01 for r in rates) > 200                      # log-uniform, not uniform


def test_the_campaign_draws_every_declared_kind_from_the_registry():
    from normbox_lab.campaign.scenario import draw, fault_kinds

    drawn = {(f.role, f.kind) for i in range(1500) for f in draw(9, i).faults}
    kinds = {k for _, k in drawn}
    for device in ("cs1000a", "qepro", "sphere", "rotator-zaber"):
        assert set(fault_kinds(device)) <= kinds, set(fault_kinds(device)) - kinds
    assert "monitor-stuck" not in kinds and "slip" in kinds     # undetectable: not drawn


@pytest.mark.parametrize("spec", ["garble@-1", "garble@0", "disconnect@2:-5",
                                  "lamp-drift@1:500", "saturation@1:2", "no-reply=1.5",
                                  "busy@x", "device-error@1:nan"])
def test_a_fault_outside_its_declared_range_is_refused(spec):
    device = {"lamp-drift": "sphere", "saturation": "qepro"}.get(spec.split("@")[0], "cs1000a")
    with pytest.raises(ValueError):
        core.FaultInjector(spec, 0, core.fault_table(device)[device])


# --- radiometers -----------------------------------------------------------------------------

@models
def test_a_lost_leading_digit_on_one_band_is_implausible_never_a_reading(model):
    d, _ = open_driver(model, "lost-digit@1:600")
    with pytest.raises(ImplausibleData, match="600 nm"):
        d.measure()


@models
@pytest.mark.parametrize("width", [1, 7, 200])
def test_a_block_of_zero_bands_is_implausible(model, width):
    d, _ = open_driver(model, f"zero-block@1:{width}")
    with pytest.raises(ImplausibleData, match="implausible data: band"):
        d.measure()


def test_the_plausibility_check_passes_every_clean_spectrum_of_the_worlds():
    from normbox_lab.drivers.radiometer_common import _relative_step
    from normbox_lab.sim.analytic_world import AnalyticWorld

    w = AnalyticWorld()
    for patch in range(1, 25):
        for angle in (30.0, 60.0, 90.0):
            spectrum = np.interp(WL, w.wavelength_nm, w.radiance_at(patch, angle))
            assert _relative_step(spectrum) == "", (patch, angle)
    spectrum[123] = 0.4 * spectrum[123]
    assert "503 nm" in _relative_step(spectrum)


def _gates(tmp_path, readings):
    from normbox_lab.acquire.quality import RunGates
    from normbox_lab.acquire.store import Store

    store = Store(tmp_path / "s.sqlite")
    run = store.create_run("repeatability", planned=len(readings))
    gates = RunGates(store, run.id)
    found = []
    for key, radiance in readings:
        arrays = {"wavelength_nm": WL, "radiance_W_sr_m2_nm": radiance}
        store.add_reading(run.id, key, "spectral", arrays)
        found += gates.reading(key, "spectral", {}, arrays)
    return store, run, found


@models
def test_a_repeated_data_block_is_an_error_flag(tmp_path, model):
    d, _ = open_driver(model, "stale-data@3")
    spectra = [d.measure().radiance_W_sr_m2_nm for _ in range(4)]
    assert np.array_equal(spectra[2], spectra[1])                 # the block came again
    assert not np.array_equal(spectra[1], spectra[0])             # noise: never equal
    store, run, found = _gates(tmp_path, [(f"r{i}", s) for i, s in enumerate(spectra)])
    assert [(f.key, f.gate, f.severity) for f in found] == [("r2", "identical-spectrum",
                                                             "error")]
    # a resumed segment's gates know the readings stored before it
    from normbox_lab.acquire.quality import RunGates

    again = RunGates(store, run.id).reading("r9", "spectral", {},
                                            {"radiance_W_sr_m2_nm": spectra[0]})
    assert [f.gate for f in again] == ["identical-spectrum"] and "r0" in again[0].message


@models
def test_small_negative_values_are_refused_or_flagged(tmp_path, model):
    """A dark over-subtracted below 5 % of the peak: the bands under it read negative.  The
    step where it starts is no 5 nm spectrum (the driver refuses it); values that reach the
    store negative anyway are an error flag."""
    from normbox_lab.acquire.quality import QualityLimits, spectral_flags

    dim_blue = TRUTH * np.exp((WL - 780.0) / 80.0)             # 0.7 % of the peak at 380 nm
    core.instance(model, scene=lambda: (WL, dim_blue), noise="on", faults="negative@1:0.05",
                  seed=3)
    d = DRIVERS[model].open(f"sim://{model}?faults=negative@1:0.05", core.CONTEXT.clock)
    with pytest.raises(ImplausibleData, match="implausible data: band"):
        d.measure()
    limits = QualityLimits()
    flags = spectral_flags("k", {}, {"radiance_W_sr_m2_nm": dim_blue - 1e-4}, limits)
    assert [(f.gate, f.severity) for f in flags] == [("radiance-negative", "error")]
    assert spectral_flags("k", {}, {"radiance_W_sr_m2_nm": dim_blue}, limits) == []


# --- QE Pro ----------------------------------------------------------------------------------

def _qepro(faults: str):
    from worlds import FlatWorld

    from normbox_lab.drivers.qepro import QEPro
    from normbox_lab.sim import qepro as simq
    from normbox_lab.sim.transport import register_url_scheme

    register_url_scheme()
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    simq.device("qepro", clock=clock, world=FlatWorld(0.5 / np.pi), faults=faults,
                light_arm=lambda: 0.0, detector_arm=lambda: 45.0)
    return QEPro.open("sim://qepro", clock)


def test_qepro_dead_pixel_is_a_typed_error_in_a_lit_frame():
    q = _qepro("dead-pixel@2:600")
    assert np.all(np.isfinite(q.acquire().counts))                # before it: data
    with pytest.raises(DeviceError) as err:
        q.acquire()
    assert err.value.code == "PIXEL" and "pixel 600" in str(err.value)


def test_qepro_count_beyond_18_bits_is_a_protocol_error():
    q = _qepro("overflow@1:1e6")
    with pytest.raises(ProtocolError, match="full scale"):
        q.acquire()


def test_qepro_hot_pixel_is_subtracted_with_the_dark_or_saturates():
    q = _qepro("hot-pixel@1:2e5")                                # 2e4 counts in 100 ms
    lit = q.acquire()
    q.set_lamp_enabled(False)
    dark = q.acquire()
    assert dark.raw_counts[650] - dark.raw_counts[649] > 15000    # hot in the dark too
    signal = lit.counts - dark.counts
    assert abs(signal[650] - 0.5 * (signal[649] + signal[651])) < 0.02 * signal[650]
    q2 = _qepro("hot-pixel@1:1e8")                               # fills the pixel
    acq = q2.acquire()
    assert acq.saturated and acq.raw_counts[650] == 262143
    with pytest.raises(DeviceError) as err:
        q2.intensities_counts()
    assert err.value.code == "SATURATED"


@pytest.mark.parametrize("level", [0.02, 0.05, 0.5, 0.9])
def test_qepro_plateau_below_full_scale_is_a_typed_error(level):
    """A light leak holding pixels 500-519 at `level` × full scale: seen in every frame where
    it lies above the light (the dark frames always: the gonio takes one with every reading
    and two around the white reference)."""
    q = _qepro(f"saturation@1:{level}")
    q.set_lamp_enabled(False)                                    # a dark frame
    with pytest.raises(DeviceError) as err:
        q.acquire()
    assert err.value.code == "PLATEAU" and "500" in str(err.value)


# --- undetectable without more hardware: modelled, bounded -------------------------------------

def test_a_stuck_monitor_hides_a_drifting_lamp():
    from normbox_lab.drivers.sphere import SphereLightSource

    sphere = core.instance("sphere", faults="monitor-stuck@1:-60", seed=2)
    driver = SphereLightSource.open("sim://sphere", core.CONTEXT.clock)
    driver.set_output(True)
    core.CONTEXT.clock.sleep(1800.0)
    before = driver.luminance_cd_m2()
    core.CONTEXT.clock.sleep(600.0)                               # 10 min at −60 %/h
    assert driver.luminance_cd_m2() == before                    # the monitor sees nothing
    assert sphere.relative_output() < 0.92                       # the light fell ~10 %


@pytest.mark.parametrize("model", ["rotator-zaber", "rotator-apt"])
@pytest.mark.parametrize("slip_deg", [2.0, 0.3])
def test_a_stage_that_loses_steps_is_seen_by_its_readback(model, slip_deg):
    """2° short: the move fails (POSITION); 0.3° short: the reading keeps setpoint and
    readback, and the position gate flags it."""
    from normbox_lab.drivers.rotator_apt import AptRotationStage
    from normbox_lab.drivers.rotator_zaber import ZaberRotationStage

    cls = ZaberRotationStage if model == "rotator-zaber" else AptRotationStage
    emu = core.instance(model, faults=f"slip@1:{slip_deg}", seed=1)
    stage = cls.open(f"sim://{model}", core.CONTEXT.clock)
    stage.home()
    if slip_deg > stage.stall_limit_deg:
        with pytest.raises(DeviceError) as err:
            stage.move_to(60.0)
        assert err.value.code == "POSITION"
    else:
        stage.move_to(60.0)
        loc = stage.locate()
        assert loc.setpoint == 60.0 and abs(loc.readback - (60.0 - slip_deg)) < 0.01
        assert abs(loc.readback - loc.setpoint) > loc.tolerance
    assert abs(emu.angle_deg() - (60.0 - slip_deg)) < 0.01        # where the sample stands


# --- the command line derives from the registry ------------------------------------------------

def test_sim_faults_lists_the_registry_and_serve_refuses_outside_it(capsys):
    from normbox_lab.cli import main

    assert main(["sim", "faults", "sphere"]) == 0
    out = capsys.readouterr().out
    for kind in core.fault_table("sphere")["sphere"]:
        assert f"`{kind}`" in out
    assert "-100 … 100 %/h" in out and "not drawn (undetectable)" in out
    assert main(["sim", "serve", "sphere", "--pty", "--faults", "lamp-drift@1:500"]) == 2
    err = capsys.readouterr().err
    assert "-100 … 100" in err and err.count("\n") == 1
    assert main(["sim", "serve", "cs1000a", "--pty", "--faults", "melt=0.1"]) == 2
    err = capsys.readouterr().err
    assert "stale-data" in err and "lost-digit" in err          # the known kinds, listed


def test_a_dark_current_far_above_the_detectors_own_is_an_error_flag():
    """dark-drift@n:1e5 (s3700-903): the readings stay unbiased, but a dark 500× the QE Pro's
    own makes the blue's noise ±50 %, not the stated SNR: an error flag, not a quiet value."""
    from normbox_lab.acquire.quality import QualityLimits, brdf_flags

    arrays = {"brdf_per_sr": np.full(401, 0.1)}
    hot = brdf_flags("k", {"dark_rate_counts_s": 1.0e5}, arrays, QualityLimits())
    assert [(f.gate, f.severity, f.limit) for f in hot] == [("dark-current", "error", 2000.0)]
    assert brdf_flags("k", {"dark_rate_counts_s": 210.0}, arrays, QualityLimits()) == []
