"""The virtual Normbox's physics: materials, the Mitsuba BSDF, the scene, the renderer and cache.

Renders use the "quick" quality (sub-second once Mitsuba's kernels are compiled; the first run
on a machine compiles them, ~20–40 s per kernel, cached by Dr.Jit afterwards)."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.predict import brdf_model as bm
from normbox_lab.predict.materials import (
    HOLDER_REFLECTANCE,
    MATERIAL_WAVELENGTHS_NM,
    PATCH_NAMES,
    TRUTH_PATCH_PARAMS,
    Material,
    reflectance_from_lightness,
    truth_brdf,
    truth_brdf_inplane,
    truth_material,
    truth_patch,
    truth_wall,
)
from normbox_lab.predict.scene import as_geometry, panel_map, panel_map_at

WL = np.array([380.0, 452.5, 550.0, 633.0, 780.0])


# --- materials ------------------------------------------------------------------------------------
def test_wall_reflectance_is_the_cie_inverse_of_lightness():
    y = reflectance_from_lightness(65.0)
    assert y == pytest.approx(0.3404, abs=5e-4)
    # forward CIE L* from Y gives 65 back
    assert 116.0 * y ** (1 / 3) - 16.0 == pytest.approx(65.0, abs=1e-9)
    assert np.allclose(truth_wall().kd, y)


def test_colorchecker_numbering_follows_colour_science():
    import colour

    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    names = list(sds)
    for n in (1, 13, 18, 19, 24):
        assert names[n - 1].startswith(PATCH_NAMES[n - 1])
        sd = sds[names[n - 1]]
        assert np.allclose(truth_patch(n).kd,
                           np.interp(MATERIAL_WAVELENGTHS_NM, sd.wavelengths, sd.values))
    assert truth_patch(19).kd.mean() > 0.8
    assert truth_patch(24).kd.mean() < 0.05


def test_truth_model_materials_equal_the_fit_model_exactly():
    ti, to = bm.gonio_geometry()
    wi, wo = bm.inplane_directions(ti, to, 4.0)
    for n in (1, 18, 19):
        m = truth_patch(n, truth="model")
        assert m.is_model_family
        kd, ks, _ = m.spectra_at(WL)
        expected = bm.ct_ggx_brdf(wi, wo, kd, ks, m.alpha, m.eta, m.c)
        assert np.array_equal(truth_brdf(m, wi, wo, WL), expected)
    # and a fitted material (with c) goes through unchanged
    fit = bm.MaterialFit("patch-7", MATERIAL_WAVELENGTHS_NM, truth_patch(7).kd, 0.7, 0.3, 1.4,
                         0.002, 5.0, 2.0)
    mat = Material.from_fit(fit)
    assert np.allclose(truth_brdf(mat, wi, wo, MATERIAL_WAVELENGTHS_NM), fit.brdf(wi, wo),
                       rtol=1e-12, atol=1e-15)


def test_default_truth_is_outside_the_model_family():
    """Backscatter grows towards blue; the Fresnel reflection at grazing angles is redder."""
    wl = np.array([400.0, 700.0])
    truth, model = truth_patch(19), truth_patch(19, truth="model")
    assert not truth.is_model_family
    retro_t = truth_brdf_inplane(truth, -30.0, -30.0, wl)       # 8° from the light (tilted arms)
    retro_m = truth_brdf_inplane(model, -30.0, -30.0, wl)
    excess = retro_t / retro_m - 1.0
    assert excess[0] > 0.2 and excess[0] > 1.5 * excess[1] > 0
    # specular direction at grazing incidence: the dispersive η makes red reflect more
    spec_t = truth_brdf_inplane(truth, -80.0, 80.0, wl) - truth.kd[[4, 64]] / np.pi
    spec_m = truth_brdf_inplane(model, -80.0, 80.0, wl) - model.kd[[4, 64]] / np.pi
    assert spec_t[1] / spec_m[1] > spec_t[0] / spec_m[0]
    # the smooth patch (18) and the rough range, as documented
    assert TRUTH_PATCH_PARAMS[18][0] < 0.2
    assert all(0.3 <= p[0] <= 0.6 for n, p in TRUTH_PATCH_PARAMS.items() if n != 18)


def test_material_names():
    assert truth_material("patch-5").name == "patch-5"
    assert truth_material(5).name == "patch-5"
    assert truth_material("wall").name == "wall"
    assert np.allclose(truth_material("holder").kd, HOLDER_REFLECTANCE)
    with pytest.raises(ValueError):
        truth_material("patch-25")
    with pytest.raises(ValueError):
        truth_material("ceiling")
    assert truth_patch(3).digest() != truth_patch(4).digest()
    assert truth_patch(3).digest() == truth_patch(3).digest()
    assert truth_patch(3).digest() != truth_patch(3, "model").digest()


# --- geometry --------------------------------------------------------------------------------------
def test_geometry_from_config_objects():
    from normbox_lab.core.geometry import NormboxGeometry

    g = as_geometry(NormboxGeometry(sample_height_mm=250.0))
    assert g.sample_height_mm == 250.0 and g.box_inner_mm == 600.0

    class Lab:
        geometry = NormboxGeometry(radiometer_distance_mm=900.0)

    assert as_geometry(Lab()).radiometer_distance_mm == 900.0
    assert as_geometry(None) == NormboxGeometry()


def test_panel_map_is_plus_minus_homogeneity():
    m = panel_map(3.0)
    assert m.shape == (5, 5)
    assert np.abs(m - 1.0).max() == pytest.approx(0.03)
    assert m.min() < 0.98 and m.max() > 1.02
    assert m.mean() == pytest.approx(1.0, abs=1e-12)
    # cell centres: 44 mm in x, 40 mm in y; the centre cell is the brightest
    assert panel_map_at(0.0, 0.0) == pytest.approx(m[2, 2])
    assert panel_map_at(-88.0, -80.0) == pytest.approx(m[0, 0])
    assert panel_map_at(44.0, 40.0) == pytest.approx(m[3, 3])


# --- the Mitsuba side ------------------------------------------------------------------------------
import mitsuba as mi


def _bsdf_eval(material: Material, wi: np.ndarray, wo: np.ndarray, wl: np.ndarray) -> np.ndarray:
    import drjit as dr

    from normbox_lab.predict.mitsuba_bsdf import make_bsdf
    from normbox_lab.predict.render import ensure_variant

    ensure_variant()
    b = make_bsdf(material)
    n = len(wi)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    si.wavelengths = mi.Spectrum(*[mi.Float(np.full(n, w)) for w in wl])
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    val = b.eval(mi.BSDFContext(), si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2]))
    return np.array(val).T / np.abs(wo[:, 2:3])    # eval returns f·|cosθo|


@pytest.mark.parametrize("truth", ["model", "default"])
def test_mitsuba_bsdf_equals_the_numpy_brdf(truth):
    ti = np.array([-30.0, -60.0, -10.0, 0.0, -75.0, -40.0])
    to = np.array([30.0, 20.0, -10.0, 45.0, 70.0, -40.0])
    wi, wo = bm.inplane_directions(ti, to, 4.0)
    wl = np.array([400.0, 452.5, 550.0, 713.0])
    for n in (18, 19):
        m = truth_patch(n, truth)
        got = _bsdf_eval(m, wi, wo, wl)
        assert np.allclose(got, truth_brdf(m, wi, wo, wl), rtol=2e-4, atol=1e-7)
    # seen from behind (two-sided): the same values
    wall = truth_wall(truth)
    flip = np.array([1.0, 1.0, -1.0])
    got_back = _bsdf_eval(wall, wi * flip, wo * flip, wl)
    assert np.allclose(got_back, truth_brdf(wall, wi, wo, wl), rtol=2e-4, atol=1e-7)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("render-cache")


def _lum(r, radiance=None):
    from normbox_lab.predict.render import luminance_cd_m2

    return luminance_cd_m2(r.wavelength_nm, r.radiance if radiance is None else radiance)


def test_white_patch_at_30_matches_the_analytic_direct_light(cache_dir):
    from normbox_lab.predict.render import direct_estimate, render_view

    white, wall = truth_patch(19), truth_wall()
    est = direct_estimate(material=white, angle_deg=30.0)
    direct = render_view(patch=white, wall=wall, angle_deg=30.0, quality="quick",
                         direct_only=True, cache_dir=cache_dir)
    full = render_view(patch=white, wall=wall, angle_deg=30.0, quality="quick",
                       cache_dir=cache_dir)
    lum_est = _lum(direct, est)
    # a white patch at 30° under a 3000 cd/m² panel: ~180 cd/m² of direct light
    assert 120.0 < lum_est < 260.0
    assert _lum(direct) == pytest.approx(lum_est, rel=0.03)
    # per 50 nm block (quick quality is noisy per 5 nm band)
    r_blocks = direct.radiance[:80].reshape(8, 10).mean(axis=1)
    e_blocks = est[:80].reshape(8, 10).mean(axis=1)
    assert np.allclose(r_blocks, e_blocks, rtol=0.10)
    # the render's standard errors describe its deviation from the truth: an SE from k batches
    # makes z a Student t with k − 1 degrees of freedom (4 batches: |t| < 3 only 94 % of the time)
    from scipy import stats

    z = np.abs(direct.radiance - est) / direct.std_error
    z_99 = stats.t.ppf(0.995, len(direct.batches) - 1)
    assert np.all(np.isfinite(z)) and np.mean(z < z_99) > 0.9
    # full light within 10 % of the direct estimate at 30° (indirect light is small there)
    assert _lum(full) == pytest.approx(lum_est, rel=0.10)
    assert _lum(full) > _lum(direct)


def test_direct_light_falls_with_the_sample_angle(cache_dir):
    from normbox_lab.predict.render import direct_estimate, render_view

    white, wall = truth_patch(19), truth_wall()
    lum_render, lum_est = [], []
    for angle in (30.0, 60.0, 90.0):
        est = direct_estimate(material=white, angle_deg=angle)
        r = render_view(patch=white, wall=wall, angle_deg=angle, quality="quick",
                        direct_only=True, cache_dir=cache_dir)
        lum_render.append(_lum(r))
        lum_est.append(_lum(r, est))
    assert lum_est[0] > lum_est[1] > lum_est[2] > 0
    assert lum_render[0] > lum_render[1] > lum_render[2] > 0
    assert np.allclose(lum_render, lum_est, rtol=0.05)
    # at 90° the sample faces the radiometer and sees the panel at grazing incidence
    assert lum_est[2] / lum_est[0] < 0.12


def test_cache_hit_returns_identical_results_and_keys_differ(cache_dir, tmp_path):
    from normbox_lab.predict.render import Lamp, render_view

    kw = {"patch": truth_patch(13), "wall": truth_wall(), "angle_deg": 45.0, "quality": "quick"}
    first = render_view(cache_dir=tmp_path, **kw)
    assert not first.cached and len(list(tmp_path.glob("*.npz"))) == 1
    second = render_view(cache_dir=tmp_path, **kw)
    assert second.cached and second.key == first.key
    assert np.array_equal(second.radiance, first.radiance)
    assert np.array_equal(second.std_error, first.std_error)
    # the lamp's relative output scales a cached render, without a new file
    half = render_view(cache_dir=tmp_path, lamp=Lamp(relative_output=0.5), **kw)
    assert np.allclose(half.radiance, 0.5 * first.radiance)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    # another angle or material is another key
    other = render_view(cache_dir=tmp_path, **{**kw, "angle_deg": 50.0})
    assert other.key != first.key and not other.cached
    from normbox_lab.predict.materials import holder_material
    from normbox_lab.predict.render import QUALITIES, render_key

    k = render_key(None, truth_patch(13), truth_wall(), holder_material(), 45.0, Lamp(),
                   QUALITIES["quick"], 12, 0)
    assert k == first.key
    assert k != render_key(None, truth_patch(13, "model"), truth_wall(), holder_material(),
                           45.0, Lamp(), QUALITIES["quick"], 12, 0)


def test_renders_are_repeatable_and_the_moved_sample_matches(tmp_path):
    """Same configuration, same seed → the same numbers, also after other angles and materials
    went through the (reused) scene; a different seed is another noise realisation."""
    from normbox_lab.predict.render import render_view

    kw = {"wall": truth_wall(), "quality": "quick", "cache": False}
    a = render_view(patch=truth_patch(2), angle_deg=55.0, **kw)
    render_view(patch=truth_patch(5), angle_deg=80.0, **kw)
    b = render_view(patch=truth_patch(2), angle_deg=55.0, **kw)
    assert np.array_equal(a.radiance, b.radiance)
    c = render_view(patch=truth_patch(2), angle_deg=55.0, seed=1, **kw)
    assert not np.array_equal(a.radiance, c.radiance)
    assert _lum(c) == pytest.approx(_lum(a), rel=0.05)


def test_fitted_materials_render(cache_dir):
    """The prediction path: a fit-model material (with c) renders like its truth twin."""
    from normbox_lab.predict.render import render_view

    truth = truth_patch(19, truth="model")
    fit = Material.from_fit(bm.MaterialFit("patch-19", truth.wavelength_nm, truth.kd, truth.ks,
                                           truth.alpha, truth.eta, 0.0, 0.0, 2.0))
    a = render_view(patch=truth, wall=truth_wall("model"), angle_deg=30.0, quality="quick",
                    direct_only=True, cache_dir=cache_dir)
    b = render_view(patch=fit, wall=truth_wall("model"), angle_deg=30.0, quality="quick",
                    direct_only=True, cache_dir=cache_dir)
    assert a.key == b.key                     # same content, same cache entry
    assert np.array_equal(a.radiance, b.radiance)


@pytest.mark.slow
def test_default_quality_error_bars_and_accuracy(tmp_path):
    """Default quality: < 1 % standard error per 5 nm band at 30°, and the direct-only render
    agrees with the quadrature band by band within its error bars."""
    from normbox_lab.predict.render import direct_estimate, render_view

    white = truth_patch(19)
    est = direct_estimate(material=white, angle_deg=30.0)
    r = render_view(patch=white, wall=truth_wall(), angle_deg=30.0, quality="default",
                    direct_only=True, cache_dir=tmp_path)
    assert np.median(r.relative_std_error) < 0.01
    assert np.allclose(r.radiance, est, rtol=0.02)
    z = np.abs(r.radiance - est) / r.std_error
    assert np.mean(z < 3.0) > 0.9


@pytest.mark.slow
def test_scalar_spectral_fallback_renders_the_same_light(tmp_path):
    """The fallback variant (no libLLVM) runs the same Python BSDF, one path at a time."""
    from normbox_lab.predict.render import Quality, direct_estimate, ensure_variant, render_view

    white = truth_patch(19)
    est = direct_estimate(material=white, angle_deg=30.0)
    r = render_view(patch=white, wall=truth_wall(), angle_deg=30.0, quality=Quality("t", 16, 4),
                    direct_only=True, cache=False, variant="scalar_spectral")
    assert r.variant == "scalar_spectral"
    assert _lum(r) == pytest.approx(_lum(r, est), rel=0.05)
    # the next default render switches back to this machine's variant
    from normbox_lab.predict.mitsuba_setup import choose_variant

    assert ensure_variant() == choose_variant() == mi.variant()


def test_panel_emitter_texture_orientation():
    """The single-emitter panel shows cell (j along y, i along x) of the map where
    `panel_cells_m` puts it: look straight up at three cell centres."""
    from normbox_lab.predict.materials import holder_material
    from normbox_lab.predict.mitsuba_bsdf import make_bsdf, make_panel_texture
    from normbox_lab.predict.render import ensure_variant
    from normbox_lab.predict.scene import panel_cells_m, scene_dict

    ensure_variant()
    cell_map = 1.0 + 0.1 * np.arange(25.0).reshape(5, 5)       # unique per cell
    grid = np.arange(360.0, 831.0, 5.0)
    tex = make_panel_texture(grid, np.ones_like(grid), cell_map)
    film = {"type": "specfilm", "width": 1, "height": 1, "component_format": "float32",
            "rfilter": {"type": "box"},
            "band": {"type": "spectrum", "value": [(500.0, 1.0), (600.0, 1.0)]}}
    grey = make_bsdf(holder_material())
    cells = panel_cells_m(None)
    T = mi.ScalarTransform4f
    for k in (0, 7, 19):                 # cell k = 5 j + i
        centre = cells[k][0]
        d = scene_dict(None, angle_deg=30.0, patch_bsdf=grey, wall_bsdf=grey, holder_bsdf=grey,
                       lamp_values=np.ones_like(grid), lamp_grid_nm=grid, film=film,
                       max_depth=1, panel_radiance=tex)
        d["sensor"] = {"type": "perspective", "fov": 0.5, "film": film,
                       "to_world": T().look_at(origin=[centre[0], centre[1], 0.4],
                                               target=list(map(float, centre)), up=[0, 1, 0])}
        img = np.asarray(mi.render(mi.load_dict(d), spp=64))
        assert img.mean() / 100.0 == pytest.approx(cell_map.ravel()[k], rel=1e-3)
