"""The neutral transport: drivers reach their instruments through `normbox_lab.core.transport`
only; a real lab loads no module of the simulator, a simulated lab registers ``sim://``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from normbox_lab.core import transport
from normbox_lab.core.errors import InstrumentError

REAL_LAB = """
[lab]
name = "a real lab"
time_scale = 1.0

[instruments.radiometer]
driver = "cs1000a"
port = "/dev/normbox-test-no-such-port"

[instruments.rotator]
driver = "apt-k10cr1"
port = "socket://127.0.0.1:9"

[instruments.sphere]
driver = "sphere-scpi"
port = "/dev/normbox-test-no-such-port-2"

[instruments.spectrometer]
driver = "qepro"
port = "sim"
"""

SCRIPT = r"""
import json, sys
from normbox_lab.acquire.config import parse_config
from normbox_lab.acquire.engine import open_run
from normbox_lab.acquire.lab import build_lab
from normbox_lab.core.errors import InstrumentError, NormboxError
from normbox_lab.drivers import cs1000, cs2000, gonio, qepro, rotator_apt, rotator_zaber, sphere

config = parse_config(sys.stdin.read(), "real.toml")
lab = build_lab(config)
errors = {}
for role in ("radiometer", "rotator", "sphere", "spectrometer"):
    try:
        lab.instrument(role)
        errors[role] = None
    except InstrumentError as exc:
        errors[role] = type(exc).__name__
    except NormboxError as exc:
        errors[role] = "untyped " + type(exc).__name__
step = open_run  # the engine and open_run are importable without the simulator
hint = lab.luminance_hint_cd_m2(type("S", (), {"params": {"patch": 3, "angle_deg": 30}})())
print(json.dumps({"simulated": config.simulated, "operator": lab.operator is not None,
                  "errors": errors, "hint": hint,
                  "sim_modules": sorted(m for m in sys.modules
                                        if m == "normbox_lab.sim"
                                        or m.startswith("normbox_lab.sim."))}))
"""


def test_a_real_lab_loads_no_module_of_the_simulator():
    out = subprocess.run([sys.executable, "-c", SCRIPT], check=False, input=REAL_LAB, text=True,
                         capture_output=True, timeout=120, cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["simulated"] is False and result["operator"] is False
    assert result["sim_modules"] == []
    # ports that are not there fail typed; `sim` is no backend of a real lab
    assert result["errors"] == {"radiometer": "InstrumentError", "rotator": "InstrumentError",
                                "sphere": "InstrumentError", "spectrometer": "InstrumentError"}
    assert result["hint"] == 20.0      # a real lab's ETA does not come from a simulated world


def test_a_simulated_lab_registers_its_transports_by_itself():
    script = r"""
import json, sys
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.sim.labsim import build_lab
lab = build_lab(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), world="analytic")
reading = lab.instrument("radiometer").measure()
spec = lab.instrument("spectrometer")
print(json.dumps({"n": len(reading.wavelength_nm), "qepro_simulated": spec.simulated,
                  "white": spec.white_standard() is not None}))
"""
    out = subprocess.run([sys.executable, "-c", script], check=False, text=True, capture_output=True,
                         timeout=300, cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == \
        {"n": 401, "qepro_simulated": True, "white": True}


def test_an_unknown_url_scheme_is_an_instrument_error():
    with pytest.raises(InstrumentError, match="nosuch://x"):
        transport.open_port("nosuch://x", timeout=0.1)
    with pytest.raises(InstrumentError, match="no backend"):
        transport.open_spectrometer("nosuch://qepro", clock=None)


def test_drivers_import_the_neutral_transport_and_never_the_simulator():
    """Imported in a fresh interpreter (this one has the simulator loaded by conftest), every
    driver module leaves no module of `normbox_lab.sim` in sys.modules, however it would be
    spelt (``from normbox_lab import sim`` included); and none opens ports by itself."""
    import normbox_lab.drivers

    folder = Path(normbox_lab.drivers.__file__).parent
    names = sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")
    script = ("import importlib, json, sys\n"
              f"for name in {names!r}:\n"
              "    importlib.import_module('normbox_lab.drivers.' + name)\n"
              "print(json.dumps(sorted(m for m in sys.modules if m == 'normbox_lab.sim' "
              "or m.startswith('normbox_lab.sim.'))))\n")
    out = subprocess.run([sys.executable, "-c", script], check=False, text=True,
                         capture_output=True, timeout=120, cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    assert len(names) >= 7 and json.loads(out.stdout.strip().splitlines()[-1]) == []
    for name in names:
        assert "serial_for_url" not in (folder / f"{name}.py").read_text(encoding="utf-8"), name


# --- Port and the one link-recovery loop ----------------------------------------------------

def test_every_port_the_drivers_get_is_a_port():
    import serial
    from wire import ScriptedPort

    from normbox_lab.sim.transport import open_port as open_sim_port

    sim_port = open_sim_port("sim://cs1000a?key=port-protocol")
    try:
        assert isinstance(sim_port, transport.Port)
        assert isinstance(serial.serial_for_url("loop://", timeout=0), transport.Port)
        assert isinstance(ScriptedPort([]), transport.Port)
        assert not isinstance(object(), transport.Port)
    finally:
        sim_port.close()


def test_recover_link_retries_on_the_clock_until_the_link_is_back():
    from normbox_lab.core.clock import VirtualClock

    clock = VirtualClock()
    back_at_s = 3.2
    calls: list[float] = []
    failures: list[str] = []

    def attempt() -> str:
        calls.append(clock.now_s())
        if clock.now_s() < back_at_s:
            raise OSError("gone")
        return "open"

    got = transport.recover_link(clock, 10.0, attempt, retry_on=(OSError,), instrument_id="x",
                                 first_wait_s=1.0, interval_s=1.0,
                                 on_failure=lambda exc: failures.append(str(exc)))
    assert got == "open"
    assert calls == [1.0, 2.0, 3.0, 4.0]          # first wait, then one try per interval
    assert failures == ["gone"] * 3


def test_recover_link_gives_up_at_its_deadline_with_a_typed_error():
    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.core.errors import InstrumentTimeout

    clock = VirtualClock()

    def attempt() -> None:
        raise OSError("still gone")

    with pytest.raises(InstrumentTimeout, match=r"rad: link lost; not back within 5 s: "
                                                r"still gone") as info:
        transport.recover_link(clock, 5.0, attempt, retry_on=(OSError,), instrument_id="rad",
                               error=InstrumentTimeout, interval_s=0.5)
    assert isinstance(info.value.__cause__, OSError)
    assert 5.0 <= clock.now_s() <= 5.5                 # bounded: no wait past the deadline
    with pytest.raises(ValueError):                   # not a link fault: raised at once
        transport.recover_link(clock, 5.0, lambda: int("x"), retry_on=(OSError,),
                               instrument_id="rad")


def test_reopen_closes_an_open_port_first():
    from wire import ScriptedPort

    port = ScriptedPort([])
    transport.reopen(port)
    assert port.is_open
    port.close()
    transport.reopen(port)
    assert port.is_open


# --- ScriptedPort checks itself -------------------------------------------------------------

def test_a_scripted_port_fails_when_an_expected_exchange_never_happened():
    from wire import LIVE, Exchange, ScriptedPort

    with ScriptedPort([Exchange(b"A\n", b"ok\n")]) as port:
        port.write(b"A\n")
        assert port.readline() == b"ok\n"
    with pytest.raises(AssertionError, match=r"still expected: \[b'B\\n'\]"), \
            ScriptedPort([Exchange(b"A\n", b"ok\n"), Exchange(b"B\n")]) as port:
        port.write(b"A\n")
    # an exception inside the block is the failure shown, not the unfinished script
    with pytest.raises(RuntimeError, match="driver broke"), ScriptedPort([Exchange(b"A\n")]):
        raise RuntimeError("driver broke")
    # every port made in a test is checked when the test ends (conftest); these are excused
    assert port in LIVE
    for p in LIVE:
        p.leave_unfinished()
