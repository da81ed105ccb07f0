"""Integrating-sphere light source (placeholder SCPI-like protocol): lines, physics, faults."""

from __future__ import annotations

import numpy as np
import pytest
from wire import Exchange, ScriptedPort

from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady, ProtocolError
from normbox_lab.drivers.sphere import SphereLightSource
from normbox_lab.predict.scene import panel_map as truth_panel_map
from normbox_lab.sim import core
from normbox_lab.sim.sphere import WARMUP_S, SphereEmulator


def scripted(script: list[Exchange]) -> tuple[SphereLightSource, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(script, clock=clock, timeout=0.05)
    return SphereLightSource(port, clock, poll_s=5.0), port


def sim_lamp(key: str, faults: str = "") -> tuple[SphereLightSource, SphereEmulator]:
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    q = f"&faults={faults}" if faults else ""
    lamp = SphereLightSource.open(f"sim://sphere?key={key}{q}", clock)
    return lamp, core.CONTEXT.instances[key]


# --- exact lines ---------------------------------------------------------------------------------

def test_command_lines():
    lamp, port = scripted([
        Exchange(b"*IDN?\n", b"IE,LE7-4x,SN7,1.0\n"),
        Exchange(b"INT 75.00\n", b"OK\n"),
        Exchange(b"SPEC:PRES D65\n", b"OK\n"),
        Exchange(b"OUTP ON\n", b"OK\n"),
        Exchange(b"STAT?\n", b"SETTLING\n"),
        Exchange(b"STAB:REM?\n", b"120.0\n"),
        Exchange(b"PANEL:MAP? 2,3\n", b"1.01200\n"),
        Exchange(b"OUTP OFF\n", b"OK\n"),
    ])
    ident = lamp.identify()
    assert (ident.model, ident.serial_number, ident.firmware) == ("LE7-4x", "SN7", "1.0")
    lamp.set_level_percent(75)
    lamp.set_spectrum_preset("D65")
    lamp.set_output(True)
    assert lamp.state() == "settling"
    assert lamp.estimate_settle_time_s() == 120.0
    assert lamp.radiance_factor(2, 3) == pytest.approx(1.012)
    lamp.set_output(False)
    port.assert_done()


def test_error_reply_drains_queue_into_device_error():
    lamp, port = scripted([
        Exchange(b"INT 150.00\n", b"ERR -222\n"),
        Exchange(b"SYST:ERR?\n", b'-222,"Data out of range"\n'),
        Exchange(b"SYST:ERR?\n", b'0,"No error"\n'),
    ])
    with pytest.raises(DeviceError) as err:
        lamp.set_level_percent(150)
    assert err.value.code == "-222" and "out of range" in err.value.meaning
    port.assert_done()


def test_spectrum_block_parsing_and_bad_count():
    lamp, port = scripted([
        Exchange(b"MEAS:SPEC?\n", b"380,1,3,REL\n0.5,0.6,0.7\n"),
        Exchange(b"MEAS:SPEC?\n", b"380,1,4,REL\n0.5,0.6,0.7\n"),
        Exchange(b"PANEL:MAP?\n", b"1,1,1\n"),
    ])
    wl, rel = lamp.internal_spectrum()
    assert list(wl) == [380, 381, 382] and list(rel) == [0.5, 0.6, 0.7]
    with pytest.raises(ProtocolError):
        lamp.internal_spectrum()
    with pytest.raises(ProtocolError):
        lamp.panel_map()
    port.assert_done()


# --- emulator physics ----------------------------------------------------------------------------

def test_warmup_settles_on_the_virtual_clock():
    lamp, emu = sim_lamp("sph-warm")
    assert lamp.state() == "off" and emu.relative_output() == 0.0
    assert lamp.estimate_settle_time_s() == pytest.approx(WARMUP_S, abs=0.1)
    lamp.set_output(True)
    assert lamp.state() == "settling"
    assert emu.relative_output() == pytest.approx(0.8, abs=0.002)       # 80 % at switch-on
    t0 = lamp.clock.now_s()
    lamp.wait_stable(timeout_s=3600.0)
    took = lamp.clock.now_s() - t0
    assert WARMUP_S <= took <= WARMUP_S + lamp.poll_s                    # τ·ln 200 ≈ 318 s
    assert abs(emu.relative_output() - 1.0) < 0.002
    lamp.clock.sleep(3600.0)
    assert lamp.stable_for_s() == pytest.approx(3600.0 + (took - WARMUP_S), abs=0.2)
    drift = np.mean([emu.relative_output() for _ in range(200)])
    assert drift == pytest.approx(1.0 - 0.0005 * (3600 + took) / 3600, abs=1e-4)   # −0.05 %/h


def test_level_change_resettles_and_scales_output():
    lamp, emu = sim_lamp("sph-level")
    lamp.set_output(True)
    lamp.wait_stable(3600.0)
    lamp.set_level_percent(50.0)
    assert lamp.state() == "settling"
    lamp.wait_stable(100.0)
    assert emu.relative_output() == pytest.approx(0.5, abs=0.002)
    assert lamp.level_percent() == 50.0


def test_internal_spectrum_and_luminance_follow_output():
    lamp, _emu = sim_lamp("sph-spec")
    lamp.set_spectrum_preset("A")
    lamp.set_output(True)
    lamp.wait_stable(3600.0)
    wl, rel = lamp.internal_spectrum()
    assert wl[0] == 380 and wl[-1] == 780 and rel.size == 401
    assert rel[wl == 560][0] == pytest.approx(1.0, abs=0.01)
    assert rel[-1] > rel[0] * 3                                          # illuminant A: red-rich
    assert lamp.luminance_cd_m2() == pytest.approx(2000.0, rel=0.003)


def test_panel_map_is_the_truth_map():
    lamp, emu = sim_lamp("sph-map")
    m = lamp.panel_map()
    assert m.shape == (5, 5)
    np.testing.assert_allclose(m, truth_panel_map(3.0), atol=1e-5)
    assert m.mean() == pytest.approx(1.0, abs=1e-5)
    assert np.abs(m - 1).max() == pytest.approx(0.03, abs=1e-5)           # ±3 % homogeneity
    assert lamp.radiance_factor(4, 0) == pytest.approx(m[4, 0], abs=1e-5)
    with pytest.raises(DeviceError):
        lamp.radiance_factor(5, 0)
    np.testing.assert_allclose(emu.panel_map(), m, atol=1e-5)


def test_unknown_command_and_error_queue():
    lamp, _emu = sim_lamp("sph-err")
    with pytest.raises(DeviceError) as err:
        lamp.query("FLY ME")
    assert err.value.code == "-100"
    assert lamp.errors() == []
    with pytest.raises(DeviceError):
        lamp.set_spectrum_preset("F11")
    assert lamp.status()["preset"] == "D65"


# --- faults --------------------------------------------------------------------------------------

def test_unstable_fault_goes_back_to_settling():
    lamp, emu = sim_lamp("sph-unst")
    lamp.set_output(True)
    lamp.wait_stable(3600.0)
    emu.faults.add("unstable", at_count=emu.faults._counters.get("unstable", 0) + 1,
                   parameter=60.0)
    assert lamp.state() == "settling"                                    # lost lock: dip
    assert emu.relative_output() < 0.99
    with pytest.raises(NotReady):
        lamp.wait_stable(30.0)
    lamp.wait_stable(60.0)
    assert lamp.is_stable()


def test_lamp_failure_is_a_typed_error_and_recovers_with_power_cycle():
    lamp, emu = sim_lamp("sph-fail")
    lamp.set_output(True)
    emu.faults.add("lamp-fail", at_count=emu.faults._counters.get("lamp-fail", 0) + 1)
    with pytest.raises(DeviceError) as err:
        lamp.wait_stable(3600.0)
    assert err.value.code == "LAMP"                 # the ERROR state, not an "ERR OR" reply
    assert "Lamp failure" in err.value.meaning and emu.relative_output() == 0.0
    lamp.set_output(False)
    lamp.set_output(True)
    lamp.wait_stable(3600.0)


def test_wait_stable_on_an_off_lamp_is_not_ready_not_a_hang():
    lamp, _emu = sim_lamp("sph-off")
    with pytest.raises(NotReady):
        lamp.wait_stable(10.0)


def test_disconnect_and_no_reply():
    lamp, emu = sim_lamp("sph-disc", faults="no-reply@2")
    lamp.identify()
    assert lamp.state() == "off"            # reply 2 lost: drain, re-handshake, asked again
    assert lamp.line_faults == 1
    emu.disconnect(5.0)
    with pytest.raises(InstrumentError):
        lamp.state()
    lamp.clock.sleep(5.0)
    assert lamp.state() == "off"


def test_served_on_a_pty_for_outside_programs():
    import os
    import select
    import subprocess
    import sys

    import serial

    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", "sphere",
                             "--pty"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ))
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no endpoint printed"
        kind, _, path = proc.stdout.readline().decode().strip().partition(": ")
        assert kind == "pty"
        with serial.Serial(path, 115200, timeout=5) as port:
            port.write(b"*IDN?\n")
            assert port.readline().startswith(b"Image Engineering (placeholder protocol),LE7-4x")
            port.write(b"OUTP ON\n")
            assert port.readline() == b"OK\n"
            port.write(b"STAT?\n")
            assert port.readline() == b"SETTLING\n"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_status_reset_abort_lines_and_role():
    from normbox_lab.core.capabilities import LightSource

    lamp, port = scripted([
        Exchange(b"*RST\n", b"OK\n"),
        Exchange(b"STAT?\n", b"STABLE\n"),
        Exchange(b"OUTP?\n", b"1\n"),
        Exchange(b"INT?\n", b"80.00\n"),
        Exchange(b"SPEC:PRES?\n", b"A\n"),
        Exchange(b"STAB:TIME?\n", b"12.5\n"),
        Exchange(b"STAB:REM?\n", b"0.0\n"),
        Exchange(b"TEMP?\n", b"33.1\n"),
        Exchange(b"HOUR?\n", b"412.0\n"),
        Exchange(b"MEAS:LUM?\n", b"1998.50\n"),
        Exchange(b"ABOR\n", b"OK\n"),
    ])
    assert isinstance(lamp, LightSource)
    lamp.reset()
    assert lamp.status() == {"state": "stable", "output": True, "level_percent": 80.0,
                             "preset": "A", "stable_for_s": 12.5, "settle_remaining_s": 0.0,
                             "temperature_c": 33.1, "lamp_hours": 412.0}
    assert lamp.luminance_cd_m2() == 1998.5
    lamp.abort()
    port.assert_done()


def test_error_state_reply_is_the_lamp_not_an_err_code():
    d, port = scripted([Exchange(b"STAT?\n", b"ERROR\n"), Exchange(b"SYST:ERR?\n",
                                                                    b'201,"Lamp failure"\n'),
                        Exchange(b"SYST:ERR?\n", b'0,"No error"\n')])
    with pytest.raises(DeviceError) as err:
        d.state()
    assert err.value.code == "LAMP" and "201 Lamp failure" in err.value.meaning
    port.assert_done()


@pytest.mark.parametrize("delay_s", [3.0, 30.0])
def test_late_reply_is_drained_and_never_answers_a_later_query(delay_s):
    """The level reply arrives after the 2 s timeout: the driver drains, re-handshakes with
    *IDN?, asks again, and no later query is answered with the stale value."""
    lamp, emu = sim_lamp(f"sph-late{delay_s:g}")
    lamp.identify()
    lamp.set_output(True)
    lamp.set_level_percent(50.0)
    emu.faults.add("late-reply", at_count=emu.faults._counters.get("late-reply", 0) + 1,
                   parameter=delay_s)
    assert lamp.level_percent() == 50.0
    assert lamp.line_faults == 1
    for _ in range(20):
        lamp.clock.sleep(2.0)                  # the stale reply comes out somewhere in here
        assert lamp.state() in ("settling", "stable")
        assert lamp.output() is True


def test_garbage_replies_are_protocol_errors():
    for reply in (b"nan\n", b"1e999\n", b"\xff\xfe\n", b"12,abc\n"):
        d, _ = scripted([Exchange(b"INT?\n", reply)])
        with pytest.raises(ProtocolError):
            d.level_percent()
    d, _ = scripted([Exchange(b"MEAS:SPEC?\n", [(0.0, b"380,-1,3,rel\n"), (0.0, b"1,2,3\n")])])
    with pytest.raises(ProtocolError, match="step"):
        d.internal_spectrum()


class _Babbling:
    """A line that never answers a command and never goes quiet: a byte every 0.1 s."""

    port = "babbling://"
    is_open = True

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock
        self.timeout = 0.05
        self.reads = 0

    def write(self, data: bytes) -> int:
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self.reads += 1
        assert self.reads < 10_000, "the drain never ended"
        self.clock.sleep(0.1)
        return b"~"

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        return self.read()

    def reset_input_buffer(self) -> None: ...
    def open(self) -> None: ...
    def close(self) -> None: ...


def test_a_line_that_never_goes_quiet_is_a_bounded_timeout():
    """The drain after a lost reply stops after RESYNC_MAX_S even if bytes keep coming."""
    clock = VirtualClock()
    lamp = SphereLightSource(_Babbling(clock), clock, attempts=2, command_timeout_s=1.0)
    with pytest.raises(InstrumentError):
        lamp.identify()
    assert clock.now_s() < 60.0
