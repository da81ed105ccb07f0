"""The shipped protocols: declared plans, keys, order, parameters; run on fakes."""

from __future__ import annotations

import pytest
from engine_fakes import FakeLab, add_gonio

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.store import Store
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import SpectralReading


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "p.sqlite")
    yield s
    s.close()


@pytest.mark.parametrize("name, planned", [("reference-sweep", 312), ("brdf-inplane", 25 * 153),
                                           ("light-map", 25), ("repeatability", 10)])
def test_shipped_protocols_declare_their_plans(name, planned):
    module = eng.load_protocol(name)
    assert module.__doc__ and isinstance(module.PARAMETERS, dict)
    plan = eng.build_plan(name)
    assert plan.planned == planned
    assert len({s.key for s in plan.steps}) == len(plan.steps)


def test_reference_sweep_is_angle_major_with_keys_and_state():
    plan = eng.build_plan("reference-sweep")
    keys = plan.commit_keys
    assert keys[:2] == ["a30/p01", "a30/p02"] and keys[23] == "a30/p24" and keys[24] == "a35/p01"
    assert keys[-1] == "a90/p24"
    angles = [int(k[1:3]) for k in keys]
    assert angles == sorted(angles)
    step = next(s for s in plan.steps if s.key == "a45/p07")
    assert dict(step.requires) == {"rotator": 45.0, "sample": "patch:7", "sphere": "stable"}
    assert step.params["patch_name"] == "orange"
    place = next(s for s in plan.steps if s.key == "a45/p07/place")
    assert place.params["message"] == "place patch 7 (orange)"


def test_brdf_inplane_geometry_and_calibration_per_material():
    plan = eng.build_plan("brdf-inplane")
    p07 = [s for s in plan.steps if s.key.startswith("p07/") and s.commits]
    assert len(p07) == 153 == 9 * 17
    assert {(s.params["theta_i_deg"], s.params["theta_o_deg"]) for s in p07} == {
        (float(i), float(o)) for i in range(-80, 1, 10) for o in range(-80, 81, 10)}
    assert "p07/i-80/o+40" in plan.commit_keys and "wall/i+0/o-10" in plan.commit_keys
    cal = next(s for s in plan.steps if s.key == "wall/calibrate")
    assert cal.kind == "calibrate" and dict(cal.requires) == {"gonio_sample": "wall"}


def test_parameters_from_lab_defaults_and_overrides(tmp_path):
    module = eng.load_protocol("repeatability")
    params = eng.resolve_parameters(module, {"repeats": 4}, {"threshold_percent": 0.5})
    assert params["repeats"] == 4 and params["threshold_percent"] == 0.5
    with pytest.raises(eng.PlanError, match="unknown parameter"):
        eng.resolve_parameters(module, None, {"repeat": 3})
    assert eng.coerce_param([30, 35], "[30,60]") == [30, 60]
    assert eng.coerce_param([30, 35], "30,60") == [30, 60]
    assert eng.coerce_param(1.0, "2") == 2.0 and isinstance(eng.coerce_param(1.0, "2"), float)
    assert eng.coerce_param("sphere", "lamp2") == "lamp2"
    assert eng.coerce_param([1, "wall"], "[3, \"wall\"]") == [3, "wall"]
    assert eng.coerce_param(10, "4") == 4 and isinstance(eng.coerce_param(10, "4"), int)


@pytest.mark.parametrize("default, text, expect", [
    ([30, 35], "[30,", "angles_deg: '[30,' has an unbalanced bracket"),
    ([30, 35], "[30, \"x\"]", "angles_deg: '\"x\"' is not a number"),
    (1.0, "abc", "angles_deg: 'abc' is not a number"),
    (10, "2.5", "angles_deg: 2.5 is not a whole number"),
    (True, "yes", "angles_deg: expected true or false, got 'yes'"),
    # one reading of a list with or without brackets; digits of other scripts never numbers
    ([30, 35], "30,,60", "angles_deg: '30,,60' has an empty item"),
    ([30, 35], "[30,,60]", "angles_deg: '[30,,60]' has an empty item"),
    ([30, 35], "[٣]", "angles_deg: '٣' has digits of another script; use the digits 0-9"),
    (10, "٤٥", "angles_deg: '٤٥' has digits of another script"),
    (10, "9" * 309, "angles_deg: a 309-character number is too long (at most 40 characters)"),
    (10, "9" * 5000, "angles_deg: 5000 characters is too long (at most 4000)"),
    ([30, 35], "[" + "9" * 400 + "]", "angles_deg: a 400-character number is too long"),
    (10, "NaN", "angles_deg: NaN is not a finite number"),
    (1.0, "-Infinity", "angles_deg: -Infinity is not a finite number"),
    (1.0, "1e309", "angles_deg: 1e309 is not a finite number"),
])
def test_a_bad_parameter_is_named_with_what_it_expects(default, text, expect):
    from normbox_lab.acquire.params import ParameterError

    with pytest.raises(ParameterError) as exc:
        eng.coerce_param(default, text, "angles_deg")
    assert str(exc.value).startswith(expect), str(exc.value)
    assert "\n" not in str(exc.value) and exc.value.exit_code == 2


def test_a_user_protocol_file(tmp_path):
    path = tmp_path / "two_points.py"
    path.write_text('"""Two readings."""\n'
                    "from normbox_lab.acquire.engine import measure, move\n"
                    "PARAMETERS = {'angles_deg': [40, 50]}\n"
                    "def steps(params, lab=None):\n"
                    "    out = []\n"
                    "    for a in params['angles_deg']:\n"
                    "        out += [move(f'm{a}', 'rotator', a),\n"
                    "                measure(f'r{a}', requires={'rotator': float(a)}, angle_deg=a)]\n"
                    "    return out\n")
    plan = eng.build_plan(str(path), {"angles_deg": [10, 20, 30]})
    assert plan.commit_keys == ["r10", "r20", "r30"]
    with pytest.raises(eng.PlanError, match="unknown protocol"):
        eng.load_protocol("no-such-protocol")


def _reading(value: float) -> SpectralReading:
    return SpectralReading(RADIOMETER_WAVELENGTHS_NM,
                           [value] * RADIOMETER_WAVELENGTHS_NM.size, None, 1.0, 0.0, "x")


def test_repeatability_flags_changes_above_threshold(store):
    module = eng.load_protocol("repeatability")
    params = dict(module.PARAMETERS)
    ctx: dict = {}
    step = eng.measure("rep01")
    assert module.on_reading(params, step, _reading(1.0), ctx) == []
    assert module.on_reading(params, eng.measure("rep02"), _reading(1.009), ctx) == []
    flags = module.on_reading(params, eng.measure("rep03"), _reading(1.02), ctx)
    assert len(flags) == 1 and "+2.00 %" in flags[0]
    # through the engine: the lamp drifts 3 % down before the 4th reading → flagged and stored
    lab = FakeLab()
    plan = eng.build_plan("repeatability", {"repeats": 5}, lab)
    e = eng.Engine(lab, store, plan)
    e.subscribe(lambda ev: setattr(lab.world, "luminance_cd_m2",
                                   lambda p, a: 0.97 * 100.0) if ev.key == "rep03"
                and ev.kind == "reading-stored" else None)
    lab.world.luminance_cd_m2 = lambda p, a: 100.0
    res = e.run()
    flagged = [d["key"] for _, k, d in store.events(res.run_id) if k == "flag"]
    assert flagged == ["rep04", "rep05"]


def test_light_map_runs_and_records_positions(store):
    lab = FakeLab()
    res = eng.Engine(lab, store, eng.build_plan("light-map", None, lab)).run()
    assert res.done == 25
    r = store.reading(res.run_id, "r1c1")
    assert r.metadata["x_mm"] == -90.0 and r.metadata["y_mm"] == -80.0
    assert store.reading(res.run_id, "r3c3").metadata["x_mm"] == 0.0


def test_brdf_resume_remounts_and_recalibrates(store):
    lab = FakeLab()
    gonio = add_gonio(lab)
    small = {"materials": [3, "wall"], "theta_i_deg": [-80, 0], "theta_o_deg": [-10, 10]}
    plan = eng.build_plan("brdf-inplane", small, lab)
    e = eng.Engine(lab, store, plan)
    e.subscribe(lambda ev: e.pause() if ev.kind == "reading-stored" and ev.key ==
                "wall/i-80/o+10" else None)
    dry = e.dry_run()
    t0 = lab.clock.now_s()
    res = e.run()
    assert res.status == "paused" and res.done == 6
    assert gonio.calibrations == 2
    # after a restart, the remaining readings need the wall mounted and calibrated again
    lab2 = FakeLab()
    gonio2 = add_gonio(lab2)
    events = []
    e2 = eng.Engine(lab2, store, eng.build_plan("brdf-inplane", small, lab2))
    e2.subscribe(events.append)
    res2 = e2.run(resume=res.run_id)
    assert res2.done == 8 and res2.taken == 2
    started = [ev.key for ev in events if ev.kind == "step-started"]
    assert started == ["wall/mount", "wall/calibrate", "wall/i+0/o-10", "wall/i+0/o+10"]
    for r in store.readings(res.run_id):
        want = 3 if r.key.startswith("p03") else "wall"
        assert r.metadata["material_seen"] == want == r.metadata["calibrated_for"]
    cals = store.artifacts("calibration", run_ref=res.run_id)
    assert [a.name for a in cals] == ["p03/calibrate", "wall/calibrate", "wall/calibrate"]
    assert gonio2.calibrations == 1
    # the ETA of the full plan matched what the first segment + a full run would take
    assert dry.total_s == pytest.approx(2 * (30 + 3) + 8 * 4.0)
    assert lab.clock.now_s() - t0 == pytest.approx(2 * (30 + 3) + 6 * 4.0)


# --- declared kinds and limits ---------------------------------------------------------------

@pytest.mark.parametrize("name", ["reference-sweep", "brdf-inplane", "light-map", "repeatability"])
def test_every_shipped_protocol_declares_the_limits_of_every_parameter(name):
    module = eng.load_protocol(name)
    assert set(module.LIMITS) == set(module.PARAMETERS)


@pytest.mark.parametrize("protocol, params, expect", [
    ("reference-sweep", {"angles_deg": [30, float("inf")]},
     "angles_deg: Infinity is not a finite number"),
    ("reference-sweep", {"angles_deg": [float("nan")]}, "angles_deg: NaN is not a finite number"),
    ("reference-sweep", {"angles_deg": [-30, 60]},
     "angles_deg: -30° is outside 0…95° (the rotator's range, lab config)"),
    ("reference-sweep", {"angles_deg": [30, 400]}, "angles_deg: 400° is outside 0…95°"),
    ("reference-sweep", {"angles_deg": [30, 1e308]}, "angles_deg: 1e+308° is outside 0…95°"),
    ("reference-sweep", {"angles_deg": []}, "angles_deg: the list is empty"),
    ("reference-sweep", {"patches": []}, "patches: the list is empty; give at least one value"),
    ("reference-sweep", {"patches": [25]}, "patches: 25 is not a patch number (1–24)"),
    ("reference-sweep", {"patches": [0]}, "patches: 0 is not a patch number (1–24)"),
    ("reference-sweep", {"patches": [7.5]}, "patches: 7.5 is not a patch number (1–24)"),
    ("reference-sweep", {"lamp_timeout_s": -1.0}, "lamp_timeout_s: -1 s must be > 0"),
    ("reference-sweep", {"rotator": "turntable"},
     "rotator: 'turntable' is not an instrument of this lab"),
    ("repeatability", {"repeats": -5}, "repeats: -5 is not a positive count (≥ 1)"),
    ("repeatability", {"repeats": 0}, "repeats: 0 is not a positive count (≥ 1)"),
    ("repeatability", {"angle_deg": 120.0}, "angle_deg: 120° is outside 0…95°"),
    ("repeatability", {"patch": 30}, "patch: 30 is not a patch number (1–24)"),
    ("repeatability", {"threshold_percent": 0.0}, "threshold_percent: 0 % must be > 0"),
    ("light-map", {"rows": 0}, "rows: 0 is not a positive count (≥ 1)"),
    ("light-map", {"margin_mm": -2.0}, "margin_mm: -2 mm must be ≥ 0"),
    ("brdf-inplane", {"theta_o_deg": [0, 100]},
     "theta_o_deg: 100° is outside -90…90° (the gonio_detector_arm's range, lab config)"),
    ("brdf-inplane", {"materials": [3, 99]},
     "materials: 99 is not a patch number (1–24, or a material name)"),
    ("brdf-inplane", {"materials": []}, "materials: the list is empty"),
])
def test_a_value_outside_its_declared_limits_is_one_line_naming_field_and_limit(
        protocol, params, expect):
    """Checked where the plan is built (command line, console and scripts alike), against the
    lab config of the instrument that will move."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.protocols._common import ParameterError

    config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    module = eng.load_protocol(protocol)
    full = eng.resolve_parameters(module, None, params)
    with pytest.raises(ParameterError) as exc:
        module.steps(full, config)
    assert str(exc.value).startswith(expect), str(exc.value)
    assert "\n" not in str(exc.value) and exc.value.exit_code == 2
    # without a lab the kinds are still checked (no ranges then)
    if "outside" not in expect and "instrument of this lab" not in expect:
        with pytest.raises(ParameterError):
            eng.build_plan(protocol, params)


def test_angle_limits_come_from_the_lab_config_else_the_drivers_default():
    from dataclasses import replace

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.protocols._common import angle_limits_deg

    config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    assert angle_limits_deg(config, "rotator") == (0.0, 95.0, "lab config")
    rot = config.instruments["rotator"]
    bare = replace(config, instruments={**config.instruments, "rotator": replace(
        rot, options={k: v for k, v in rot.options.items() if "angle" not in k})})
    assert angle_limits_deg(bare, "rotator") == (-170.0, 170.0, "apt-k10cr1 default")
    assert angle_limits_deg(config, "no-such-role") is None
    plan = eng.build_plan("reference-sweep", {"angles_deg": [150], "patches": [7]}, bare)
    assert plan.commit_keys == ["a150/p07"]
