"""Error sources of the virtual Normbox: the spec, and each switch changing exactly what it
should (and nothing when off).  The world's renderer is replaced by a closed-form stand-in
that records the angle it was asked for, so nothing renders here."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.core.error_sources import (
    GEOMETRY_FIELDS,
    PAPER_SPEC,
    SOURCE_FIELDS,
    Magnitude,
    parse_error_spec,
)
from normbox_lab.core.errors import ConfigError
from normbox_lab.predict.materials import truth_brdf_inplane, truth_material
from normbox_lab.predict.render import RenderResult
from normbox_lab.sim.world import VirtualNormbox

BANDS_NM = np.arange(380.0, 781.0, 5.0)


def stand_in_render(world: VirtualNormbox):
    asked: list[float] = []

    def render(patch, angle_deg, *, direct_only=False, quality=None):
        asked.append(float(angle_deg))
        rad = (1.0 + patch / 10) * (1.0 + 0.5 * np.sin(BANDS_NM / 40.0)) * np.cos(
            np.radians(angle_deg)) + 0.2
        return RenderResult(BANDS_NM, rad, rad * 1e-3, rad[None], 0.0, "stand-in", "")
    world.render = render
    return asked


def observe(spec: str) -> dict[str, object]:
    """Everything the error sources may touch, for one world."""
    world = VirtualNormbox(errors=spec)
    asked = stand_in_render(world)
    wl = world.wavelength_nm
    out: dict[str, object] = {}
    for patch, angle in [(19, 30.0), (13, 65.0), (19, 65.0), (13, 80.0), (19, 60.0)]:
        world.place_patch(patch)
        world.set_sample_angle(angle)
        _, rad = world.radiance_in_view()
        out[f"L{patch}@{angle:g}"] = rad
        out[f"s{patch}@{angle:g}"] = asked[-1]
    world.aim_panel(44.0, -40.0)
    out["panel"] = world.radiance_in_view()[1]
    world.mount_gonio_material("patch-7")
    out["brdf"] = np.array([world.brdf_truth(ti, to, 4.0, wl)
                            for ti, to in [(-30, 30), (-60, 10), (0, 40)]])
    out["geometry"] = world.geometry
    out["nominal"] = world.nominal_geometry
    return out


def same(a: object, b: object) -> bool:
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


OFF = None


@pytest.fixture(scope="module")
def off():
    return observe("off")


def test_all_off_is_the_truth(off):
    wl = VirtualNormbox().wavelength_nm
    assert off["s19@65"] == 65.0 and off["geometry"] == off["nominal"]
    m = truth_material("patch-7")
    assert np.array_equal(off["brdf"][0], truth_brdf_inplane(m, -30, 30, wl, 4.0))
    band = (1.2 + 0.12) * 0 + (1.0 + 19 / 10) * (1.0 + 0.5 * np.sin(BANDS_NM / 40.0)) * np.cos(
        np.radians(30.0)) + 0.2
    assert np.allclose(off["L19@30"], np.interp(wl, BANDS_NM, band), rtol=0, atol=1e-12)


#: what each source may change (keys of `observe`); everything else must stay identical
CHANGES = {
    "angle": {"L", "s"},
    "angle-sweep": {"L", "s"},
    "angle-offset": {"L13@65", "L19@65", "L13@80", "s13@65", "s19@65", "s13@80"},
    "geometry": {"geometry", "panel"},      # the light map aims by the truth aperture
    "cs1000": {"L"},
    "cs1000-wl": {"L"},
    "qepro-snr": {"brdf"},
    "qepro-nonlin": {"brdf"},
    "gonio-cal": {"brdf"},
    "homogeneity": {"geometry", "panel"},   # the light map sees the truth map
    "diffusivity": {"L"},
    "lamp": {"L"},
    "render": set(),       # acts in the demo's fast-render world (seed and target), not here
}
SPECS = {"angle": "angle=1", "angle-sweep": "angle-sweep=1",
         "angle-offset": "angle-offset=65:+0.7;80:-0.7", "geometry": "geometry=1",
         "cs1000": "cs1000=0.02", "cs1000-wl": "cs1000-wl=0.3", "qepro-snr": "qepro-snr=1000",
         "qepro-nonlin": "qepro-nonlin=0.005", "gonio-cal": "gonio-cal=0.007",
         "homogeneity": "homogeneity=0.03", "diffusivity": "diffusivity=0.026",
         "lamp": "lamp=0.01", "render": "render=0.01"}


def test_every_source_has_a_switch_test():
    assert set(CHANGES) == set(SOURCE_FIELDS) == set(SPECS)


@pytest.mark.parametrize("name", list(SOURCE_FIELDS))
def test_each_switch_changes_exactly_its_part(name, off):
    on = observe(SPECS[name])
    allowed = CHANGES[name]
    for key, value in on.items():
        may = key in allowed or any(key.startswith(a) and a in ("L", "s") for a in allowed)
        if key == "nominal":
            may = False
        if not may:
            assert same(value, off[key]), f"{name} changed {key}"
    changed = [k for k in on if not same(on[k], off[k])]
    if name == "render":
        assert changed == []
    elif name == "angle-offset":
        assert set(changed) == allowed
    else:
        assert changed, f"{name} changed nothing"


def test_angle_offsets_are_exact_and_shared_by_patches():
    on = observe("angle-offset=65:+0.7;80:-0.7")
    assert on["s13@65"] == pytest.approx(65.7) and on["s19@65"] == pytest.approx(65.7)
    assert on["s13@80"] == pytest.approx(79.3) and on["s19@60"] == 60.0


def test_random_angle_error_per_reading_and_sweep_misadjustment_per_angle():
    rnd = observe("angle=1")
    assert rnd["s13@65"] != rnd["s19@65"]
    assert all(abs(rnd[f"s{k}"] - float(k.split("@")[1])) <= 1.0
               for k in ("13@65", "19@65", "13@80", "19@30"))
    sweep = observe("angle-sweep=1")
    assert sweep["s13@65"] == sweep["s19@65"] != 65.0


def test_radiometer_gain_and_shift(off):
    gain = observe("cs1000=0.02")
    r = gain["L19@30"] / off["L19@30"]
    assert np.allclose(r, r[0]) and 0.98 <= r[0] <= 1.02 and r[0] != 1.0
    assert gain["L19@30"][0] / off["L19@30"][0] != gain["L13@65"][0] / off["L13@65"][0]
    shift = observe("cs1000-wl=0.3")
    d = shift["L19@30"] - off["L19@30"]
    slope = np.gradient(off["L19@30"])
    k = np.sum(d[5:-5] * slope[5:-5]) / np.sum(slope[5:-5] ** 2)
    assert 0 < abs(k) <= 0.3 and np.allclose(d[5:-5], k * slope[5:-5], atol=2e-3)


def test_light_gains_spare_the_light_map(off):
    for spec, bound in [("lamp=0.01", 0.01), ("diffusivity=0.026", 0.026),
                        ("lamp=+0.01", 0.01)]:
        on = observe(spec)
        ratios = [on[k] / off[k] for k in on if k.startswith("L")]
        g = ratios[0][0]
        assert all(np.allclose(r, g) for r in ratios) and 0 < abs(g - 1) <= bound + 1e-12
        assert np.array_equal(on["panel"], off["panel"])
    assert observe("lamp=+0.01")["L19@30"][0] / off["L19@30"][0] == pytest.approx(1.01)


def test_geometry_and_homogeneity_move_only_their_fields(off):
    g = observe("geometry=1")["geometry"]
    nominal = off["nominal"]
    for f in GEOMETRY_FIELDS:
        assert 0 < abs(getattr(g, f) - getattr(nominal, f)) <= 1.0
    assert g.radiometer_distance_mm == nominal.radiometer_distance_mm
    h = observe("homogeneity=+0.03")["geometry"]
    assert h.panel_homogeneity_percent == pytest.approx(nominal.panel_homogeneity_percent + 3)
    assert h.sample_height_mm == nominal.sample_height_mm


def test_gonio_calibration_nonlinearity_noise(off):
    cal = observe("gonio-cal=+0.007")["brdf"] / off["brdf"]
    assert np.allclose(cal, 1.007)
    nl = observe("qepro-nonlin=0.005")["brdf"] / off["brdf"]
    for row, f in zip(nl, off["brdf"]):
        assert row.min() == pytest.approx(0.995, abs=1e-12)        # at the reading's peak
        assert np.allclose(row, 1 - 0.005 * f / f.max())
    snr = observe("qepro-snr=1000")["brdf"]
    rel = (snr - off["brdf"]) / np.sqrt(off["brdf"] * off["brdf"].max(axis=1, keepdims=True))
    assert 0.5e-3 < np.std(rel) < 2e-3


def test_fast_world_renders_with_its_own_random_numbers():
    from normbox_lab.predict.fastrender import config_seed
    from normbox_lab.sim.fast_world import PREDICTION_SEED, TRUTH_REL_SE, FastVirtualNormbox
    from normbox_lab.sim.world import TRUTH_RENDER_SEED

    calls = []

    class Fast:
        def render_view(self, **kw):
            calls.append((kw["seed"], kw["target_rel_se"]))

    for spec in ("off", "render=0.01", "render=0.01,seed=5"):
        w = FastVirtualNormbox(errors=spec, fast=Fast())
        w.render(19, 30.0)
    # the quality's target, or the render source's; never the prediction's seed
    assert [t for _, t in calls] == [TRUTH_REL_SE["default"], 0.01, 0.01]
    assert calls[0][0] == config_seed(TRUTH_RENDER_SEED + 1, "patch-19@30")
    assert calls[2][0] == config_seed(TRUTH_RENDER_SEED + 5, "patch-19@30")
    assert config_seed(PREDICTION_SEED, "patch-19@30") not in {s for s, _ in calls}
    # common random numbers only when asked for
    w = FastVirtualNormbox(errors="off", fast=Fast(), render_seed=PREDICTION_SEED)
    w.render(19, 30.0)
    assert calls[-1][0] == config_seed(PREDICTION_SEED, "patch-19@30")


# --- the spec -----------------------------------------------------------------------------------
def test_spec_round_trip_and_paper():
    e = parse_error_spec("angle=1.0,angle-offset=65:+0.7;80:-0.7,cs1000=0.02,lamp=+0.01")
    assert e.angle_deg == Magnitude(1.0) and e.lamp_repeatability == Magnitude(0.01, True)
    assert e.angle_offset_deg == {65.0: 0.7, 80.0: -0.7}
    assert parse_error_spec(e.spec()) == e
    paper = parse_error_spec("paper")
    assert set(paper.on_names()) == set(SOURCE_FIELDS) - {"angle", "angle-sweep", "render"}
    assert paper.angle_offset_deg == {65.0: -0.3, 80.0: 0.3}
    assert parse_error_spec(PAPER_SPEC) == paper
    assert parse_error_spec("all=paper,cs1000=off").cs1000_gain == Magnitude()
    assert not parse_error_spec("off").any_on


@pytest.mark.parametrize("spec, field", [
    ("angle=abc", "errors.angle"), ("bogus=1", "errors.bogus"), ("cs1000", "errors.cs1000"),
    ("angle-offset=65+0.7", "errors.angle-offset"), ("qepro-snr=-3", "errors.qepro-snr"),
    ("lamp=nan", "errors.lamp"), ("geometry=1mm", "errors.geometry")])
def test_spec_errors_name_the_field(spec, field):
    with pytest.raises(ConfigError) as exc:
        parse_error_spec(spec)
    assert exc.value.field == field and field in str(exc.value)


def test_lab_config_errors_table(tmp_path):
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config

    text = SIM_CONFIG_TEMPLATE.replace("[render]", '[render]\nerrors = "angle-offset=65:+0.7"')
    cfg = parse_config(text, str(tmp_path / "lab.toml"))
    world = VirtualNormbox(config=cfg)
    assert world.errors.angle_offset_deg == {65.0: 0.7}
    world = VirtualNormbox(config=cfg, errors="cs1000=0.02")     # on top of the config's
    assert world.errors.angle_offset_deg == {65.0: 0.7} and world.errors.cs1000_gain.on
    bad = SIM_CONFIG_TEMPLATE.replace("[render]", '[render]\nerrors = "lamp=x"')
    with pytest.raises(ConfigError, match="errors.lamp"):
        VirtualNormbox(config=parse_config(bad, "lab.toml"))


def test_cli_rejects_a_bad_spec_before_running(tmp_path, capsys):
    from normbox_lab.cli import main

    rc = main(["demo", "--quick", "--errors", "cs1000=two", "--out", str(tmp_path / "o")])
    assert rc == 2 and "errors.cs1000" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
