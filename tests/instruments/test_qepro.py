"""QE Pro on the emulated USB bus: python-seabreeze (pyseabreeze) drives it unmodified; the
driver's seabreeze path against it: counts model, corrections, OBP gaps filled, faults."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from worlds import FlatWorld

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError
from normbox_lab.drivers.qepro import QEPro
from normbox_lab.sim import core
from normbox_lab.sim import qepro as sim


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


def test_seabreeze_lists_opens_and_reads_the_emulated_qepro():
    """seabreeze's own Spectrometer API is the client: list, open, read, close."""
    from normbox_lab.sim.usb import emulated_usb

    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)          # a simulated lab's QE Pro leaves the bus with it
    with emulated_usb("qepro", seed=3, clock=clock, world=FlatWorld(0.5 / np.pi),
                      light_arm=lambda: 0.0, detector_arm=lambda: 45.0,
                      serial_number="QEP-USB-0042") as backend:
        import warnings

        import seabreeze

        with warnings.catch_warnings():      # other tests in this process opened one before
            warnings.simplefilter("ignore")
            # network_adapter="none": pyseabreeze skips its multicast discovery of network
            # spectrometers (nothing leaves the machine), as the driver does
            seabreeze.use("pyseabreeze", pyusb_backend=backend, network_adapter="none")
        from seabreeze.spectrometers import SeaBreezeError, Spectrometer, list_devices

        devices = list_devices()
        assert [(d.model, d.serial_number) for d in devices] == [("QEPRO", "QEP-USB-0042")]
        spec = Spectrometer.from_serial_number("QEP-USB-0042")
        with pytest.raises(SeaBreezeError):
            Spectrometer.from_serial_number("QEP-USB-0042")                 # already open
        assert (spec.pixels, spec.max_intensity) == (1044, 262143.0)
        assert spec.integration_time_micros_limits == (8_000, 1_600_000_000)
        wl = spec.wavelengths()                  # from the OBP coefficients 0x00180100/0101
        c0, c1, c2 = sim.WAVELENGTH_COEFFS
        px = np.arange(1044)
        assert np.allclose(wl, np.float32(c0) + np.float32(c1) * px + np.float32(c2) * px ** 2)
        spec.integration_time_micros(200_000)
        assert backend.device.integration_time_us == 200_000
        t0 = clock.now_s()
        raw = spec.intensities()
        assert clock.now_s() - t0 == pytest.approx(0.2)      # the exposure, on the device clock
        assert raw.shape == (1044,) and raw.max() <= 262143 and np.all(raw == np.round(raw))
        assert raw[:4].mean() == pytest.approx(1500, abs=40)             # electrically dark
        assert raw[300:700].mean() > 20 * 1500                           # the lit white-ish
        dark_corrected = spec.intensities(correct_dark_counts=True)
        assert np.median(dark_corrected[:4]) == pytest.approx(0, abs=40)
        with pytest.raises(SeaBreezeError):
            spec.intensities(correct_nonlinearity=True)   # pyseabreeze: no such QEPRO feature
        spec.close()
    assert list_devices() == []                                          # unplugged


def test_obp_frames_on_the_wire():
    """Exact frames: serial number length, a set command with ACK, a refused checksum, an
    unknown message type, and the buffered spectrum's size."""
    dev = sim.SimulatedQEProDevice(VirtualClock(), serial_number="QEP01234")
    fn = sim.QEProUsb(dev)
    fn.bulk_out(sim.EP_OUT, sim.obp_frame(0x00000101))
    reply = fn.bulk_in(sim.EP_IN, 4096)
    assert len(reply) == 64 and reply[:2] == b"\xc1\xc0" and reply[4:6] == b"\x01\x00"
    assert reply[22:25] == b"\x00\x01\x08"            # no checksum, 1 immediate byte: 8
    assert reply[-4:] == b"\xc5\xc4\xc3\xc2"
    fn.bulk_out(sim.EP_OUT, sim.obp_frame(0x00110010, (50_000).to_bytes(4, "little"),
                                          flags=sim.FLAG_REQUEST_ACK))
    ack = fn.bulk_in(sim.EP_IN, 4096)
    assert ack[4:6] == b"\x03\x00" and dev.integration_time_us == 50_000         # ACK
    fn.bulk_out(sim.EP_OUT, sim.obp_frame(0x00110010, (10).to_bytes(4, "little"),
                                          flags=sim.FLAG_REQUEST_ACK))
    nack = fn.bulk_in(sim.EP_IN, 4096)
    assert nack[4:8] == b"\x09\x00\x06\x00" and dev.integration_time_us == 50_000  # NACK 6
    good = sim.obp_frame(0x00000100, checksum_type=sim.CHECKSUM_MD5)
    fn.bulk_out(sim.EP_OUT, good)
    assert fn.bulk_in(sim.EP_IN, 4096)[22:32] == b"\x01\x08QEP01234"    # MD5 reply
    bad = good[:-20] + bytes(16) + good[-4:]
    fn.bulk_out(sim.EP_OUT, bad)
    assert fn.bulk_in(sim.EP_IN, 4096)[4:8] == b"\x09\x00\x03\x00"      # bad checksum
    fn.bulk_out(sim.EP_OUT, sim.obp_frame(0x00DEAD00))         # unknown, no ACK asked: silent
    assert fn.bulk_in(sim.EP_IN, 4096) == b""
    fn.bulk_out(sim.EP_OUT, b"\x00\x17" + sim.obp_frame(0x00DEAD00, flags=sim.FLAG_REQUEST_ACK))
    assert fn.bulk_in(sim.EP_IN, 4096)[4:8] == b"\x09\x00\x02\x00"      # junk skipped; NACK 2
    fn.bulk_out(sim.EP_OUT, sim.obp_frame(0x00100928))
    spectrum = fn.bulk_in(sim.EP_IN, 1 << 16)
    assert len(spectrum) == 44 + 32 + 1044 * 4 + 20
    assert int.from_bytes(spectrum[76:80], "little") == pytest.approx(1500, abs=100)
    assert fn.bulk_in(sim.EP_IN, 4096) == b""


def test_driver_runs_the_seabreeze_path_and_fills_the_pyseabreeze_gaps():
    q, dev = open_sim()
    assert type(q.spec).__module__ == "seabreeze.spectrometers"             # the real thing
    assert not q._native()["thermo_electric"] and q.has_tec and q.has_nonlinearity
    q.set_tec_setpoint_c(-12.0)
    assert dev._tec_setpoint_c == pytest.approx(-12.0)                     # over raw OBP
    q.set_lamp_enabled(False)
    assert dev.lamp_on is False
    q.set_lamp_enabled(True)
    assert q.status()["nonlinearity_correction"] is True


def test_noise_off_option_gives_noise_free_counts():
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    q = QEPro.open("sim://qepro?noise=off", clock)              # no arms: the dark alone
    clock.sleep(900.0)                                           # the TEC has settled
    a, b = q.acquire(correct_nonlinearity=False), q.acquire(correct_nonlinearity=False)
    assert np.array_equal(a.raw_counts, b.raw_counts) and a.raw_counts[:4].tolist() == [1500] * 4


def test_bad_fault_spec_and_unknown_option_are_instrument_errors():
    for url in ("sim://qepro?faults=disconnect@x", "sim://qepro?faults=meltdown",
                "sim://qepro?colour=blue", "sim://qepro?slide=sideways",
                "sim://qepro?noise=maybe"):
        core.CONTEXT.reset(clock=VirtualClock())
        with pytest.raises(InstrumentError):
            QEPro.open(url, core.CONTEXT.clock)


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


def test_disconnect_longer_than_the_reconnect_window_is_typed():
    """``faults=disconnect@3:30``: the third spectrum request drops the device for 30 s, the
    reconnect window is 10 s → InstrumentError (never a raw seabreeze or pyusb exception) at
    every operation while it is away; back after 30 s."""
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    sim.device("qepro", clock=clock, world=FlatWorld(0.5 / np.pi), light_arm=lambda: 0.0,
               detector_arm=lambda: 45.0, faults="disconnect@3:30", seed=7)
    q = QEPro.open("sim://qepro", clock)
    q.acquire()
    q.acquire()
    t0 = clock.now_s()
    with pytest.raises(InstrumentError) as err:
        q.acquire()
    assert "not back within 10 s" in str(err.value)
    assert 10.0 <= clock.now_s() - t0 < 11.0
    with pytest.raises(InstrumentError):                    # still away at t0 + 20 s: typed
        q.set_integration_time_s(0.2)
    assert 20.0 <= clock.now_s() - t0 < 21.0
    assert q.tec_temperature_c() < 25.0                     # back at t0 + 30 s: reopened
    assert q.acquire().counts.max() > 1000


def test_real_open_reports_missing_device_typed():
    from normbox_lab.sim.usb import BACKEND_NAME, bus

    bus()                                                   # an emulated bus, nothing on it
    with pytest.raises(InstrumentError):
        QEPro.open("usb:NO-SUCH-QEPRO", VirtualClock(), backend="pyseabreeze",
                   pyusb_backend=BACKEND_NAME)


def test_cseabreeze_stays_the_default_on_hardware():
    code = ("import sys; from normbox_lab.core.clock import VirtualClock; "
            "from normbox_lab.core.errors import InstrumentError; "
            "from normbox_lab.drivers.qepro import QEPro\n"
            "try:\n    QEPro.open('usb:NO-SUCH-QEPRO', VirtualClock())\n"
            "except InstrumentError as e:\n    print(type(e).__name__)\n"
            "import seabreeze.backends; print(seabreeze.backends.BackendConfig.requested)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False, timeout=120).stdout.split()
    assert out == ["InstrumentError", "cseabreeze"]


def test_the_driver_sends_nothing_onto_the_network(monkeypatch):
    """pyseabreeze's listing multicasts a discovery request (UDP to 239.239.239.239:57357)
    unless an adapter is named; the driver names none (`NO_NETWORK_ADAPTER`), so opening,
    reading and reopening the simulated QE Pro sends no datagram at all."""
    import socket

    from normbox_lab.drivers.qepro import QEPro

    sent: list[tuple] = []
    real_sendto = socket.socket.sendto

    def recording_sendto(self, data, *args):
        sent.append(args[-1])
        return real_sendto(self, data, *args)

    monkeypatch.setattr(socket.socket, "sendto", recording_sendto)
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    sim.device("qepro", clock=clock, light_arm=lambda: 0.0, detector_arm=lambda: 45.0)
    q = QEPro.open("sim://qepro", clock)
    q.intensities_counts()
    q.spec.close()
    q.spec = q._reopen()                      # a reconnect lists the devices again
    q.intensities_counts()
    assert sent == []


class _Frames:
    """The opened spectrometer with chosen raw frames or nonlinearity coefficients."""

    def __init__(self, inner, frame=None) -> None:
        self._inner, self._frame = inner, frame

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def intensities(self, *a):
        return self._frame if self._frame is not None else self._inner.intensities(*a)


def test_raw_counts_above_the_18_bit_full_scale_are_a_typed_error_not_data():
    from normbox_lab.core.errors import ProtocolError

    q, _dev = open_sim()
    good = np.asarray(q.spec.intensities(False, False), dtype=float)
    for bad in (np.where(np.arange(good.size) == 300, 262144.0, good),   # one count over
                good * 1e30,                                              # finite but huge
                np.where(np.arange(good.size) == 5, -1.0, good)):        # negative
        q.spec = _Frames(q.spec, bad)
        with pytest.raises(ProtocolError, match="full scale"):
            q.acquire()
    q.spec = _Frames(q.spec, np.full(good.size, 262143.0))                # at full scale: data
    assert q.acquire().saturated


def test_a_nonlinearity_correction_that_overflows_is_a_typed_error_not_nan():
    from normbox_lab.core.errors import ProtocolError

    q, _dev = open_sim()
    assert np.all(np.isfinite(q.acquire().counts))
    feature = q._features()["nonlinearity_coefficients"][0]
    for coeffs in ([1.0, -1e-3], [1.0, 1e300, 1e300], [1.0, float("nan")], ["x"]):
        feature.get_nonlinearity_coefficients = lambda c=coeffs: c
        with pytest.raises(ProtocolError, match="nonlinearity"):
            q.acquire()
