"""`normbox-lab bench predict`: the fast band-vector renderer against stock Mitsuba, equal noise.

Scene: the virtual Normbox (`normbox_lab.predict.scene`), lamp `render.Lamp()`, the 24 ColorChecker
patches × 13 sample angles (30…90 step 5) = 312 configurations, with materials of the fit-model
family (`materials.truth_patch(n, "model")`, `truth_wall("model")`: what the pipeline predicts
with).  Bands: 81 triangular 5 nm hats, 380–780 nm.

- Fast: `fastrender.predict_spectra` renders all configurations to the target (largest relative
  standard error over the bands ≤ `target`, 0.2 % by default), all patches per path
  (`patchset`: one set of paths per angle serves every patch), in process or with
  `--executor dask`; its wall time for all of them is the headline figure.  A configuration's
  time is its angle's time divided by the number of patches.
- Baseline, in the same run: stock Mitsuba `llvm_ad_spectral` (4 hero wavelengths per path,
  `specfilm` with the same 81 hats, the project's `normbox` BSDF; `render.render_view`,
  uncached) on a few configurations (default 3: patch 19 at 30°, 13 at 60°, 24 at 90°) at a
  fixed sample count, its standard error from 16 independent batches.
- Equal noise: Monte-Carlo variance falls as 1/N and time grows as N, so each renderer's time
  is normalised to the target, t · (ε / target)², with ε the RMS over the bands of the relative
  standard error (the same statistic for both).  The ratio is Σ stock / Σ fast over the
  measured baseline configurations; the stock time for all 312 is that ratio times the fast
  sweep's time (an extrapolation, printed as such).

Last line: ``ratio: R`` (stock / fast time at equal noise).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from typing import TextIO

import numpy as np

ANGLES_DEG = tuple(float(a) for a in range(30, 91, 5))
PATCHES = tuple(range(1, 25))
BASELINE = ((19, 30.0), (13, 60.0), (24, 90.0))


def band_rms_rel_se(radiance: np.ndarray, std_error: np.ndarray) -> float:
    """RMS over the bands with signal of the relative standard error."""
    rad = np.asarray(radiance)
    sig = np.abs(rad) > 1e-6 * max(float(np.max(np.abs(rad))), 1e-300)
    rel = np.asarray(std_error)[sig] / np.abs(rad[sig])
    return float(np.sqrt(np.mean(rel * rel))) if rel.size else 0.0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="normbox-lab bench predict", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--target", type=float, default=0.002,
                   help="relative standard error per band to reach (default 0.002)")
    p.add_argument("--executor", default="inprocess", choices=("inprocess", "dask"))
    p.add_argument("--workers", type=int, default=2, help="cluster workers (dask)")
    p.add_argument("--address", default=None,
                   help="an existing dask cluster's scheduler, e.g. tcp://scheduler:8786")
    p.add_argument("--quick", action="store_true",
                   help="4 patches × 3 angles and a small baseline (a smoke run)")
    p.add_argument("--baseline-spp", type=int, default=64,
                   help="stock samples per pixel per batch (10×10 px, 16 batches)")
    p.add_argument("--seed", type=int, default=0)
    return p


def run_bench_predict(out: TextIO = sys.stdout,
                      configs: Sequence[tuple[int, float]] | None = None, *,
                      argv: Sequence[str] | None = None, target_rel_se: float | None = None,
                      executor: str | None = None, workers: int | None = None,
                      baseline: Sequence[tuple[int, float]] | None = None,
                      baseline_spp: int | None = None, quick: bool | None = None,
                      seed: int | None = None) -> int:
    """Run the benchmark; `configs`: (patch number, angle) pairs (default all 312)."""
    a = _parser().parse_args(list(argv) if argv is not None else [])
    target = float(target_rel_se if target_rel_se is not None else a.target)
    kind = executor or a.executor
    n_workers = int(workers or a.workers)
    quick = bool(a.quick if quick is None else quick)
    spp = int(baseline_spp or a.baseline_spp)
    seed = int(a.seed if seed is None else seed)
    if configs is None:
        configs = ([(p, ang) for ang in (30.0, 60.0, 90.0) for p in (1, 13, 19, 24)] if quick
                   else [(p, ang) for ang in ANGLES_DEG for p in PATCHES])
    if baseline is None:
        baseline = BASELINE
    if quick:
        spp = min(spp, 16)

    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.executors import make_executor
    from normbox_lab.predict.fastrender import FastNormbox, predict_spectra
    from normbox_lab.predict.mitsuba_setup import jit_variant
    from normbox_lab.predict.render import Lamp, Quality, ensure_variant, render_view

    def emit(line: str = "") -> None:
        print(line, file=out, flush=True)

    wall = mats.truth_wall("model")
    lamp = Lamp()
    patch_numbers = sorted({p for p, _ in configs} | {p for p, _ in baseline})
    patch_mat = {p: mats.truth_patch(p, "model") for p in patch_numbers}
    angles = sorted({float(x) for _, x in configs})
    emit(f"bench predict: {len(configs)} configurations ({len({p for p, _ in configs})} patches"
         f" × {len(angles)} angles), fit-family materials, 81 bands (5 nm hats, 380–780 nm),"
         f" target {100 * target:.2f} % relative standard error in the worst band")
    emit(f"machine: {os.cpu_count()} CPUs; fast variant "
         f"{jit_variant('mono')}, executor {kind}" + (f" ({n_workers} workers)" if kind != "inprocess"
                                                  else ""))

    # -- warm-up (kernel compilation, not timed in the figures) -------------------------------
    t0 = time.perf_counter()
    FastNormbox().render_view(patch=patch_mat[patch_numbers[0]], wall=wall, angle_deg=angles[0],
                              lamp=lamp, n_paths=1024)
    warm_fast = time.perf_counter() - t0

    # -- fast sweep -------------------------------------------------------------------------
    ex = make_executor(kind, workers=n_workers, address=a.address)
    try:
        by_patch = {p: [x for q, x in configs if q == p] for p in {q for q, _ in configs}}
        # predict_spectra renders full patch × angle grids; the bench asks for exact pairs
        full = all(sorted(v) == angles for v in by_patch.values())
        t0 = time.perf_counter()
        c0 = time.process_time()
        if full:
            res = predict_spectra([patch_mat[p] for p in sorted(by_patch)], angles, wall=wall,
                                  lamp=lamp, target_rel_se=target, seed=seed, executor=ex)
            sets = [res]
        else:
            sets = [predict_spectra([patch_mat[p]], sorted(v), wall=wall, lamp=lamp,
                                    target_rel_se=target, seed=seed, executor=ex)
                    for p, v in sorted(by_patch.items())]
        fast_wall = time.perf_counter() - t0
        fast_cpu = time.process_time() - c0
    finally:
        ex.close()
    fast = {}
    for s in sets:
        for i, name in enumerate(s.patch_names):
            for j, ang in enumerate(s.angles_deg):
                fast[(name, float(ang))] = (s.radiance[i, j], s.std_error[i, j],
                                            int(s.n_paths[i, j]), float(s.render_time_s[i, j]))
    worst = np.array([np.max(v[1][v[0] > 0] / v[0][v[0] > 0]) for v in fast.values()])
    rms = np.array([band_rms_rel_se(v[0], v[1]) for v in fast.values()])
    paths = np.array([v[2] for v in fast.values()])
    emit(f"fast: {len(fast)} configurations in {fast_wall:.1f} s wall "
         f"({fast_wall / len(fast):.3f} s per configuration; warm-up {warm_fast:.1f} s)"
         + (f"; {fast_cpu:.1f} CPU·s in this process" if kind == "inprocess" else ""))
    emit(f"load average (1 min) now {os.getloadavg()[0]:.2f} — other processes share the CPUs")
    emit(f"fast: paths per configuration median {int(np.median(paths))}, "
         f"min {paths.min()}, max {paths.max()}")
    emit(f"fast: achieved relative SE per band — worst band: median {100 * np.median(worst):.3f}"
         f" %, max {100 * worst.max():.3f} %; band RMS: median {100 * np.median(rms):.3f} %")
    for ang in angles:
        sel = [v for (n, x), v in fast.items() if x == ang]
        emit(f"  {ang:4.0f}°: {np.mean([v[3] for v in sel]):.3f} s/config, "
             f"{int(np.median([v[2] for v in sel]))} paths, worst-band SE "
             f"{100 * np.median([np.max(v[1] / np.maximum(v[0], 1e-300)) for v in sel]):.3f} %")

    # -- baseline: stock Mitsuba, same scene and materials ---------------------------------
    variant = ensure_variant()
    q = Quality("bench", spp=spp, batches=16)
    t0 = time.perf_counter()
    # warm-up with the same spp: the sample count is part of Mitsuba's compiled kernel
    render_view(patch=patch_mat[baseline[0][0]], wall=wall, angle_deg=baseline[0][1], lamp=lamp,
                quality=Quality("warm", spp=spp, batches=1), cache=False)
    warm_stock = time.perf_counter() - t0
    emit(f"baseline: stock Mitsuba {variant} (hero wavelengths, specfilm), "
         f"{q.batches} batches × {q.spp} spp × 100 px = {q.batches * q.spp * 100} paths per "
         f"configuration (warm-up {warm_stock:.1f} s)")
    sum_stock = sum_fast = 0.0
    cpu_stock = cpu_fast = 0.0
    for p, ang in baseline:
        name = patch_mat[p].name
        t0 = time.perf_counter()
        c0 = time.process_time()
        r = render_view(patch=patch_mat[p], wall=wall, angle_deg=ang, lamp=lamp, quality=q,
                        cache=False, seed=seed + 1)
        t_stock = time.perf_counter() - t0
        c_stock = time.process_time() - c0
        e_stock = band_rms_rel_se(r.radiance, r.std_error)
        stock_at = t_stock * (e_stock / target) ** 2
        fr = fast.get((name, float(ang)))
        if fr is None:
            box = FastNormbox()
            t1 = time.perf_counter()
            rv = box.render_view(patch=patch_mat[p], wall=wall, angle_deg=ang, lamp=lamp,
                                 target_rel_se=target, seed=seed)
            fr = (rv.radiance, rv.std_error, rv.info["n_paths"], time.perf_counter() - t1)
        # its angle again as the sweep renders it (all the sweep's patches per path, or this
        # configuration alone when it is not in the sweep), for the CPU time per configuration
        mates = sorted({q for q, x in configs if x == float(ang)} | {p})
        box_c = FastNormbox()
        box_c.render_view(patch=patch_mat[p], wall=wall, angle_deg=ang, lamp=lamp, n_paths=1024)
        c1 = time.process_time()
        together = box_c.render_patches(patches=[patch_mat[q] for q in mates], wall=wall,
                                        angle_deg=ang, lamp=lamp, target_rel_se=target,
                                        seed=seed)
        c_fast = (time.process_time() - c1) / len(mates)
        rc = together[mates.index(p)]
        e_fast = band_rms_rel_se(fr[0], fr[1])
        cpu_stock += c_stock * (e_stock / target) ** 2
        cpu_fast += c_fast * (band_rms_rel_se(rc.radiance, rc.std_error) / target) ** 2
        fast_at = fr[3] * (e_fast / target) ** 2
        sum_stock += stock_at
        sum_fast += fast_at
        z = (fr[0] - r.radiance) / np.maximum(np.hypot(fr[1], r.std_error), 1e-300)
        emit(f"  {name}@{ang:g}: stock {t_stock:.2f} s at band-RMS SE {100 * e_stock:.3f} % → "
             f"{stock_at:.1f} s at {100 * target:.2f} %; fast {fr[3]:.3f} s at "
             f"{100 * e_fast:.3f} % → {fast_at:.3f} s; ratio {stock_at / fast_at:.1f}; "
             f"agreement |z| median {np.median(np.abs(z)):.2f}, max {np.max(np.abs(z)):.2f}")
    ratio = sum_stock / sum_fast
    emit(f"stock for all {len(fast)} configurations at equal noise (extrapolated with the ratio):"
         f" ≈ {ratio * fast_wall:.0f} s; fast measured: {fast_wall:.1f} s")
    emit(f"CPU-time ratio on the same configurations (less sensitive to other load): "
         f"{cpu_stock / cpu_fast:.1f}")
    emit(f"ratio: {ratio:.1f}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_bench_predict(sys.stdout, argv=list(argv) if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
