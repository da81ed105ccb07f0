"""The fault-behaviour table (docs/fault-behaviour.md): every row names the test that shows
its behaviour, and those tests exist.  Rows whose test lives nowhere else are here."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.acquire.registry import driver_class, drivers_for
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import InstrumentTimeout, ProtocolError

ROOT = Path(__file__).resolve().parents[2]


def _table_rows() -> list[tuple[str, str, str, str]]:
    rows = []
    for line in (ROOT / "docs" / "fault-behaviour.md").read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and "::" in cells[3]:
            rows.append(tuple(cells))            # fault, instruments, behaviour, test
    return rows


def test_every_row_names_an_existing_test():
    rows = _table_rows()
    assert len(rows) >= 15
    for fault, _instruments, behaviour, test in rows:
        assert re.match(r"^(retry|clear prompt|typed abort|refused)", behaviour), (fault, behaviour)
        for ref in re.findall(r"`([\w/.]+::\w+)`", test):
            file, name = ref.split("::")
            tree = ast.parse((ROOT / file).read_text(encoding="utf-8"))
            names = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
            assert name in names, f"{fault}: {ref} does not exist"


def test_lamp_stability_check_is_inside_the_retry_loop(tmp_path):
    """A lost reply while the engine checks the lamp before a reading is retried, not fatal."""
    from engine_fakes import FakeLab

    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store

    lab = FakeLab()
    calls = {"n": 0}
    real = lab.sphere.is_stable

    def flaky() -> bool:
        calls["n"] += 1
        if calls["n"] in (5, 9):
            raise InstrumentTimeout("no reply", instrument="sphere")
        return real()

    lab.sphere.is_stable = flaky
    with Store(tmp_path / "s.sqlite") as store:
        plan = eng.build_plan("reference-sweep", {"angles_deg": [30, 60], "patches": [1, 2]}, lab)
        res = eng.Engine(lab, store, plan).run()
        assert res.status == "done" and res.done == 4
        faults = [d for _, k, d in store.events(res.run_id) if k == "fault"]
        assert len(faults) == 2 and {f["role"] for f in faults} == {"sphere"}


@pytest.mark.parametrize("model", drivers_for("radiometer"))
def test_garbled_spectra_are_reread_never_stored_wrong(model):
    """garble on 5 % of the replies: each reading is the truth (to the wire's 5 digits)
    or a typed ProtocolError — never a band 10–100× off (the wire has no checksum).  Every
    radiometer of the registry (its emulator has the driver's name)."""
    from normbox_lab.sim import core

    wl = np.arange(380.0, 781.0)
    truth = 2e-3 * (1.0 + np.sin(wl / 37.0) ** 2)
    core.CONTEXT.reset(VirtualClock())
    try:
        core.instance(model, scene=lambda: (wl, truth), noise="off", faults="garble=0.05",
                      seed=4)
        d = driver_class(model).open(f"sim://{model}?faults=garble=0.05&noise=off", core.CONTEXT.clock)
        good = refused = 0
        for _ in range(12):
            try:
                r = d.measure()
            except ProtocolError:
                refused += 1
                continue
            ratio = r.radiance_W_sr_m2_nm / truth
            # what passes: the truth, or a mantissa digit flip no check can see (< 20 % of
            # the peak at one band, with Lv still consistent)
            assert np.all(np.abs(r.radiance_W_sr_m2_nm - truth) < 0.2 * truth.max()), ratio
            good += 1
        assert good >= 6
    finally:
        core.CONTEXT.reset()


def test_qepro_nan_or_short_counts_are_protocol_errors():
    from normbox_lab.drivers.qepro import QEPro
    from normbox_lab.sim import core
    from normbox_lab.sim import qepro as simq
    from normbox_lab.sim.transport import register_url_scheme

    register_url_scheme()
    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock)
    try:
        simq.device("qepro", clock=clock, light_arm=lambda: 0.0, detector_arm=lambda: 45.0)
        q = QEPro.open("sim://qepro", clock)
        good = q.acquire().raw_counts
        for bad in (good[:-1], np.where(np.arange(good.size) == 3, np.nan, good)):
            q.spec.intensities = lambda *a, bad=bad: bad
            with pytest.raises(ProtocolError):
                q.acquire()
    finally:
        core.CONTEXT.reset()


def test_implausible_data_is_retried_and_recorded_as_a_quality_flag(tmp_path):
    from engine_fakes import FakeLab

    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store
    from normbox_lab.core.errors import ImplausibleData

    lab = FakeLab()
    real = lab.radiometer.measure
    calls = {"n": 0}

    def corrupted_once():
        calls["n"] += 1
        if calls["n"] == 2:
            raise ImplausibleData("implausible data: band 500 nm is 40.1", raw=b"4.01e1",
                                  instrument="radiometer")
        return real()

    lab.radiometer.measure = corrupted_once
    with Store(tmp_path / "s.sqlite") as store:
        plan = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [1, 2]}, lab)
        res = eng.Engine(lab, store, plan).run()
        assert res.status == "done" and res.done == 2
        flags = store.flag_rows(run_id=res.run_id)
        assert [f["gate"] for f in flags] == ["instrument-error:implausible-data"]
