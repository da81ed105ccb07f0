"""Lab assembly, the analytic world and the virtual operator."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.acquire import lab as labmod
from normbox_lab.acquire import registry
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.engine import PromptRequest
from normbox_lab.acquire.operator import TerminalOperator, VirtualOperator
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import ConfigError, NormboxError
from normbox_lab.sim import core, labsim
from normbox_lab.sim.analytic_world import AnalyticWorld, colorchecker_reflectances


@pytest.fixture(scope="module")
def world():
    return AnalyticWorld()


def test_build_lab_shares_clock_and_world_with_the_sim_context():
    cfg = parse_config(SIM_CONFIG_TEMPLATE)
    lab = labsim.build_lab(cfg, world="analytic")
    assert isinstance(lab.clock, VirtualClock) and lab.clock.time_scale == 0.0
    assert core.CONTEXT.clock is lab.clock and core.CONTEXT.world is lab.world
    assert isinstance(lab.world, AnalyticWorld)
    assert isinstance(lab.operator, VirtualOperator) and lab.operator.world is lab.world
    assert "gonio" in lab.roles()
    with pytest.raises(NormboxError, match="unknown driver"):
        labmod.driver_class("cs9000")
    with pytest.raises(NormboxError, match="unknown world"):
        labsim.build_lab(cfg, world="mars")


def test_missing_role_is_a_config_error():
    cfg = parse_config(SIM_CONFIG_TEMPLATE.split("[instruments.gonio_light_arm]")[0])
    lab = labsim.build_lab(cfg, world="none")
    with pytest.raises(ConfigError, match="spectrometer"):
        lab.instrument("spectrometer")


# --- the one driver registry: options come from the drivers' signatures ------------------------

_SAMPLE = {int: 3, float: 2.5, bool: True, str: "x"}


@pytest.mark.parametrize("name", sorted(registry.DRIVERS))
def test_every_registered_option_is_a_keyword_the_driver_takes(name):
    """Each derived option binds to the driver's open() (or the __init__ it forwards to), with
    the type its annotation names, and a config table holding all of them is accepted."""
    import inspect

    cls = registry.driver_class(name)
    options = registry.driver_options(name)
    assert options, name
    open_params = inspect.signature(cls.open).parameters
    init_params = inspect.signature(cls.__init__).parameters
    for key, typ in options.items():
        param = open_params.get(key) or init_params[key]
        if key not in open_params:        # forwarded: open() takes **options
            assert any(p.kind == p.VAR_KEYWORD for p in open_params.values()), (name, key)
        assert param.kind in (param.KEYWORD_ONLY, param.POSITIONAL_OR_KEYWORD), (name, key)
        assert typ.__name__ in str(param.annotation), (name, key, param.annotation)
        if param.default is not inspect.Parameter.empty and param.default is not None:
            assert isinstance(param.default, typ) or (typ is float and isinstance(
                param.default, int)), (name, key, param.default)
    assert not set(options) & set(registry.DRIVERS[name].internal)
    role = registry.DRIVERS[name].roles[0]
    baud = (registry.DRIVERS[name].baud_rates or (9600,))[0]     # a rate the entry allows
    values = {k: (baud if k == "baud" else -10.0 if k == "min_angle_deg" else _SAMPLE[t])
              for k, t in options.items()}
    text = SIM_CONFIG_TEMPLATE.split(f"[instruments.{role}]")[0] + f"[instruments.{role}]\n" + \
        f'driver = "{name}"\nport = "sim://x"\n' + "".join(
            f"{k} = {str(v).lower() if isinstance(v, bool) else repr(v).replace(chr(39), chr(34))}\n"
            for k, v in values.items()) + SIM_CONFIG_TEMPLATE.split(f"[instruments.{role}]")[1] \
        .split("\n[", 1)[1].join(["\n[", ""])
    cfg = parse_config(text)
    assert cfg.instruments[role].options == values


def test_a_keyword_added_to_a_driver_is_an_option_and_a_missing_one_is_refused(monkeypatch):
    class Radiometer9000:
        @classmethod
        def open(cls, url: str, clock: object, *, integration_s: float = 1.0,
                 callback: object = None, **options: object) -> Radiometer9000:
            return cls(**options)

        def __init__(self, *, gain: int | None = None, secret: bool = False) -> None:
            self.gain = gain

    import sys
    import types

    module = types.ModuleType("radiometer9000")
    module.Radiometer9000 = Radiometer9000
    monkeypatch.setitem(sys.modules, "radiometer9000", module)
    monkeypatch.setattr(registry, "DRIVERS", {**registry.DRIVERS, "cs9000": registry.DriverEntry(
        "radiometer9000", "Radiometer9000", ("radiometer",), internal=("secret",))})
    # (an object-typed keyword is the program's; `internal` ones are too)
    assert registry.driver_options("cs9000") == {"integration_s": float, "gain": int}
    assert "cs9000" in registry.drivers_for("radiometer")
    base = SIM_CONFIG_TEMPLATE.replace('driver = "cs1000a"      # cs1000a | cs2000a',
                                       'driver = "cs9000"').replace("baud = 9600", "gain = 4")
    assert parse_config(base).instruments["radiometer"].options == {"gain": 4}
    with pytest.raises(ConfigError, match=r"instruments\.radiometer\.secret.*unknown option"):
        parse_config(base.replace("gain = 4", "secret = true"))
    with pytest.raises(ConfigError, match="instruments.radiometer.driver"):
        parse_config(base.replace('driver = "cs9000"', 'driver = "qepro"'))


def test_an_angle_limit_on_the_spectrometer_is_a_config_error_not_a_type_error():
    """`max_angle_deg = -1` under [instruments.spectrometer] raised TypeError from the QE Pro's
    constructor when the lab opened it; the registry knows the QE Pro takes no angle limit."""
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://qepro"',
                                       'port = "sim://qepro"\nmax_angle_deg = -1')
    with pytest.raises(ConfigError, match=r"instruments\.spectrometer\.max_angle_deg.*unknown"):
        parse_config(text)


def test_colorchecker_reflectances_come_from_colour_science(world):
    refl = colorchecker_reflectances()
    assert refl.shape == (24, 401)
    white, black = refl[18], refl[23]
    assert 0.8 < white.mean() < 0.95 and black.mean() < 0.05
    # red (15) reflects more at 650 nm than at 450 nm, blue (13) the other way round
    assert refl[14][270] > 3 * refl[14][70] and refl[12][70] > 3 * refl[12][270]


def test_analytic_radiance_is_direct_cosine_plus_constant_indirect(world):
    w = world
    w.place_patch(19)
    w.set_sample_angle(30.0)
    _, l30 = w.radiance_in_view()
    w.set_sample_angle(90.0)
    _, l90 = w.radiance_in_view()
    ratio = (w.direct_sr * np.cos(np.radians(30)) + w.indirect_sr) / w.indirect_sr
    np.testing.assert_allclose(l30 / l90, ratio, rtol=1e-12)
    # Lambertian: radiance = ρ/π · L_panel · geometry
    np.testing.assert_allclose(l90, w.reflectance[18] / np.pi * w.panel_W_sr_m2_nm
                               * w.indirect_sr, rtol=1e-12)
    assert w.luminance_cd_m2(19, 30.0) > w.luminance_cd_m2(19, 90.0) > w.luminance_cd_m2(24, 90)
    wl = np.array([500.0, 600.0])
    w.mount_gonio_material(19)
    np.testing.assert_allclose(w.brdf_truth(10, 20, 4, wl),
                               np.interp(wl, w.wavelength_nm, w.reflectance[18]) / np.pi)
    w.mount_gonio_material("wall")
    np.testing.assert_allclose(w.brdf_truth(10, 20, 4, wl), 0.34 / np.pi)


def test_panel_map_is_brightest_in_the_centre(world):
    w = world
    w.aim_panel(0, 0)
    _, centre = w.radiance_in_view()
    w.aim_panel(90, 80)
    _, corner = w.radiance_in_view()
    assert 0.95 < corner.sum() / centre.sum() < 1.0
    w.place_patch(1)           # placing a patch points the radiometer back at the sample
    assert w.aim is None


def test_virtual_operator_acts_on_the_world_and_answers_faults(world):
    clock = VirtualClock()
    op = VirtualOperator(world, clock, fault_policy="retry", response_s=4.0,
                         max_fault_retries=2)
    assert op(PromptRequest(1, "a30/p05/place", "operator", "place patch 5", ("ok",),
                            {"action": "place_patch", "patch": 5})) == "ok"
    assert world.patch == 5 and clock.now_s() == 4.0
    fault = PromptRequest(2, "a30/p05", "fault", "timeout", ("retry", "skip", "abort"), {})
    assert [op(fault) for _ in range(3)] == ["retry", "retry", "skip"]
    with pytest.raises(ValueError):
        VirtualOperator(world, clock, fault_policy="pray")


def test_virtual_operator_answers_only_what_the_prompt_offers(world):
    """Preparing an instrument (an APT/Zaber power blip while homing) offers retry / abort:
    once its retries are used up the virtual operator aborts, it never answers 'skip' (which
    stopped the run with "operator answered 'skip'; expected one of retry, abort")."""
    op = VirtualOperator(world, VirtualClock(), fault_policy="retry", max_fault_retries=2)
    prepare = PromptRequest(1, "prepare/rotator", "fault", "power blip", ("retry", "abort"), {})
    assert [op(prepare) for _ in range(3)] == ["retry", "retry", "abort"]
    skipper = VirtualOperator(world, VirtualClock(), fault_policy="skip")
    assert skipper(prepare) == "abort"


def test_the_operator_world_is_a_protocol_not_probed_attribute_by_attribute(world):
    from normbox_lab.acquire.operator import OperatorWorld

    assert isinstance(world, OperatorWorld)

    class PatchesOnly:
        def place_patch(self, n: int) -> None: ...

    with pytest.raises(NormboxError, match="PatchesOnly"):
        VirtualOperator(PatchesOnly(), VirtualClock())
    # a material given as (ASCII) digits is that patch
    op = VirtualOperator(world, VirtualClock())
    op(PromptRequest(1, "m", "operator", "mount", ("ok",),
                     {"action": "mount_gonio_material", "material": "7"}))
    assert world.gonio_material == "patch-7"


def test_terminal_operator_reads_answers():
    import io

    out = io.StringIO()
    op = TerminalOperator(io.StringIO("x\nsk\n"), out)
    req = PromptRequest(1, "k", "fault", "it broke", ("retry", "skip", "abort"), {})
    assert op(req) == "skip" and "please answer" in out.getvalue()
    assert TerminalOperator(io.StringIO("\n"), io.StringIO())(req) == "retry"
    assert TerminalOperator(io.StringIO(""), io.StringIO())(req) == "abort"
    # in a simulated lab, the person at the terminal places the virtual patch by answering ok
    world = AnalyticWorld()
    place = PromptRequest(2, "a30/p04/place", "operator", "place patch 4", ("ok",),
                          {"action": "place_patch", "patch": 4})
    assert TerminalOperator(io.StringIO("\n"), io.StringIO(), world=world)(place) == "ok"
    assert world.patch == 4


# --- the run command, end to end, with fake drivers behind the lab assembly ---------------------

# (the `fake_drivers` fixture is in conftest.py)

def test_run_command_dry_run_pause_and_resume(fake_drivers, capsys):
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store
    from normbox_lab.cli import main

    store = str(fake_drivers / "cli.sqlite")
    common = ["--world", "analytic", "--store", store, "--param", "angles_deg=[30,90]",
              "--param", "patches=1,19"]
    assert main(["run", "reference-sweep", "--dry-run", *common]) == 0
    from pathlib import Path

    assert not Path(store).exists()          # a dry run only reads: no store is created
    out, err = capsys.readouterr()
    assert "using the simulated lab template" in err
    assert "4 readings" in out and "a90/p19" in out and out.strip().splitlines()[-1].startswith("ETA")

    # pause after the second reading (what Ctrl-C does), then resume from the printed id
    original = eng.Engine.run

    def run_and_pause(self, resume=None):
        self.subscribe(lambda ev: self.pause() if ev.kind == "reading-stored"
                       and ev.key == "a30/p19" else None)
        return original(self, resume)
    eng.Engine.run = run_and_pause
    try:
        assert main(["run", "reference-sweep", "--plain", *common]) == 3    # paused: incomplete
    finally:
        eng.Engine.run = original
    out = capsys.readouterr().out
    assert "paused, 2/4 readings" in out
    resume_line = out.splitlines()[-1]
    assert resume_line.startswith("run 1 paused before a90/p01 — resume with: normbox-lab run "
                                  "reference-sweep --resume 1 --store ")
    run_id = resume_line.split("--resume ")[1].split()[0]
    assert main(["run", "--resume", run_id, "--store", store, "--plain"]) == 0   # same world
    out = capsys.readouterr().out
    assert "done, 4/4 readings (2 taken now)" in out
    with Store(store) as s:
        (run,) = s.runs()
        assert run.status == "done" and s.keys(run.id) == {"a30/p01", "a30/p19", "a90/p01",
                                                             "a90/p19"}
        assert run.parameters["angles_deg"] == [30, 90]
        segs = [d for _, k, d in s.events(run.id) if k == "segment"]
        assert [d["world"] for d in segs] == ["analytic", "analytic"]
    assert main(["run", "--resume", run_id, "--store", store, "--param", "patches=[2]"]) == 2


def test_world_follows_attached_emulators_and_gonio_names():
    class Rot:
        def angle_deg(self):
            return 30.0

    class Sphere:
        def relative_output(self):
            return 0.5

    w = AnalyticWorld()
    w.place_patch(19)
    w.attach_rotator(Rot())
    w.attach_sphere(Sphere())
    _, seen = w.radiance_in_view()
    np.testing.assert_allclose(seen, 0.5 * w.radiance_at(19, 30.0))
    op = VirtualOperator(w, VirtualClock())
    op(PromptRequest(1, "p07/mount", "operator", "mount", ("ok",),
                     {"action": "mount_gonio_material", "material": 7}))
    assert w.gonio_material == "patch-7"
    wl = np.array([550.0])
    np.testing.assert_allclose(w.brdf_truth(0, 10, 4, wl),
                               np.interp(wl, w.wavelength_nm, w.reflectance[6]) / np.pi)


def test_luminance_hint_is_closed_form_for_any_world():
    from normbox_lab.acquire import engine as eng

    cfg = parse_config(SIM_CONFIG_TEMPLATE)
    lab = labsim.build_lab(cfg, world="none")
    step = eng.build_plan("reference-sweep").steps[2]            # a30/p01/place … a30/p01
    meas = next(s for s in eng.build_plan("reference-sweep").steps if s.key == "a30/p19")
    ref = AnalyticWorld().luminance_cd_m2(19, 30.0)
    assert lab.luminance_hint_cd_m2(meas) == pytest.approx(ref)
    assert lab.luminance_hint_cd_m2(eng.measure("x", luminance_cd_m2=7.0)) == 7.0
    panel = next(s for s in eng.build_plan("light-map").steps if s.key == "r3c3")
    assert lab.luminance_hint_cd_m2(panel) == pytest.approx(3000.0 * 1.03, rel=0.02)
    assert step.kind == "prompt"


# --- the simulated lab end to end: wire-level emulators, analytic world -------------------------

def _sim_lab():
    return labsim.build_lab(parse_config(SIM_CONFIG_TEMPLATE), world="analytic")


def test_reference_sweep_on_the_simulated_lab_sees_the_right_patch_and_angle(tmp_path):
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store

    lab = _sim_lab()
    with Store(tmp_path / "s.sqlite") as store:
        plan = eng.build_plan("reference-sweep", {"angles_deg": [30, 90],
                                                  "patches": [2, 19, 24]}, lab)
        e = eng.Engine(lab, store, plan)
        eta = e.dry_run().total_s
        t0 = lab.clock.now_s()
        res = e.run()
        elapsed = lab.clock.now_s() - t0
        assert res.status == "done" and res.done == 6
        # the ETA from the drivers' timing models (worst-case homing included)
        assert abs(elapsed - eta) / eta < 0.08
        for r in store.readings(res.run_id):
            truth = lab.world.radiance_at(r.metadata["patch"], r.metadata["angle_deg"])
            ratio = np.median(r.arrays["radiance_W_sr_m2_nm"] / truth)
            assert abs(ratio - 1) < 0.03, (r.key, ratio)         # ±2 % radiometric + noise
        roles = {i["role"] for i in store.instruments(res.run_id)}
        assert roles == {"radiometer", "rotator", "sphere"}
    lab.close()


def test_brdf_inplane_on_the_simulated_gonio_closes_on_the_truth(tmp_path):
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store

    lab = _sim_lab()
    with Store(tmp_path / "b.sqlite") as store:
        plan = eng.build_plan("brdf-inplane", {"materials": [7, "wall"], "theta_i_deg": [-40],
                                               "theta_o_deg": [-30, 30, 60]}, lab)
        res = eng.Engine(lab, store, plan).run()
        assert res.status == "done" and res.done == 6
        for r in store.readings(res.run_id):
            m = r.metadata
            lab.world.mount_gonio_material("patch-7" if m["material"] == 7 else "wall")
            truth = lab.world.brdf_truth(m["theta_i_deg"], m["theta_o_deg"], 4.0,
                                         r.arrays["wavelength_nm"])
            assert abs(np.median(r.arrays["brdf_per_sr"] / truth) - 1) < 0.02, r.key
        assert [a.name for a in store.artifacts("calibration", run_ref=res.run_id)] == \
            ["p07/calibrate", "wall/calibrate"]
    lab.close()


def test_simulated_lamp_instability_and_wire_faults_are_ridden_out(tmp_path):
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store

    _sim_lab()
    # the sphere's command count is deterministic on the virtual clock: ~620 polls of the
    # warm-up, then per reading its STAT? and 3 + 3 lamp-monitor samples, so the 656th command
    # lands in the middle of the first angle (652-662 all suspend a40/p07 or a40/p08)
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://sphere"',
                                       'port = "sim://sphere?faults=unstable@656:45"')
    text = text.replace('port = "sim://cs1000a"',
                        'port = "sim://cs1000a?faults=no-reply=0.05&seed=3"')
    lab = labsim.build_lab(parse_config(text), world="analytic")
    with Store(tmp_path / "f.sqlite") as store:
        plan = eng.build_plan("reference-sweep", {"angles_deg": [40, 80],
                                                  "patches": [5, 6, 7, 8, 9, 10]}, lab)
        res = eng.Engine(lab, store, plan).run()
        assert res.status == "done" and res.done == 12
        kinds = [k for _, k, _ in store.events(res.run_id)]
        assert kinds.count("suspended") == 1 and kinds.count("unsuspended") == 1
        for r in store.readings(res.run_id):
            truth = lab.world.radiance_at(r.metadata["patch"], r.metadata["angle_deg"])
            assert abs(np.median(r.arrays["radiance_W_sr_m2_nm"] / truth) - 1) < 0.03, r.key
    lab.close()
