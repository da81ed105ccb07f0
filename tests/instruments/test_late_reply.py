"""Late replies on the line protocols: a reply that arrives after the driver's timeout must
never be taken as the answer to a later command.

The run below is the reproducer: CS-1000A with ``late-reply@7:12`` (the first spectrum line of
the first reading arrives 12 s late, after the 10 s command timeout), noise off, analytic
world, one angle, one patch, 12 readings.  Every stored reading must equal the truth (within
the instrument's radiometric tolerance), or the run must report the fault.
"""

from __future__ import annotations

import numpy as np
import pytest
import test_cs1000 as cs1000_wire
import test_cs2000 as cs2000_wire
from wire import Exchange

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import InstrumentTimeout
from normbox_lab.sim import labsim as labmod


def _run(tmp_path, radiometer_url: str, driver: str = "cs1000a", repeats: int = 12):
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://cs1000a"', f'port = "{radiometer_url}"')
    if driver != "cs1000a":
        text = text.replace('driver = "cs1000a"', f'driver = "{driver}"')
        text = text.replace("baud = 9600 ", "# baud = 9600 ")
    lab = labmod.build_lab(parse_config(text), world="analytic")
    store = Store(tmp_path / "late.sqlite")
    plan = eng.build_plan("repeatability", {"repeats": repeats, "angle_deg": 60.0,
                                            "patch": 19}, lab)
    res = eng.Engine(lab, store, plan).run()
    readings = list(store.readings(res.run_id))
    ratios = []
    for r in readings:
        truth = lab.world.radiance_at(r.metadata["patch"], r.metadata["angle_deg"])
        ratios.append(r.arrays["radiance_W_sr_m2_nm"] / truth)
    events = [k for _, k, _ in store.events(res.run_id)]
    store.close()
    lab.close()
    return res, ratios, events


@pytest.mark.parametrize("driver,url", [
    ("cs1000a", "sim://cs1000a?noise=off&faults=late-reply@7:12"),
    ("cs1000a", "sim://cs1000a?noise=off&faults=late-reply@5:12"),
    ("cs1000a", "sim://cs1000a?noise=off&faults=late-reply@2:40"),
    ("cs2000a", "sim://cs2000a?noise=off&faults=late-reply@6:12"),
    ("cs2000a", "sim://cs2000a?noise=off&faults=late-reply@9:12"),
])
def test_late_reply_never_corrupts_stored_readings(tmp_path, driver, url):
    res, ratios, events = _run(tmp_path, url, driver)
    if res.status == "done":
        assert res.done == 12
    else:
        assert "failed" in events or res.status in ("failed", "suspended"), (res, events)
    assert ratios, "no reading stored"
    for i, ratio in enumerate(ratios):
        # noise off: the only deviation is the instrument's fixed ±2 % calibration model
        assert np.all(np.abs(ratio - np.median(ratio)) < 1e-3), (i, np.min(ratio), np.max(ratio))
        assert abs(np.median(ratio) - 1) < 0.03, (i, np.median(ratio))


# --- a reply given up on, arriving later still (scripted port, virtual clock) ----------------
#
# Timeout 10 s, late window 10 s: a reply 30 s late is given up on at 20 s; the line is
# drained (0.5 s quiet) and the sync query sent at 20.5 s.  The late reply then comes at 30 s
# and is taken for the sync query's reply (the shapes are equal when the late command was the
# sync query itself); the sync query's own reply, a moment later, is then still on its way.
# Before, it reached the next command: ``MEAS,1: expected OK00,ttt (raw=b'OK00,CS-2000A
# ,2,2000123')``.


def test_cs2000_a_sync_reply_given_up_on_never_answers_the_next_command():
    w = cs2000_wire
    iddr = w.IDDR.reply
    d, port = w.scripted([*w.remote_script(),
                          Exchange(b"IDDR\n", iddr, delay_s=30.0),  # identify(): 30 s late
                          Exchange(b"IDDR\n", iddr, delay_s=9.6),   # sync query: at 30.1 s
                          Exchange(b"IDDR\n", iddr, delay_s=0.2),   # identify() again: 30.2 s
                          *w.measure_script()])
    assert d.identify().serial_number == "2000123"
    faults = d.line_faults
    reading = d.measure()             # the IDDR reply at 30.2 s is dropped, not taken
    port.assert_done()
    np.testing.assert_allclose(reading.radiance_W_sr_m2_nm, w.SPECTRUM, rtol=6e-5)
    assert reading.metadata["measurement_time_s"] == 2
    assert d.line_faults == faults + 1


def test_cs2000_a_reply_given_up_on_is_drained_before_the_next_command():
    """SPMS's reply 45 s late, the sync query unanswered within its 20 s: an
    InstrumentTimeout.  The next command first resynchronises (the late OK00 and the sync
    replies are read and dropped) instead of taking the late OK00 as MEAS,1's answer."""
    w = cs2000_wire
    iddr = w.IDDR.reply
    d, port = w.scripted([*w.remote_script(),
                          Exchange(b"SPMS,0,2\n", b"OK00\n", delay_s=45.0),
                          Exchange(b"IDDR\n", iddr, delay_s=30.0),  # 50.5 s: after its 40.5
                          Exchange(b"IDDR\n", iddr, delay_s=9.6),   # the resync's: 50.6 s
                          *w.measure_script()])
    with pytest.raises(InstrumentTimeout):
        d.set_speed("normal")
    reading = d.measure()
    port.assert_done()
    np.testing.assert_allclose(reading.radiance_W_sr_m2_nm, w.SPECTRUM, rtol=6e-5)


def test_cs1000_a_sync_reply_given_up_on_never_answers_the_next_command():
    """The CS-1000A's sync query is STR (status()): the same race."""
    w = cs1000_wire
    st = b"OK,0,0,1.000\n"
    d, port = w.scripted([Exchange(b"RMT,1\n", b"OK\n"),
                          Exchange(b"STR\n", st, delay_s=30.0),
                          Exchange(b"STR\n", st, delay_s=9.6),
                          Exchange(b"STR\n", st, delay_s=0.2),
                          *w.measure_script()])
    assert d.status()["time_mode"] == "auto"
    reading = d.measure()
    port.assert_done()
    assert reading.integration_time_s == 1.5
    np.testing.assert_allclose(reading.radiance_W_sr_m2_nm, w.SPECTRUM, rtol=6e-5)
