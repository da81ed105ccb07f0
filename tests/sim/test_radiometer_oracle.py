"""The emulator as the oracle: no radiometer reading is stored wrong without an error flag.

Neither Konica Minolta protocol has a checksum or numbered replies.  Each case below runs a
reference sweep (angles 30° and 60°, patches 1–6: 12 readings) on the analytic world with a
fault schedule on the radiometer's line, and compares every stored reading with the reading of
a fault-free run of the same seed (noise off, so the two differ only by the lamp's drift over
the longer run).  A reading without an error flag must agree: its level within 0.3 % and its
shape band by band within 3·10⁻⁴ (five significant digits on the wire).  The faults are the
ones that stored wrong data before: a garbled byte in a data line (bands down to 0.01×, one
band 0.0), replies 12 s or 30 s later than the 10 s timeout (readings 0.21× to 12.7×).
"""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.store import Store
from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim import core
from normbox_lab.sim import labsim as labmod

PLAN = {"angles_deg": [30, 60], "patches": [1, 2, 3, 4, 5, 6]}
_FAULT_FREE: dict[tuple[str, int], dict[str, np.ndarray]] = {}


def _sweep(path, driver: str, faults: str, seed: int):
    """(run result, {key: stored radiance}, keys with an error flag)."""
    core.CONTEXT.reset(VirtualClock())
    url = f"sim://{driver}?noise=off&seed={seed}" + (f"&faults={faults}" if faults else "")
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://cs1000a"', f'port = "{url}"')
    text = text.replace("seed = 1", f"seed = {seed}")
    if driver != "cs1000a":
        text = text.replace('driver = "cs1000a"', f'driver = "{driver}"')
        text = text.replace("baud = 9600 ", "# baud = 9600 ")
    lab = labmod.build_lab(parse_config(text), world="analytic")
    store = Store(path)
    try:
        res = eng.Engine(lab, store, eng.build_plan("reference-sweep", PLAN, lab)).run()
        stored = {r.key: r.arrays["radiance_W_sr_m2_nm"] for r in store.readings(res.run_id)}
        errors = {f["key"] for f in store.flag_rows(run_id=res.run_id)
                  if f["severity"] == "error"}
    finally:
        store.close()
        lab.close()
        core.CONTEXT.reset()
    return res, stored, errors


def _fault_free(tmp_path, driver: str, seed: int) -> dict[str, np.ndarray]:
    if (driver, seed) not in _FAULT_FREE:
        res, stored, errors = _sweep(tmp_path / "fault-free.sqlite", driver, "", seed)
        assert res.status == "done" and len(stored) == 12 and not errors
        _FAULT_FREE[driver, seed] = stored
    return _FAULT_FREE[driver, seed]


def _wrong_unflagged(stored, errors, truth) -> list[tuple[str, float, float]]:
    wrong = []
    for key, radiance in stored.items():
        if key in errors:
            continue
        ratio = radiance / truth[key]
        level = float(np.median(ratio))
        shape = float(np.max(np.abs(ratio / level - 1.0)))
        if abs(level - 1.0) > 3e-3 or shape > 3e-4:
            wrong.append((key, float(np.min(ratio)), float(np.max(ratio))))
    return wrong


@pytest.mark.parametrize(("driver", "faults", "seed"), [
    ("cs2000a", "garble=0.2", 7),
    ("cs2000a", "garble=0.2", 8),
    ("cs2000a", "garble=0.2", 9),
    ("cs1000a", "garble=0.2", 7),
    ("cs1000a", "garble=0.2", 8),
    ("cs1000a", "late-reply=0.2:12", 7),
    ("cs1000a", "late-reply=0.2:12", 8),
    ("cs2000a", "late-reply=0.2:12", 7),
])
def test_garbled_or_late_replies_are_read_again_never_stored(tmp_path, driver, faults, seed):
    """Every reading is complete and right: the faults cost lab time, not data."""
    truth = _fault_free(tmp_path, driver, seed)
    res, stored, errors = _sweep(tmp_path / "faulty.sqlite", driver, faults, seed)
    assert _wrong_unflagged(stored, errors, truth) == []
    assert res.status == "done" and sorted(stored) == sorted(truth) and not errors


@pytest.mark.parametrize(("driver", "faults", "seed"), [
    ("cs1000a", "late-reply=0.2:30", 7),
    ("cs2000a", "late-reply=0.2:30", 13),
])
def test_replies_far_beyond_the_timeout_never_answer_a_later_command(tmp_path, driver, faults,
                                                                     seed):
    """30 s late (three times the timeout): the line is resynchronised (sync query, read until
    its reply); a reading is stored right or carries an error flag."""
    truth = _fault_free(tmp_path, driver, seed)
    _res, stored, errors = _sweep(tmp_path / "faulty.sqlite", driver, faults, seed)
    assert stored, "nothing stored"
    assert _wrong_unflagged(stored, errors, truth) == []
