"""Every kernel is memory-safe on every CPU, and a NaN never comes back as a number.

A gather with an index outside its array read garbage quietly on one machine and killed the
process on a 2-core AVX2 one (an index made from NaN in the emitter's factor map).  Each
kernel path renders small in a child process under Dr.Jit's bounds checks
(`tests/kernel_paths.py`); any out-of-bounds message on its stderr, or a crash, fails.  A
positive control (a gather with an index from NaN, on purpose) proves the checks and the
message we look for are live.  The same script under ``NORMBOX_LLVM_TARGET=haswell`` compiles
every kernel for an AVX2 machine (the user's), where the unfixed kernels segfault."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.core.errors import RenderError

SCRIPT = Path(__file__).resolve().parents[1] / "kernel_paths.py"
ROOT = SCRIPT.parent.parent


def _run_paths(*names: str, timeout_s: float = 900.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), str(SCRIPT.parent), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, str(SCRIPT), *names], capture_output=True,
                          text=True, timeout=timeout_s, cwd=ROOT, env=env, check=False)


def test_every_kernel_path_is_in_bounds_under_drjits_checks():
    from kernel_paths import PATHS

    res = _run_paths()
    report = f"stdout:\n{res.stdout}\nstderr (last 4000):\n{res.stderr[-4000:]}"
    assert res.returncode == 0, report                 # a crash is a negative status
    oob = [line for line in res.stderr.splitlines() if "out-of-bounds" in line]
    assert not oob, "\n".join(sorted(set(oob)))
    done = [line.split()[1] for line in res.stdout.splitlines()
            if line.startswith("path ") and line.split()[2] == "ok"]
    assert done == list(PATHS), report
    # the paths the bug report names, each rendered
    assert {"radiometer_view", "all_patches", "dispersive_truth", "camera_cornell",
            "camera_box", "triplets", "stock_mitsuba"} <= set(done)


def test_the_bounds_checks_see_an_index_made_from_nan():
    """The positive control: without it, a Dr.Jit that stopped checking (or changed its
    message) would make the test above pass on anything."""
    res = _run_paths("canary", timeout_s=300.0)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "out-of-bounds read" in res.stderr, res.stderr[-2000:]


def _nan_patch():
    from normbox_lab.predict import materials as mats

    patch = mats.truth_patch(13, "model")
    kd = np.array(patch.kd, dtype=np.float64)
    kd[len(kd) // 2] = np.nan
    return mats.Material(patch.name, patch.wavelength_nm, kd=kd, ks=patch.ks,
                         alpha=patch.alpha, eta=patch.eta, c=patch.c)


@pytest.mark.parametrize("estimator", ["one patch (randomised QMC)", "band path tracer",
                                       "all patches per path"])
def test_a_nan_in_a_lanes_radiance_is_a_typed_error(estimator):
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.fastrender import FastNormbox

    box = FastNormbox()
    wall = mats.truth_wall("model")
    patch = _nan_patch()
    with pytest.raises(RenderError, match="NaN or infinite"):
        if estimator == "band path tracer":
            box.tracer(45.0).render({"patch": patch, "wall": wall, "holder": wall},
                                    np.array([360.0, 830.0]), [1.0, 1.0], n_paths=1024)
        elif estimator == "all patches per path":
            box.render_patches(patches=[mats.truth_patch(1, "model"), patch], wall=wall,
                               angle_deg=45.0, n_paths=2048)
        else:
            box.render_view(patch=patch, wall=wall, angle_deg=45.0, n_paths=2048)


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_a_nan_in_the_camera_is_a_typed_error():
    """An infinite lamp value (its slope to the next 1 nm sample is inf − inf = NaN)."""
    from normbox_lab.images import cornell

    cs = cornell.cornell_scene(8, 6)
    mats = cornell.cornell_materials()
    lamp = np.array([1.0, np.inf])
    with pytest.raises(RenderError, match="camera tracer"):
        cs.tracer.render(mats, np.array([360.0, 830.0]), lamp, spp=1, seed=1)
