"""The device contract: each driver has exactly the capabilities it claims, the engine and the
console reach instruments only through `isinstance(inst, Capability)`, and a step an
instrument cannot do fails as a typed plan error."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from engine_fakes import FakeGonio, FakeLab

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.store import Store
from normbox_lab.core import capabilities as caps
from normbox_lab.drivers.cs1000 import CS1000A
from normbox_lab.drivers.cs2000 import CS2000A
from normbox_lab.drivers.gonio import Gonioreflectometer
from normbox_lab.drivers.qepro import QEPro
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.drivers.sphere import SphereLightSource

BASIC = {"Identifiable", "Closable", "HealthPollable"}
CLAIMS = {
    CS1000A: BASIC | {"RemoteControllable", "SpectrumReadable", "Abortable", "Recoverable"},
    CS2000A: BASIC | {"RemoteControllable", "SpectrumReadable", "Abortable", "Recoverable"},
    AptRotationStage: BASIC | {"Movable", "Homeable", "Stoppable"},
    ZaberRotationStage: BASIC | {"Movable", "Homeable", "Stoppable"},
    SphereLightSource: BASIC | {"Switchable", "LampLevel", "Settling", "Abortable"},
    QEPro: BASIC | {"TemperatureReadable"},
    Gonioreflectometer: BASIC | {"BrdfReadable", "Calibratable", "Stoppable"},
}
ROLES = {
    CS1000A: caps.Spectroradiometer, CS2000A: caps.Spectroradiometer,
    AptRotationStage: caps.RotationStage, ZaberRotationStage: caps.RotationStage,
    SphereLightSource: caps.LightSource, QEPro: caps.Spectrometer,
    Gonioreflectometer: caps.Gonioreflectometer,
}


@pytest.mark.parametrize("driver", list(CLAIMS), ids=lambda c: c.__name__)
def test_each_driver_has_exactly_the_capabilities_it_claims(driver):
    assert set(caps.capabilities_of(driver)) == CLAIMS[driver]
    for name in CLAIMS[driver]:
        assert issubclass(driver, getattr(caps, name))
    assert issubclass(driver, ROLES[driver])


def test_the_capability_table_in_the_module_names_every_driver():
    doc = caps.__doc__ or ""
    for driver in CLAIMS:
        assert driver.__module__.removeprefix("normbox_lab.") in doc, driver
    assert {c.__name__ for c in caps.CAPABILITIES} >= set().union(*CLAIMS.values())


def test_engine_fakes_are_the_roles_they_stand_for():
    lab = FakeLab()
    assert isinstance(lab.rotator, caps.Movable) and isinstance(lab.rotator, caps.Homeable)
    assert isinstance(lab.sphere, caps.Settling) and isinstance(lab.sphere, caps.Switchable)
    assert isinstance(lab.radiometer, caps.SpectrumReadable)
    assert isinstance(lab.radiometer, caps.Abortable)
    assert not isinstance(lab.radiometer, caps.Recoverable)
    gonio = FakeGonio(lab.clock, lab.world)
    assert isinstance(gonio, caps.BrdfReadable) and isinstance(gonio, caps.Calibratable)
    assert not isinstance(gonio, caps.SpectrumReadable)


ENGINE_MODULES = ("engine", "steps", "plan", "estimate", "retry", "runner", "events", "session",
                  "quality")
PROBE = re.compile(r"\b(hasattr|getattr)\s*\(")


def test_engine_and_console_never_probe_instruments_by_attribute_name():
    root = Path(eng.__file__).parent
    for name in ENGINE_MODULES:
        text = (root / f"{name}.py").read_text(encoding="utf-8")
        assert not PROBE.search(text), f"acquire/{name}.py probes with hasattr/getattr"
    controller = (root.parent / "tui" / "controller.py").read_text(encoding="utf-8")
    # the console asks capabilities; getattr remains only for readings and its own state
    assert "hasattr(" not in controller
    assert not re.search(r"getattr\(\s*inst\b", controller)


def test_a_step_an_instrument_cannot_do_is_a_plan_error(tmp_path):
    lab = FakeLab()
    # the lamp where the protocol expects a radiometer: it cannot take a spectral reading
    lab.instruments["radiometer"] = lab.sphere
    store = Store(tmp_path / "s.sqlite")
    try:
        plan = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [1]}, lab)
        with pytest.raises(eng.PlanError, match="radiometer .*FakeLamp.* is not SpectrumReadable"):
            eng.Engine(lab, store, plan).dry_run()
    finally:
        store.close()


def test_a_new_step_kind_is_one_class(tmp_path, monkeypatch):
    """A kind registered in KINDS is validated, estimated and executed with no engine change."""
    from normbox_lab.acquire import steps

    class Beep(steps.StepKind):
        name = "beep"

        def estimate_s(self, step, est):
            return 7.0

        def execute(self, step, run, for_key):
            run.clock.sleep(7.0)

    monkeypatch.setitem(steps.KINDS, "beep", Beep())
    lab = FakeLab(lamp_on=True)
    base = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [1]}, lab)
    plan = eng.Plan("beeping", {}, [*base.steps, eng.Step("end/beep", "beep", {"role": ""})])
    store = Store(tmp_path / "s.sqlite")
    try:
        e = eng.Engine(lab, store, plan)
        dry = e.dry_run()
        assert dry.executed[-1].key == "end/beep" and dry.executed[-1].duration_s == 7.0
        t0 = lab.clock.now_s()
        res = e.run()
        assert res.status == "done"
        assert lab.clock.now_s() - t0 == pytest.approx(dry.total_s)
    finally:
        store.close()


def test_the_cached_isinstance_answers_as_typing_does():
    """Capabilities decide isinstance from the type and cache it; an instance's own attributes
    and `__getattr__` proxies still count, as with typing's runtime check."""
    import typing

    class Bare:
        pass

    class Proxy:
        def __init__(self, inner):
            self._inner = inner

        def __getattr__(self, name):
            return getattr(self._inner, name)

    lab = FakeLab()
    bare, patched = Bare(), Bare()
    patched.recover = lambda: None
    cases = [bare, patched, lab.rotator, lab.sphere, lab.radiometer, Proxy(lab.rotator),
             Proxy(bare)]
    for obj in cases:
        for cap in caps.CAPABILITIES:
            expected = all(hasattr(obj, n) for n in typing._get_protocol_attrs(cap))
            assert isinstance(obj, cap) is expected, (obj, cap)
            assert isinstance(obj, cap) is expected, (obj, cap)       # cached answer
    assert isinstance(patched, caps.Recoverable) and not isinstance(bare, caps.Recoverable)
    assert isinstance(Proxy(lab.rotator), caps.Movable)
