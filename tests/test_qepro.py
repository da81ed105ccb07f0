"""QE Pro through a seabreeze-shaped simulated device: counts model, corrections, faults."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError
from normbox_lab.drivers.qepro import QEPro
from normbox_lab.sim import core
from normbox_lab.sim import qepro as sim


class FlatWorld:
    def __init__(self, brdf_per_sr: float) -> None:
        self.f = brdf_per_sr

    def brdf_truth(self, theta_i_deg, theta_o_deg, tilt_deg, wavelength_nm):
        return np.full(np.shape(wavelength_nm), self.f)


def open_sim(brdf_per_sr: float = 0.5 / np.pi, query: str = "") -> tuple[QEPro, sim.SimulatedQEProDevice]:
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    dev = sim.device("qepro", clock=clock, world=FlatWorld(brdf_per_sr),
                     light_arm=lambda: 0.0, detector_arm=lambda: 45.0)
    return QEPro.open("sim://qepro" + query, clock), dev


def test_driver_does_not_import_seabreeze_at_module_import():
    code = ("import sys, normbox_lab.drivers.qepro, normbox_lab.drivers.gonio; "
            "sys.exit(1 if 'seabreeze' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_seabreeze_shape_of_the_simulated_device():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    sim.device("qepro", clock=clock)
    spec = sim.SimulatedSpectrometer.from_serial_number("QEP-SIM-0001")
    with pytest.raises(sim.SeaBreezeError):
        sim.SimulatedSpectrometer.from_serial_number("QEP-SIM-0001")     # already open
    assert (spec.model, spec.pixels, spec.max_intensity) == ("QE-PRO", 1044, 262143.0)
    assert spec.integration_time_micros_limits == (8_000, 1_600_000_000)
    wl = spec.wavelengths()
    assert wl.shape == (1044,) and np.all(np.diff(wl) > 0) and wl[0] == 350.0
    with pytest.raises(sim.SeaBreezeError):
        spec.integration_time_micros(7_999)
    spec.f.thermo_electric.set_temperature_setpoint_degrees_celsius(-10.0)
    assert "thermo_electric" in spec.features and spec.f.strobe_lamp is not None
    spec.integration_time_micros(200_000)
    t0 = clock.now_s()
    raw = spec.intensities()
    assert clock.now_s() - t0 == pytest.approx(0.2)                      # blocks for the exposure
    assert raw.max() <= 262143 and np.all(raw == np.round(raw))
    assert raw[:4].mean() == pytest.approx(1500, abs=40)                 # electrically dark pixels
    spec.close()
    with pytest.raises(sim.SeaBreezeError):
        spec.intensities()


def test_counts_scale_with_time_and_radiance_snr_and_nonlinearity():
    q, _dev = open_sim()
    q.wait_tec_stable(tolerance_c=0.05)
    q.set_integration_time_s(0.05)
    a = np.mean([q.acquire(correct_nonlinearity=True).counts for _ in range(20)], axis=0)
    q.set_integration_time_s(0.2)
    b = np.mean([q.acquire(correct_nonlinearity=True).counts for _ in range(20)], axis=0)
    band = slice(300, 700)
    # corrected counts are linear in time (dark current is tiny at −10 °C after settling)
    assert np.median(b[band] / a[band]) == pytest.approx(4.0, rel=2e-3)
    raw_a = np.mean([q.acquire(correct_nonlinearity=False).counts for _ in range(5)], axis=0)
    q.set_integration_time_s(0.05)
    raw_b = np.mean([q.acquire(correct_nonlinearity=False).counts for _ in range(5)], axis=0)
    # uncorrected: the brighter spectrum reads low by 0.5 % × fraction of full scale
    frac = b[band] / 262143
    expected = 4.0 * (1 - 0.005 * frac) / (1 - 0.005 * frac / 4)
    assert np.median(raw_a[band] / raw_b[band] / expected) == pytest.approx(1.0, abs=1.5e-3)
    # SNR ≈ 1000:1 near full scale
    q.set_integration_time_s(0.25)
    shots = np.array([q.acquire().counts for _ in range(30)])
    i = int(np.argmax(shots.mean(axis=0)))
    assert shots[:, i].mean() > 0.6 * 262143
    snr = shots[:, i].mean() / shots[:, i].std()
    assert 600 < snr < 1300


def test_saturation_is_flagged_and_typed():
    q, _dev = open_sim(brdf_per_sr=1.0 / np.pi)
    q.set_integration_time_s(2.0)
    acq = q.acquire()
    assert acq.saturated and acq.raw_counts.max() == 262143
    with pytest.raises(DeviceError) as err:
        q.intensities_counts()
    assert err.value.code == "SATURATED"
    with pytest.raises(DeviceError):
        q.set_integration_time_s(0.001)                                  # below 8 ms


def test_tec_settles_towards_the_set_point():
    q, _dev = open_sim()
    assert q.tec_temperature_c() == pytest.approx(25.0, abs=0.01)        # just powered up
    q.clock.sleep(30.0)
    assert q.tec_temperature_c() == pytest.approx(-10 + 35 * np.exp(-1), abs=0.01)
    t = q.wait_tec_stable(tolerance_c=0.5, poll_s=5.0)
    assert abs(t + 10) <= 0.5
    q.set_tec_setpoint_c(-15.0)
    assert q.tec_temperature_c() == pytest.approx(t, abs=0.01)


def test_dark_current_grows_with_temperature():
    q, dev = open_sim()
    dev.lamp_on = False
    q.set_integration_time_s(10.0)
    warm = np.median(q.acquire(correct_nonlinearity=False).counts[10:1000])
    q.clock.sleep(600.0)
    cold = np.median(q.acquire(correct_nonlinearity=False).counts[10:1000])
    ts = (np.arange(10000) + 0.5) / 1000.0                                # 0…10 s
    expected_warm = np.sum(200 * 2 ** ((-10 + 35 * np.exp(-ts / 30) + 10) / 6)) / 1000.0
    assert warm == pytest.approx(expected_warm, rel=0.01)                 # ∫ rate(T(t)) dt
    assert cold == pytest.approx(200 * 10, rel=0.05)


def test_lamp_enable_line_darkens_the_spectrum():
    q, _dev = open_sim()
    on = q.acquire().counts
    q.set_lamp_enabled(False)
    off = q.acquire().counts
    assert on.max() > 50_000 and off.max() < 0.03 * on.max()          # dark current only


def test_usb_drop_reconnects_and_retries():
    q, dev = open_sim(query="")
    q.acquire()
    dev.faults.add("disconnect", at_count=dev.faults._counters.get("disconnect", 0) + 1,
                   parameter=3.0)
    t0 = q.clock.now_s()
    acq = q.acquire()                                                    # drops, comes back
    assert q.clock.now_s() - t0 >= 3.0 and acq.counts.max() > 1000
    dev.faults.add("disconnect", at_count=dev.faults._counters["disconnect"] + 1,
                   parameter=60.0)
    with pytest.raises(InstrumentError):
        q.acquire()                                                      # gone for good: typed


def test_real_open_reports_missing_device_typed():
    with pytest.raises(InstrumentError):
        QEPro.open("usb:NO-SUCH-QEPRO", VirtualClock())
