"""`normbox-lab bench predict`: the fast band-vector renderer against stock Mitsuba, equal noise.

Scene: the virtual Normbox (`normbox_lab.predict.scene`), lamp `render.Lamp()`, the 24 ColorChecker
patches × 13 sample angles (30…90 step 5) = 312 configurations, with materials of the fit-model
family (`materials.truth_patch(n, "model")`, `truth_wall("model")`: what the pipeline predicts
with).  Bands: 81 triangular 5 nm hats, 380–780 nm.

- Fast: `fastrender.predict_spectra` renders all configurations to the target (largest relative
  standard error over the bands ≤ `target`, 0.2 % by default), all patches per path
  (`patchset`: one set of paths per angle serves every patch), in process or with
  `--executor dask`; its wall time for all of them is the headline figure.
- Baseline, in the same run: stock Mitsuba `llvm_ad_spectral` (4 hero wavelengths per path,
  `specfilm` with the same 81 hats, the project's `normbox` BSDF; `render.render_view`,
  uncached) on a few configurations (default 3: patch 19 at 30°, 13 at 60°, 24 at 90°), each at
  three sample counts (default 64, 256, 1024 spp × 100 px × 16 batches).  Its time is fitted as
  t = a + b·N over the three, and only the slope b counts (the per-call overhead a is left to
  stock's credit); its noise per path is that of the largest sample count, ε²·N.
- Equal noise: each renderer's time is scaled to the target, t · (ε / target)², with ε the RMS
  over the bands of the relative standard error (the same statistic for both).  Stock at the
  target: b · N · (ε_N / target)².  Fast, amortised: the baseline configuration's angle
  rendered for all the sweep's patches at once (`FastNormbox.render_patches`, timed on its
  own), scaled by the *limiting* patch of that angle (the largest ε of them: every patch gets
  the paths it needs) and divided by the number of patches.  Fast, per configuration: the
  configuration rendered alone (`render_patches` with one patch), scaled by its own ε.
- Agreement: z = (fast alone − stock) / combined SE per band; its mean and RMS (not the
  spread around its own mean: errors common to all bands would hide there).
- Three repeats (seeds seed, seed+1, seed+2; `--repeats`), each with its own fast sweep and
  stock renders: the ratios' median and range.

Every time is taken twice: wall clock and this process's CPU time (all its threads); with other
processes on the machine the CPU-time ratio is the steadier one.  Last line: ``ratio: R``
(median over the repeats of the amortised stock / fast CPU-time ratio at equal noise).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from typing import Any, TextIO

import numpy as np

ANGLES_DEG = tuple(float(a) for a in range(30, 91, 5))
PATCHES = tuple(range(1, 25))
BASELINE = ((19, 30.0), (13, 60.0), (24, 90.0))
BASELINE_SPP = (64, 256, 1024)


def band_rms_rel_se(radiance: np.ndarray, std_error: np.ndarray) -> float:
    """RMS over the bands with signal of the relative standard error."""
    rad = np.asarray(radiance)
    sig = np.abs(rad) > 1e-6 * max(float(np.max(np.abs(rad))), 1e-300)
    rel = np.asarray(std_error)[sig] / np.abs(rad[sig])
    return float(np.sqrt(np.mean(rel * rel))) if rel.size else 0.0


def linear_fit(n: Sequence[float], t: Sequence[float]) -> tuple[float, float]:
    """Least-squares (a, b) of t = a + b·n."""
    b, a = np.polyfit(np.asarray(n, dtype=np.float64), np.asarray(t, dtype=np.float64), 1)
    return float(a), float(b)


def spread(values: Sequence[float], fmt: str = "{:.0f}") -> str:
    """'median (min–max)' of a few repeats."""
    v = np.asarray(values, dtype=np.float64)
    return (f"{fmt.format(float(np.median(v)))} ({fmt.format(float(v.min()))}–"
            f"{fmt.format(float(v.max()))})")


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
                   help="4 patches × 3 angles, one repeat and a small baseline (a smoke run)")
    p.add_argument("--baseline-spp", default=",".join(map(str, BASELINE_SPP)),
                   help="stock samples per pixel per batch, ≥ 3 square numbers (10×10 px, "
                        "16 batches; default 64,256,1024)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    return p


def run_bench_predict(out: TextIO = sys.stdout,
                      configs: Sequence[tuple[int, float]] | None = None, *,
                      argv: Sequence[str] | None = None, target_rel_se: float | None = None,
                      executor: str | None = None, workers: int | None = None,
                      baseline: Sequence[tuple[int, float]] | None = None,
                      baseline_spp: Sequence[int] | None = None, quick: bool | None = None,
                      repeats: int | None = None, seed: int | None = None) -> int:
    """Run the benchmark; `configs`: (patch number, angle) pairs (default all 312)."""
    a = _parser().parse_args(list(argv) if argv is not None else [])
    target = float(target_rel_se if target_rel_se is not None else a.target)
    kind = executor or a.executor
    n_workers = int(workers or a.workers)
    quick = bool(a.quick if quick is None else quick)
    spps = [int(s) for s in (baseline_spp or str(a.baseline_spp).split(","))]
    n_rep = int(repeats if repeats is not None else (1 if quick else a.repeats))
    seed = int(a.seed if seed is None else seed)
    if configs is None:
        configs = ([(p, ang) for ang in (30.0, 60.0, 90.0) for p in (1, 13, 19, 24)] if quick
                   else [(p, ang) for ang in ANGLES_DEG for p in PATCHES])
    if baseline is None:
        baseline = BASELINE
    if quick:
        spps = [16, 36, 64]
    if len(spps) < 3:
        raise ValueError("the stock baseline needs at least three sample counts")

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
    by_patch = {p: sorted(x for q, x in configs if q == p) for p in {q for q, _ in configs}}
    if any(v != angles for v in by_patch.values()):
        raise ValueError("bench predict renders full patch × angle grids")
    sweep = [patch_mat[p] for p in sorted(by_patch)]
    emit(f"bench predict: {len(configs)} configurations ({len(by_patch)} patches"
         f" × {len(angles)} angles), fit-family materials, 81 bands (5 nm hats, 380–780 nm),"
         f" target {100 * target:.2f} % relative standard error in the worst band, "
         f"{n_rep} repeat(s)")
    emit(f"machine: {os.cpu_count()} CPUs; fast variant {jit_variant('mono')}, executor {kind}"
         + (f" ({n_workers} workers)" if kind != "inprocess" else "")
         + f"; load average (1 min) at start {os.getloadavg()[0]:.2f}")

    # -- warm-up (kernel compilation, the scene of this process; not timed) -------------------
    t0 = time.perf_counter()
    box = FastNormbox()
    box.render_patches(patches=sweep[:2], wall=wall, angle_deg=angles[0], lamp=lamp,
                       n_paths=4096)
    if kind == "inprocess":
        predict_spectra(sweep[:2], angles[:1], wall=wall, lamp=lamp, n_paths=4096)
    emit(f"fast warm-up {time.perf_counter() - t0:.1f} s")

    # -- fast sweeps --------------------------------------------------------------------------
    sweeps = []
    ex = make_executor(kind, workers=n_workers, address=a.address)
    try:
        for r in range(n_rep):
            t0 = time.perf_counter()
            c0 = time.process_time()
            res = predict_spectra(sweep, angles, wall=wall, lamp=lamp, target_rel_se=target,
                                  seed=seed + r, executor=ex)
            sweeps.append((res, time.perf_counter() - t0, time.process_time() - c0,
                           os.getloadavg()[0]))
    finally:
        ex.close()
    for r, (res, wall_s, cpu_s, load) in enumerate(sweeps):
        emit(f"fast sweep {r + 1}: {res.radiance.shape[0] * res.radiance.shape[1]} "
             f"configurations in {wall_s:.2f} s wall"
             + (f", {cpu_s:.2f} CPU·s" if kind == "inprocess" else "")
             + f" (load {load:.2f})")
    res0 = sweeps[0][0]
    worst = np.max(res0.std_error / np.maximum(res0.radiance, 1e-300), axis=2)
    emit(f"fast: worst-band relative SE median {100 * np.median(worst):.3f} %, max "
         f"{100 * worst.max():.3f} %")
    # per angle: paths, time, and the limiting patch (largest band-RMS relative SE)
    for j, ang in enumerate(res0.angles_deg):
        eps = [band_rms_rel_se(res0.radiance[i, j], res0.std_error[i, j])
               for i in range(len(res0.patch_names))]
        emit(f"  {ang:4.0f}°: {int(res0.n_paths[0, j]):7d} paths, "
             f"{np.sum(res0.render_time_s[:, j]):.3f} s for the angle, limiting patch "
             f"{res0.patch_names[int(np.argmax(eps))]} (band-RMS SE {100 * max(eps):.3f} %)")

    # -- baseline: stock Mitsuba, same scene and materials -----------------------------------
    variant = ensure_variant()
    t0 = time.perf_counter()
    for spp in spps:     # the sample count is part of Mitsuba's compiled kernel: warm each
        render_view(patch=patch_mat[baseline[0][0]], wall=wall, angle_deg=baseline[0][1],
                    lamp=lamp, quality=Quality("warm", spp=spp, batches=1), cache=False)
    emit(f"baseline: stock Mitsuba {variant} (hero wavelengths, specfilm), 16 batches × "
         f"{'/'.join(map(str, spps))} spp × 100 px; t = a + b·N fitted per configuration and "
         f"repeat, b used (warm-up {time.perf_counter() - t0:.1f} s)")
    clocks = ("wall", "CPU")
    amortised = {k: [] for k in clocks}
    per_config = {k: [] for k in clocks}
    zs = []
    rows = {(p, ang): [] for p, ang in baseline}

    def timed(fn: Any, **kw: Any) -> tuple[Any, dict[str, float]]:
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn(**kw)
        return out, {"wall": time.perf_counter() - t0, "CPU": time.process_time() - c0}

    for r in range(n_rep):
        sums = {k: [0.0, 0.0] for k in clocks}
        alone_ratios: dict[str, list[float]] = {k: [] for k in clocks}
        for p, ang in baseline:
            name = patch_mat[p].name
            times, eps = [], []
            for spp in spps:
                st, t = timed(render_view, patch=patch_mat[p], wall=wall, angle_deg=ang,
                              lamp=lamp, quality=Quality("bench", spp=spp, batches=16),
                              cache=False, seed=1000 * (seed + r) + spp)
                times.append(t)
                eps.append(band_rms_rel_se(st.radiance, st.std_error))
            n = [16 * 100 * s for s in spps]
            box.render_patches(patches=sweep[:1], wall=wall, angle_deg=ang, lamp=lamp,
                               n_paths=4096)          # the scene at this angle (not timed)
            together, t_ang = timed(box.render_patches, patches=sweep, wall=wall,
                                    angle_deg=ang, lamp=lamp, target_rel_se=target,
                                    seed=seed + r)
            e_lim = max(band_rms_rel_se(x.radiance, x.std_error) for x in together)
            alone, t_alone = timed(box.render_patches, patches=[patch_mat[p]], wall=wall,
                                   angle_deg=ang, lamp=lamp, target_rel_se=target,
                                   seed=seed + r)
            alone = alone[0]
            e_alone = band_rms_rel_se(alone.radiance, alone.std_error)
            z = (alone.radiance - st.radiance) / np.maximum(
                np.hypot(alone.std_error, st.std_error), 1e-300)
            zs.append(z)
            row = {}
            for k in clocks:
                a_s, b_s = linear_fit(n, [t[k] for t in times])
                if b_s <= 0.0:        # overhead-bound (tiny sample counts): no slope to fit
                    a_s, b_s = 0.0, times[-1][k] / n[-1]
                stock_at = b_s * n[-1] * (eps[-1] / target) ** 2
                share_at = t_ang[k] * (e_lim / target) ** 2 / len(sweep)
                alone_at = t_alone[k] * (e_alone / target) ** 2
                sums[k][0] += stock_at
                sums[k][1] += share_at
                alone_ratios[k].append(stock_at / alone_at)
                row[k] = (a_s, b_s, stock_at, share_at, alone_at)
            rows[(p, ang)].append(row)
            w, c = row["wall"], row["CPU"]
            emit(f"  repeat {r + 1} {name}@{ang:g}: stock wall t = {w[0]:.2f} s + "
                 f"{1e6 * w[1]:.3f} µs·N ({', '.join(f'{t[clocks[0]]:.2f}' for t in times)} s; "
                 f"band-RMS SE {', '.join(f'{100 * e:.3f}' for e in eps)} %) → {w[2]:.2f} s "
                 f"wall / {c[2]:.2f} CPU·s at {100 * target:.2f} %; fast amortised "
                 f"{1e3 * w[3]:.2f} / {1e3 * c[3]:.2f} ms, alone {1e3 * w[4]:.1f} / "
                 f"{1e3 * c[4]:.1f} ms (wall / CPU); ratios wall {w[2] / w[3]:.0f}× / "
                 f"{w[2] / w[4]:.0f}×, CPU {c[2] / c[3]:.0f}× / {c[2] / c[4]:.0f}× (amortised /"
                 f" alone); z vs stock mean {np.mean(z):+.2f}, RMS {np.sqrt(np.mean(z * z)):.2f}")
        for k in clocks:
            amortised[k].append(sums[k][0] / sums[k][1])
            per_config[k].append(float(np.median(alone_ratios[k])))
    emit("per baseline configuration over the repeats, wall-time and CPU-time ratios: "
         "amortised / per configuration")
    for (p, ang), rr in rows.items():
        emit(f"  {patch_mat[p].name}@{ang:g}: wall "
             f"{spread([x['wall'][2] / x['wall'][3] for x in rr])}× / "
             f"{spread([x['wall'][2] / x['wall'][4] for x in rr])}×; CPU "
             f"{spread([x['CPU'][2] / x['CPU'][3] for x in rr])}× / "
             f"{spread([x['CPU'][2] / x['CPU'][4] for x in rr])}×")
    zz = np.concatenate(zs)
    emit(f"agreement, fast alone vs stock over {len(zs)} renders × {zs[0].size} bands: z mean "
         f"{np.mean(zz):+.3f}, RMS {np.sqrt(np.mean(zz * zz)):.3f}, |z| > 3: "
         f"{int(np.sum(np.abs(zz) > 3))}")
    walls = [w for _, w, _, _ in sweeps]
    cpus = [c for _, _, c, _ in sweeps]
    emit(f"fast, all {len(configs)} configurations: {spread(walls, '{:.2f}')} s wall, "
         f"{spread(cpus, '{:.2f}')} CPU·s; stock at equal noise ≈ "
         f"{np.median(amortised['wall']) * np.median(walls):.0f} s wall (the amortised ratio "
         f"× the sweep)")
    for k in clocks:
        emit(f"{k}-time ratios: per configuration (rendered alone) "
             f"{spread(per_config[k])}×; amortised (all patches per path, limiting patch per "
             f"angle) {spread(amortised[k])}×")
    emit(f"load average (1 min) at the end {os.getloadavg()[0]:.2f}: with other processes on "
         f"the CPUs the CPU-time ratio is the steadier figure")
    emit(f"ratio: {np.median(amortised['CPU']):.1f}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_bench_predict(sys.stdout, argv=list(argv) if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
