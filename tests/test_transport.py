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
                         capture_output=True, timeout=120, cwd=Path(__file__).parent)
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
from normbox_lab.acquire.lab import build_lab
lab = build_lab(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), world="analytic")
reading = lab.instrument("radiometer").measure()
spec = lab.instrument("spectrometer")
print(json.dumps({"n": len(reading.wavelength_nm), "qepro_simulated": spec.simulated,
                  "white": spec.white_standard() is not None}))
"""
    out = subprocess.run([sys.executable, "-c", script], check=False, text=True, capture_output=True,
                         timeout=300, cwd=Path(__file__).parent)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == \
        {"n": 401, "qepro_simulated": True, "white": True}


def test_an_unknown_url_scheme_is_an_instrument_error():
    with pytest.raises(InstrumentError, match="nosuch://x"):
        transport.open_port("nosuch://x", timeout=0.1)
    with pytest.raises(InstrumentError, match="no backend"):
        transport.open_spectrometer("nosuch://qepro", clock=None)


def test_drivers_import_the_neutral_transport_and_never_the_simulator():
    import normbox_lab.drivers

    for path in sorted(Path(normbox_lab.drivers.__file__).parent.glob("*.py")):
        text = path.read_text(encoding="utf-8")
        assert "normbox_lab.sim" not in text, path.name
        assert "serial_for_url" not in text, path.name
