"""Gonioreflectometer: geometry set, calibration closure (known BRDF in → same BRDF out), faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady
from normbox_lab.drivers.gonio import Gonioreflectometer, OperatorWhiteStandard
from normbox_lab.drivers.qepro import QEPro
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.sim import core
from normbox_lab.sim import qepro as sim_qepro

LOBE_WIDTH_DEG = 12.0


class LobeWorld:
    """Lambertian 0.5/π with a spectral tint plus a specular lobe around θo = −θi."""

    def __init__(self, lobe: float = 0.8) -> None:
        self.lobe = lobe

    def brdf_truth(self, theta_i_deg, theta_o_deg, tilt_deg, wavelength_nm):
        wl = np.asarray(wavelength_nm, dtype=float)
        diffuse = 0.5 / math.pi * (0.6 + 0.4 * (wl - 350.0) / 550.0)
        lobe = self.lobe * math.exp(-((theta_o_deg + theta_i_deg) / LOBE_WIDTH_DEG) ** 2)
        return diffuse + lobe


def lamp(wl):
    """A known lamp: a smooth 'LED + phosphor' spectral irradiance, W·m⁻²·nm⁻¹."""
    wl = np.asarray(wl, dtype=float)
    return 0.3 * np.exp(-((wl - 450) / 20) ** 2) + 0.8 * np.exp(-((wl - 600) / 90) ** 2) + 0.05


def build(world=None, faults: str = "") -> tuple[Gonioreflectometer, sim_qepro.SimulatedQEProDevice]:
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    light = ZaberRotationStage.open("sim://rotator-zaber?key=gonio-light", clock,
                                    min_angle_deg=-90, max_angle_deg=90, instrument_id="light")
    det = ZaberRotationStage.open("sim://rotator-zaber?key=gonio-detector", clock,
                                  min_angle_deg=-90, max_angle_deg=90, instrument_id="detector")
    dev = sim_qepro.device("qepro", clock=clock, world=world or LobeWorld(), lamp=lamp,
                           faults=faults)
    spec = QEPro.open("sim://qepro", clock)
    spec.wait_tec_stable()
    return Gonioreflectometer.from_parts(spectrometer=spec, light_arm=light, detector_arm=det,
                                         clock=clock), dev


def test_geometry_set_153_with_blocked_flagged():
    gonio, _ = build()
    geos = gonio.geometries()
    assert len(geos) == 153
    assert [g[:2] for g in geos[:2]] == [(-80.0, -80.0), (-80.0, -70.0)]
    blocked = [(ti, to) for ti, to, b in geos if b]
    assert blocked == [(t, t) for t in range(-80, 1, 10)]                # backscatter: arms meet


def test_measure_before_calibration_is_not_ready():
    gonio, _ = build()
    with pytest.raises(NotReady):
        gonio.measure_brdf(-30, 30)


def test_calibration_closure_known_brdf_in_same_brdf_out():
    world = LobeWorld()
    gonio, _dev = build(world)
    refs = gonio.calibrate()
    assert {"white_counts", "dark_counts", "white_reflectance", "wavelength_nm"} <= set(refs)
    peak = refs["white_counts"].max() / 262143
    assert 0.5 < peak < 0.7                                             # ≈ 60 % of full scale
    band = (gonio.output_wavelength_nm >= 420) & (gonio.output_wavelength_nm <= 720)
    for ti, to in [(-30, 30), (-60, 60), (-80, 40), (0, 20), (-40, -10), (-80, 80), (-10, 0),
                   (-50, 70)]:
        r = gonio.measure_brdf(ti, to)
        truth = world.brdf_truth(ti, to, 4.0, r.wavelength_nm)
        rel = r.brdf_per_sr[band] / truth[band] - 1
        assert abs(np.median(rel)) < 0.003, (ti, to, np.median(rel))    # no bias
        assert np.std(rel) < 0.02, (ti, to, np.std(rel))                # noise ≈ 1000:1 per pixel
        assert r.wavelength_nm[0] == 380 and r.wavelength_nm[-1] == 780 and r.wavelength_nm.size == 401
        assert r.raw_counts is not None and r.raw_counts.size == 1044
        assert not r.blocked and r.tilt_deg == 4.0
    # the arms really went there
    assert core.CONTEXT.instances["gonio-light"].angle_deg() == pytest.approx(-50, abs=1e-3)
    assert core.CONTEXT.instances["gonio-detector"].angle_deg() == pytest.approx(70, abs=1e-3)


def test_specular_peak_auto_ranges_instead_of_saturating():
    gonio, _dev = build(LobeWorld(lobe=5.0))
    gonio.calibrate()
    r = gonio.measure_brdf(-30, 30)
    assert r.integration_time_s < gonio.references()["integration_time_s"][0] / 4
    truth = LobeWorld(5.0).brdf_truth(-30, 30, 4.0, r.wavelength_nm)
    assert np.median(r.brdf_per_sr / truth) == pytest.approx(1.0, abs=0.005)


def test_too_bright_even_at_8_ms_is_a_saturation_error():
    gonio, _dev = build(LobeWorld(lobe=30.0))
    gonio.calibrate()
    with pytest.raises(DeviceError) as err:
        gonio.measure_brdf(-30, 30)
    assert err.value.code == "SATURATED"


def test_blocked_geometry_is_measured_and_flagged():
    gonio, _dev = build()
    gonio.calibrate()
    r = gonio.measure_brdf(-40, -40)
    assert r.blocked
    assert np.max(np.abs(r.brdf_per_sr)) < 0.01                          # arm shadow: no signal


def test_operator_white_standard_prompts_and_missing_handler():
    clock = VirtualClock()
    asked = []
    std = OperatorWhiteStandard(asked.append, reflectance=np.array([0.98, 0.99]),
                                wavelength_nm=np.array([300.0, 1000.0]))
    std.insert()
    std.remove()
    assert len(asked) == 2 and "white standard" in asked[0]
    assert std.reflectance(np.array([650.0]))[0] == pytest.approx(0.985)

    class RealLikeSpec:
        def white_standard(self):
            return None
    g = Gonioreflectometer(None, None, RealLikeSpec(), clock)
    with pytest.raises(NotReady):
        g.calibrate()


def test_spectrometer_drop_during_a_sweep_recovers():
    gonio, dev = build()
    gonio.calibrate()
    dev.faults.add("disconnect", at_count=dev.faults._counters.get("disconnect", 0) + 3,
                   parameter=2.0)
    r = gonio.measure_brdf(-20, 40)
    assert np.isfinite(r.brdf_per_sr).all()
    dev.faults.add("disconnect", at_count=dev.faults._counters["disconnect"] + 1,
                   parameter=600.0)
    with pytest.raises(InstrumentError):
        gonio.measure_brdf(-20, 50)


def test_lamp_dimming_after_the_white_reference_is_caught_and_re_referenced():
    """``faults=lamp-dim@5:0.5``: the lamp halves from the 5th spectrum on, after the white
    reference.  Every reading is bracketed by a lamp check at its own geometry: the dimmed
    lamp is seen (lamp ratio 0.5), the references are taken again and the reading repeated,
    so every stored BRDF still agrees with the truth; none is stored at 0.5x."""
    world = LobeWorld()
    gonio, dev = build(world, faults="lamp-dim@5:0.5")
    gonio.calibrate()
    band = (gonio.output_wavelength_nm >= 420) & (gonio.output_wavelength_nm <= 720)
    ratios = []
    for ti, to in [(-30, 30), (-60, 60), (-80, 40), (0, 20), (-40, -10), (-50, 70)]:
        r = gonio.measure_brdf(ti, to)
        truth = world.brdf_truth(ti, to, 4.0, r.wavelength_nm)
        assert abs(np.median(r.brdf_per_sr[band] / truth[band]) - 1) < 0.005, (ti, to)
        ratios.append(r.metadata["lamp_ratio"])
        assert abs(r.metadata["lamp_ratio"] - 1) <= 0.02
    assert dev.conditions == {"lamp-dim": 0.5} and gonio.recalibrations == 1
    assert r.metadata["recalibrations"] == 1 and r.metadata["lamp_drift_limit_percent"] == 2.0


def test_a_lamp_still_drifting_after_re_referencing_is_flagged_as_an_error():
    from normbox_lab.acquire.quality import QualityLimits, brdf_flags

    gonio, dev = build()
    gonio.calibrate()
    level = {"x": 1.0}
    base = dev.lamp_irradiance

    def fading(wl):
        level["x"] *= 0.97                                   # 3 % dimmer at every spectrum
        return base(wl) * level["x"]

    dev.lamp_irradiance = fading
    r = gonio.measure_brdf(-30, 30)
    assert gonio.recalibrations == 1 and r.metadata["lamp_ratio"] < 0.98
    flags = brdf_flags("k", {**r.metadata, "blocked": r.blocked},
                       {"brdf_per_sr": r.brdf_per_sr}, QualityLimits())
    lamp = [f for f in flags if f.gate == "lamp-drift"]
    assert len(lamp) == 1 and lamp[0].severity == "error" and lamp[0].limit == 2.0
    ok = brdf_flags("k", {"lamp_ratio": 0.99, "lamp_drift_limit_percent": 2.0},
                    {"brdf_per_sr": r.brdf_per_sr}, QualityLimits())
    assert not [f for f in ok if f.gate == "lamp-drift"]


def test_operator_placed_white_has_no_per_reading_lamp_check():
    gonio, _dev = build()
    gonio.calibrate()
    gonio.white_standard = OperatorWhiteStandard(lambda message: None)
    assert "lamp_ratio" not in gonio.measure_brdf(-30, 30).metadata


def test_arm_stall_is_a_typed_error():
    gonio, _dev = build()
    gonio.calibrate()
    arm = core.CONTEXT.instances["gonio-detector"]
    arm.faults.add("stall", at_count=arm.faults._counters.get("stall", 0) + 1, parameter=0.5)
    with pytest.raises(DeviceError):
        gonio.measure_brdf(-20, -70)


def test_eta_matches_the_clock():
    gonio, _dev = build()
    gonio.calibrate()
    gonio.measure_brdf(-80, -60)
    est = gonio.estimate_measure_time_s(-10, 60)
    t0 = gonio.clock.now_s()
    gonio.measure_brdf(-10, 60)
    took = gonio.clock.now_s() - t0
    assert est <= took <= est + 0.5                                     # + status polls


def test_full_153_sweep_closes_everywhere():
    world = LobeWorld()
    gonio, _ = build(world)
    gonio.calibrate()
    band = slice(40, 341)                                                # 420–720 nm
    worst = 0.0
    for ti, to, blocked in gonio.geometries():
        r = gonio.measure_brdf(ti, to)
        assert r.blocked == blocked
        if not blocked:
            truth = world.brdf_truth(ti, to, 4.0, r.wavelength_nm)
            worst = max(worst, abs(float(np.median(r.brdf_per_sr[band] / truth[band] - 1))))
    assert worst < 0.003


def test_stop_halts_both_arms():
    gonio, _ = build()
    for arm in (gonio.light_arm, gonio.detector_arm):
        arm.home()
    gonio.light_arm.move_to(-80.0, wait=False)
    gonio.detector_arm.move_to(80.0, wait=False)
    gonio.clock.sleep(1.0)
    assert gonio.is_moving()
    gonio.stop()
    assert not gonio.is_moving()
    assert -80 < core.CONTEXT.instances["gonio-light"].angle_deg() < 0


def test_roles():
    from normbox_lab.core.capabilities import Gonioreflectometer as GonioRole
    from normbox_lab.core.capabilities import RotationStage, Spectrometer

    gonio, _ = build()
    assert isinstance(gonio, GonioRole)
    assert isinstance(gonio.spectrometer, Spectrometer)
    assert isinstance(gonio.light_arm, RotationStage)
