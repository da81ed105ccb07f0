"""The device contract: each driver has exactly the capabilities it claims, the engine and the
console reach instruments only through `isinstance(inst, Capability)`, and a step an
instrument cannot do fails as a typed plan error."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
from engine_fakes import FakeGonio, FakeLab

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.registry import driver_class, drivers_for
from normbox_lab.acquire.store import Store
from normbox_lab.core import capabilities as caps
from normbox_lab.drivers.gonio import Gonioreflectometer
from normbox_lab.drivers.qepro import QEPro
from normbox_lab.drivers.rotator_apt import AptRotationStage
from normbox_lab.drivers.rotator_zaber import ZaberRotationStage
from normbox_lab.drivers.sphere import SphereLightSource

BASIC = {"Identifiable", "Closable", "HealthPollable"}
#: every radiometer driver of the registry claims the same (a new model needs no line here)
RADIOMETERS = [driver_class(name) for name in drivers_for("radiometer")]
CLAIMS = {
    **{cls: BASIC | {"RemoteControllable", "SpectrumReadable", "Abortable", "Recoverable"}
       for cls in RADIOMETERS},
    AptRotationStage: BASIC | {"Movable", "Homeable", "Stoppable"},
    ZaberRotationStage: BASIC | {"Movable", "Homeable", "Stoppable"},
    SphereLightSource: BASIC | {"Switchable", "LampLevel", "LampMonitor", "Settling", "Abortable"},
    QEPro: BASIC | {"TemperatureReadable"},
    Gonioreflectometer: BASIC | {"BrdfReadable", "Calibratable", "Stoppable"},
}
ROLES = {
    **dict.fromkeys(RADIOMETERS, caps.Spectroradiometer),
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
                  "quality", "operator")
PROBE = re.compile(r"\b(hasattr|getattr)\s*\(")


def _code_strings_and_calls(tree: ast.AST) -> tuple[list[str], list[str]]:
    """String constants of the code (docstrings left out) and the names of functions called."""
    docstrings = {id(body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                       ast.AsyncFunctionDef))
                  for body in [node.body] if body and isinstance(body[0], ast.Expr)
                  and isinstance(body[0].value, ast.Constant)}
    strings = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str) and id(n) not in docstrings]
    calls = [n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call)
             and isinstance(n.func, ast.Name)]
    return strings, calls


@pytest.mark.parametrize("name", ENGINE_MODULES)
def test_engine_operator_and_gates_ask_capabilities_not_names(name):
    """No hasattr/getattr probe and no hard-coded lamp role ("sphere") in the engine, the
    operators and the quality gates: they ask the capabilities (`LabAccess.light_sources`,
    `isinstance(inst, Settling)`) and the world's Protocol (`OperatorWorld`)."""
    path = Path(eng.__file__).parent / f"{name}.py"
    strings, calls = _code_strings_and_calls(ast.parse(path.read_text(encoding="utf-8")))
    assert not {"hasattr", "getattr"} & set(calls), f"acquire/{name}.py probes with hasattr/getattr"
    sphere = [s for s in strings if re.search(r"\bsphere\b", s)]
    assert sphere == [], f"acquire/{name}.py names the sphere: {sphere}"


def test_the_ast_check_sees_a_probe_and_a_role_literal():
    strings, calls = _code_strings_and_calls(ast.parse(
        '"""the sphere (a docstring)"""\nif hasattr(x, "y"): lab.instrument("sphere")\n'))
    assert calls == ["hasattr"] and strings == ["y", "sphere"]


def test_the_console_never_probes_instruments_by_attribute_name():
    controller = (Path(eng.__file__).parent.parent / "tui" / "controller.py").read_text(
        encoding="utf-8")
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
