"""Closure that can fail: truth inside the fit model's family, no instrument noise, and truth
and prediction rendered with *independent* random numbers — so the comparison tests the whole
pipeline (fit recovery, scene, light, rendering), not only that the fits reproduce the truth.

Acceptance per configuration: NRMSE ≤ 0.5 % + 3 × the combined Monte-Carlo standard error
(truth and prediction, RMS over wavelength, relative to the mean reference radiance) and
ΔE00 ≤ 0.2.  The full version covers all 24 patches × 13 angles = 312 configurations (slow).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.analyze.pipeline import compare_run, fit_run, predict_run
from normbox_lab.core.types import BrdfReading, SpectralReading
from normbox_lab.predict.brdf_model import gonio_geometry
from normbox_lab.predict.materials import truth_brdf_inplane, truth_material

NRMSE_FLOOR = 0.005
DELTA_E00_MAX = 0.2


def _world(target_rel_se: float | None = None):
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.demo import DemoOptions, make_world

    config = parse_config(SIM_CONFIG_TEMPLATE.replace(
        'quality = "default"', 'quality = "default"\ntruth = "model"'))
    world, render = make_world(config, DemoOptions(truth="model"), "default")
    if target_rel_se is not None:          # both truth and prediction (the render reads it)
        world.target_rel_se = target_rel_se
    # the truth's noise drawn independently of the prediction's, at the same target
    world.errors = dataclasses.replace(world.errors, render_rel_se=world.target_rel_se)
    return world, render


def _gonio_run(store, patches):
    run = store.create_run("brdf-inplane", status="running")
    wl = np.arange(380.0, 781.0, 5.0)
    ti, to = gonio_geometry()
    for name in [f"p{p:02d}" for p in patches] + ["wall"]:
        mat = truth_material(int(name[1:]) if name != "wall" else "wall", "model")
        f = truth_brdf_inplane(mat, ti, to, wl, 4.0)
        for k in range(ti.size):
            store.add_brdf(run.id, f"{name}/i{ti[k]:+.0f}/o{to[k]:+.0f}",
                           BrdfReading(float(ti[k]), float(to[k]), 4.0, wl, f[k]))
    store.set_run_status(run.id, "done")
    return run.id


def _reference_run(store, world, patches, angles):
    """Truth radiance per configuration (as a noise-free radiometer would read it) and its own
    Monte-Carlo standard error."""
    run = store.create_run("reference-sweep", status="running")
    wl = world.wavelength_nm
    se = np.zeros((len(patches), len(angles), wl.size))
    for ai, a in enumerate(angles):
        for pi, p in enumerate(patches):
            r = world.render(p, a)
            rad = np.interp(wl, r.wavelength_nm, r.radiance)
            se[pi, ai] = np.interp(wl, r.wavelength_nm, r.std_error)
            store.add_spectral(run.id, f"a{a:g}/p{p:02d}",
                               SpectralReading(wl, rad, None, 1.0, 0.0, "world"),
                               {"patch": p, "angle_deg": float(a), "patch_name": str(p)})
    store.set_run_status(run.id, "done")
    return run.id, se


def closure(tmp_path, patches, angles, target_rel_se=None):
    patches = sorted(patches)                  # the comparison's order
    world, render = _world(target_rel_se)
    with Store(tmp_path / "closure.sqlite") as store:
        brdf = _gonio_run(store, patches)
        ref, truth_se = _reference_run(store, world, patches, angles)
        fits = fit_run(store, brdf)
        assert max(f.fit_error_pct for f in fits.values()) < 0.1
        aid = predict_run(store, ref, quality="default", render=render)
        pred_se = store.artifacts("prediction")[-1].arrays["std_error"]
        assert store.artifacts("prediction")[-1].id == aid
        c = compare_run(store, ref, brdf)
        reference = np.array([[store.reading(ref, f"a{a:g}/p{p:02d}").arrays[
            "radiance_W_sr_m2_nm"] for a in angles] for p in patches])
    combined = np.sqrt(np.mean(truth_se ** 2 + pred_se ** 2, axis=-1)) / reference.mean(axis=-1)
    limit = NRMSE_FLOOR + 3.0 * combined
    return c, limit, combined


def _check(c, limit, combined):
    over = np.argwhere(~(c.nrmse <= limit))
    assert over.size == 0, [(c.patch_names[p], float(c.angle_deg[a]), float(c.nrmse[p, a]),
                             float(limit[p, a])) for p, a in over[:10]]
    bad = np.argwhere(~(c.delta_e00 <= DELTA_E00_MAX))
    assert bad.size == 0, [(c.patch_names[p], float(c.angle_deg[a]), float(c.delta_e00[p, a]))
                           for p, a in bad[:10]]
    # independent random numbers: the comparison sees the Monte-Carlo noise (with shared
    # random numbers NRMSE would be far below the combined standard error everywhere)
    assert float(np.median(c.nrmse / combined)) > 0.2


def test_closure_independent_noise_small(tmp_path):
    c, limit, combined = closure(tmp_path, [19, 13, 7], [30.0, 60.0, 90.0])
    _check(c, limit, combined)


#: Monte-Carlo target of the full closure: at the default 0.4 % per band, independent noise
#: alone gives ΔE00 up to ~0.26 on a few of the 312 configurations (varies with the seed:
#: patch 6 at 70° 0.22 / 0.13 / 0.04 for three truth seeds); 0.2 % halves it.
FULL_TARGET_REL_SE = 0.002


@pytest.mark.slow
def test_closure_independent_noise_all_312(tmp_path):
    c, limit, combined = closure(tmp_path, list(range(1, 25)), list(range(30, 91, 5)),
                                 target_rel_se=FULL_TARGET_REL_SE)
    assert c.nrmse.shape == (24, 13)
    _check(c, limit, combined)
    print(f"closure 312: NRMSE max {100 * np.nanmax(c.nrmse):.3f} % (limit min "
          f"{100 * np.min(limit):.3f} %, max {100 * np.max(limit):.3f} %), NRMSE/limit max "
          f"{np.nanmax(c.nrmse / limit):.2f}; ΔE00 max {np.nanmax(c.delta_e00):.3f}, mean "
          f"{np.nanmean(c.delta_e00):.3f}; combined MC SE median {100 * np.median(combined):.3f} %")
