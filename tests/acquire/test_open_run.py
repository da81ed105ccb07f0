"""`open_run`: one assembly of lab + store + plan + operator + engine for a new run or a
resume (the command line, the console, the demo and the bench all use it)."""

from __future__ import annotations

import pytest
from engine_fakes import FakeLab

from normbox_lab.acquire.engine import PlanError, open_run
from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import StoreError

SMALL = {"angles_deg": [30, 60], "patches": [1, 2, 3]}


def test_a_new_run_pauses_and_resumes_with_its_stored_parameters(tmp_path):
    path = tmp_path / "s.sqlite"
    with open_run("reference-sweep", lab=FakeLab(lamp_on=True), store=path,
                  params=SMALL) as opened:
        assert opened.resume is None and opened.plan.planned == 6
        engine = opened.engine
        engine.subscribe(lambda ev: engine.pause() if ev.kind == "progress"
                         and ev.data["done"] == 4 else None)
        first = opened.run()
    assert (first.status, first.done) == ("paused", 4)
    # parameters cannot change on resume; the stored ones are used
    with pytest.raises(PlanError, match="cannot change a resumed run"):
        open_run(resume=first.uuid, lab=FakeLab(lamp_on=True), store=path,
                 params={"patches": [1]})
    with pytest.raises(PlanError, match="ran 'reference-sweep'"):
        open_run("light-map", resume=first.uuid, lab=FakeLab(lamp_on=True), store=path)
    with open_run(resume=first.uuid, lab=FakeLab(lamp_on=True), store=path) as opened:
        assert opened.resume == first.run_id
        assert opened.plan.parameters["patches"] == [1, 2, 3]
        assert [e.key for e in opened.dry_run().executed if e.kind == "measure"] == \
            ["a60/p02", "a60/p03"]
        second = opened.run()
    assert (second.status, second.done, second.taken) == ("done", 6, 2)
    with pytest.raises(StoreError, match="already done"):
        open_run(resume=first.uuid, lab=FakeLab(), store=path)
    store = Store(path)
    try:
        assert len(list(store.readings(first.run_id))) == 6
    finally:
        store.close()


def test_a_lab_built_from_a_config_records_its_world_and_is_closed(tmp_path):
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.sim.labsim import build_lab

    config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    with pytest.raises(PlanError, match="sim://"):       # the simulation comes from outside
        open_run("reference-sweep", config=config, store=tmp_path / "t.sqlite")
    opened = open_run("reference-sweep", config=config, store=tmp_path / "s.sqlite",
                      world="analytic", make_lab=build_lab,
                      params={"angles_deg": [30], "patches": [1, 2]})
    try:
        assert opened.engine.segment_info == {"world": "analytic", "lab": "<simulated template>",
                                              "time_scale": 0.0, "seed": 1}
        assert opened.lab.operator is not None          # the virtual operator answers
        assert opened.dry_run().lines()[-1].startswith("ETA ")
    finally:
        opened.close()
    assert opened.lab._open == {}                       # the instruments were closed

