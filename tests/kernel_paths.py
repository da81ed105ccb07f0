"""Render every kernel path small, under Dr.Jit's bounds checks (`JitFlag.Debug`).

Run as a script in a subprocess (`test_kernel_safety.py`): Dr.Jit's C++ side prints an
out-of-bounds gather or scatter as a message on stderr and goes on, and a read outside an
array on a CPU where it is not checked may crash the process, so the caller reads the child's
stderr and its exit status.  Each path prints `path <name> ok <seconds>` on stdout when it
returns; a path that raises prints `path <name> error <type>: <message>` and the script exits 1.

    python tests/kernel_paths.py [--no-debug] [name ...]     (no names: every path)

With ``--no-debug`` the same paths run as the product runs them (no bounds checks): the
kernels every process finds in Dr.Jit's on-disk cache, which a second process must not compile
again (`test_kernel_cache.py`).
"""

from __future__ import annotations

import sys
import time
import traceback
from collections.abc import Callable

import numpy as np

FLAT_NM = np.array([360.0, 830.0])


def _fit_family() -> tuple:
    from normbox_lab.predict import materials as mats

    return mats.truth_patch(13, "model"), mats.truth_wall("model")


def radiometer_view() -> None:
    """One patch per path (the randomised-QMC estimator) and the plain band path tracer
    (`BandPathTracer.render`), at grazing, oblique and normal angles."""
    from normbox_lab.predict.fastrender import FastNormbox

    patch, wall = _fit_family()
    box = FastNormbox()
    for angle in (0.0, 30.0, 65.0, 85.0, 90.0):
        r = box.render_view(patch=patch, wall=wall, angle_deg=angle, n_paths=4096, seed=1)
        assert np.all(np.isfinite(r.radiance))
        est = box.tracer(angle).render({"patch": patch, "wall": wall,
                                        "holder": wall}, FLAT_NM, [1.0, 1.0],
                                       n_paths=2048, seed=2)
        assert np.all(np.isfinite(est.radiance))
    direct = box.render_view(patch=patch, wall=wall, angle_deg=45.0, n_paths=2048, seed=3,
                             direct_only=True)
    assert np.all(np.isfinite(direct.radiance))


def all_patches() -> None:
    """All patches per path, with the guide to the aperture's sides (the default, 12 bounces)
    and without it (direct light only: no guide), and without randomised QMC."""
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.fastrender import FastNormbox

    wall = mats.truth_wall("model")
    patches = [mats.truth_patch(n, "model") for n in (1, 16, 24)]
    box = FastNormbox()
    for angle in (10.0, 90.0):
        rs = box.render_patches(patches=patches, wall=wall, angle_deg=angle, n_paths=4096,
                                seed=4)
        assert all(np.all(np.isfinite(r.radiance)) for r in rs)
    tr = box.tracer(45.0, direct_only=True)
    assert tr.guide is None
    ests = tr.render_patches(patches, {"wall": wall, "holder": wall}, FLAT_NM, [1.0, 1.0],
                             n_paths=4096, seed=5)
    assert all(np.all(np.isfinite(e.radiance)) for e in ests)
    guided = box.tracer(45.0)
    guided.qmc = False
    try:
        ests = guided.render_patches(patches, {"wall": wall, "holder": wall}, FLAT_NM,
                                     [1.0, 1.0], n_paths=4096, seed=6)
    finally:
        guided.qmc = True
    assert all(np.all(np.isfinite(e.radiance)) for e in ests)


def dispersive_truth() -> None:
    """The default truth: λ-dependent η and the backscatter lobe (one patch at a time)."""
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.fastrender import FastNormbox

    patch, wall = mats.truth_patch(19), mats.truth_wall()
    box = FastNormbox()
    for angle in (30.0, 90.0):
        r = box.render_view(patch=patch, wall=wall, angle_deg=angle, n_paths=2048, seed=7)
        assert r.info["renderer"] == "fastrender" and np.all(np.isfinite(r.radiance))


def camera_cornell() -> None:
    """The camera tracer (first hit, continuation, layers) in the Cornell room."""
    from normbox_lab.images import cornell

    cs = cornell.cornell_scene(16, 12)
    img = cs.tracer.render(cornell.cornell_materials(), FLAT_NM, [1.0, 1.0], spp=2, seed=1)
    assert np.all(np.isfinite(img.radiance))


def camera_box() -> None:
    """The camera tracer on the Normbox view (the paper's Fig. 1), default truth."""
    from normbox_lab.images.normbox_view import render_normbox_camera
    from normbox_lab.predict import materials as mats

    img = render_normbox_camera(mats.truth_patch(7), mats.truth_wall(), 45.0, width=16,
                                height=12, spp=2, seed=2)
    assert np.all(np.isfinite(img.radiance))


def triplets() -> None:
    """MIST's wavelength triplets through stock Mitsuba's RGB path (`images.triplet`)."""
    from normbox_lab.images.triplet import render_triplets

    patch, wall = _fit_family()
    r = render_triplets(patch, wall, 30.0, spp=4, batches=2, pixels=4,
                        wavelengths_nm=np.array([450.0, 550.0, 650.0]))
    assert np.all(np.isfinite(r.radiance))


def stock_mitsuba() -> None:
    """Stock Mitsuba (`llvm_ad_spectral`) with the project's BSDF plugin (dispersive truth with
    backscatter, and the fit family) through the `path` integrator."""
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.render import Quality, render_view

    q = Quality("probe", spp=4, batches=2)
    for patch, wall in ((mats.truth_patch(19), mats.truth_wall()), _fit_family()):
        r = render_view(patch=patch, wall=wall, angle_deg=60.0, quality=q, cache=False, seed=1)
        assert np.all(np.isfinite(r.radiance))


def canary() -> None:
    """A gather with an index made from NaN, on purpose: the bounds checks must report it (the
    test's positive control; Dr.Jit's checked gather reads 0 instead of the address)."""
    import drjit as dr
    import mitsuba as mi

    from normbox_lab.predict.mitsuba_setup import in_variant, jit_variant

    with in_variant(jit_variant("mono")):
        table = mi.Float([1.0, 2.0])
        nan = dr.opaque(mi.Float, float("nan"), 4)
        dr.eval(dr.gather(mi.Float, table, mi.UInt32(nan * 1.0)))


PATHS: dict[str, Callable[[], None]] = {
    "radiometer_view": radiometer_view,
    "all_patches": all_patches,
    "dispersive_truth": dispersive_truth,
    "camera_cornell": camera_cornell,
    "camera_box": camera_box,
    "triplets": triplets,
    "stock_mitsuba": stock_mitsuba,
}
#: run only when named (`test_kernel_safety` names it)
CONTROLS: dict[str, Callable[[], None]] = {"canary": canary}
#: paths whose renders go through Mitsuba's own film (`mi.render`): Dr.Jit 1.5's Debug mode
#: reports every packet scatter of Mitsuba's ImageBlock as out of bounds and drops it (the
#: image comes out all zero; Mitsuba's own Cornell box shows the same), so these run with
#: `JitFlag.PacketOps` off, where the same scatters are checked one element at a time
MITSUBA_FILM_PATHS = ("triplets", "stock_mitsuba")


def main(names: list[str]) -> int:
    import drjit as dr

    debug = "--no-debug" not in names
    names = [n for n in names if n != "--no-debug"]
    dr.set_flag(dr.JitFlag.Debug, debug)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    status = 0
    for name in names or list(PATHS):
        t0 = time.perf_counter()
        dr.set_flag(dr.JitFlag.PacketOps, not debug or name not in MITSUBA_FILM_PATHS)
        try:
            {**PATHS, **CONTROLS}[name]()
        except Exception as exc:  # noqa: BLE001 - reported per path, the script exits 1
            traceback.print_exc()
            print(f"path {name} error {type(exc).__name__}: {exc}", flush=True)
            status = 1
            continue
        launches = dr.kernel_history()
        compiled = [k for k in launches if k.get("hash") and not k.get("cache_hit")]
        print(f"path {name} ok {time.perf_counter() - t0:.1f} s, {len(launches)} launches, "
              f"{len(compiled)} kernels compiled", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
