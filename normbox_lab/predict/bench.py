"""`normbox-lab bench predict`: the fast band-vector renderer against stock Mitsuba, both
rendered *to* the same noise and timed there.

Scene: the virtual Normbox (`normbox_lab.predict.scene`), lamp `render.Lamp()`, materials of
the fit-model family (`materials.truth_patch(n, "model")`, `truth_wall("model")`); 81 bands
(5 nm hats, 380–780 nm).  Baseline configurations (default: patch 19 at 30°, 13 at 60°, 24 at
90°).  Equal noise is asked of three quantities, each with its own target:

- `band`: the RMS over the bands of the relative noise per band (default 0.2 %);
- `Y`: the relative noise of the luminance (CIE 1931 Y of the band spectrum; default 0.2 %);
- `ΔE00`: the RMS ΔE00 between a render and its expectation (XYZ normalised by the white
  patch at 30°, Lab D65; default 0.04, what 0.2 % of luminance makes on a bright neutral).

The fast renderer's band errors are correlated (every path carries every band), stock's are
nearly independent (hero wavelengths), so the band target and the colour targets give
different ratios; all three are printed.

**Fast, to the target.**  The noise is measured, not taken from a law: K independent renders
(seeds; `--seeds`, default 12) at each path count of a ladder 1024·2^j, each quantity's noise
their spread (randomised QMC: the noise falls faster than 1/√N, differently per angle, so no
power law is assumed).  The path count at the target is interpolated between the two ladder
points around it (log–log), then K fresh renders at that count are timed and their noise
measured again; where it misses the target by more than 10 % the count is raised and the step
repeated.  The figure is the median time of one render there, and the noise it reached is
printed beside it.  Where the smallest count (1024 paths) already beats a target, the fast
time is that of 1024 paths and the ratio a lower bound ("≥").  Two ways: the configuration
rendered alone, and amortised (`--amortised`, default on: all 24 patches of the angle from one
set of paths, `FastNormbox.render_patches`, the *limiting* patch's noise against the target,
the time divided by 24).

**Stock, to the target.**  `render.render_view` (`llvm_ad_spectral`, specfilm with the same 81
hats, the project's `normbox` BSDF, 10×10 px, uncached) in independent batches: a pilot (64 spp
× 16 batches) gives each quantity's noise per batch; the batch count at the largest spp of
16/64/256/1024 that still needs ≥ 16 batches follows (fewest calls), and that render is timed
(its kernel compiled beforehand, untimed); its noise is the spread over its batches /
√batches (independent batches: this scaling is exact).  Missed by more than 10 %: more
batches; beaten by more than 20 %: fewer (not under 16); rendered and timed again.

Every time is taken as wall clock and as this process's CPU time (all its threads; the steadier
figure on a shared machine).  Repeats (`--repeats`, default 3) use their own seeds; each ratio
is printed per repeat and as median (range) with its spread, (max − min) / median.  The first
line names the machine (`core.machine.machine_header`).  Last line: ``ratio: R``, the median
over the repeats of the per-band CPU-time ratio, amortised (alone with ``--no-amortised``).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np

BASELINE = ((19, 30.0), (13, 60.0), (24, 90.0))
PATCHES = tuple(range(1, 25))
QUANTITIES = ("band", "Y", "ΔE00")
#: the fast renderer's smallest path count (whole sub-batches) and the ladder's top
FAST_MIN_PATHS = 1024
FAST_MAX_PATHS = 1 << 21
FAST_PATH_STEP = 512
STOCK_SPP = (16, 64, 256, 1024)
STOCK_MIN_BATCHES = 16
#: a render within this factor of the target counts as at the target
TOLERANCE = 1.10
#: stock's batches are cut when a render beats its target by more than this
LOW_TOLERANCE = 0.80
CLOCKS = ("wall", "CPU")


class Colour:
    """Luminance and Lab of band spectra [..., band], normalised by a white's Y."""

    def __init__(self, band_centres_nm: np.ndarray, white: np.ndarray) -> None:
        from normbox_lab.core.colorimetry import spectra_to_XYZ

        self.wl = np.asarray(band_centres_nm, dtype=float)
        self.y_white = float(spectra_to_XYZ(np.asarray(white, dtype=float), self.wl)[1])

    def xyz(self, spectra: np.ndarray) -> np.ndarray:
        from normbox_lab.core.colorimetry import spectra_to_XYZ

        return spectra_to_XYZ(np.asarray(spectra, dtype=float), self.wl) / self.y_white

    def lab(self, spectra: np.ndarray) -> np.ndarray:
        from normbox_lab.core.colorimetry import XYZ_to_Lab_D65

        return XYZ_to_Lab_D65(self.xyz(spectra))


def noise(samples: np.ndarray, colour: Colour, *, of_mean: bool) -> dict[str, np.ndarray]:
    """Each quantity's noise from independent samples [k, ..., band]: of one sample (K seeded
    renders, `of_mean` False) or of their mean (a render's batches, True: / √k).  Per leading
    index after k: band (RMS over bands with signal of the relative SD), Y (relative SD),
    ΔE00 (RMS ΔE00 of a sample against the samples' mean, ddof 1)."""
    from normbox_lab.core.colorimetry import delta_e00

    s = np.asarray(samples, dtype=float)
    k = s.shape[0]
    if k < 2:
        raise ValueError("noise needs at least two independent samples")
    div = math.sqrt(k) if of_mean else 1.0
    mean = s.mean(axis=0)
    sig = np.abs(mean) > 1e-6 * np.max(np.abs(mean), axis=-1, keepdims=True)
    rel = np.where(sig, s.std(axis=0, ddof=1) / np.where(sig, np.abs(mean), 1.0), 0.0)
    band = np.sqrt(np.sum(rel ** 2, axis=-1) / np.maximum(np.sum(sig, axis=-1), 1))
    y = colour.xyz(s)[..., 1]
    y_rel = y.std(axis=0, ddof=1) / np.abs(y.mean(axis=0))
    lab = colour.lab(s)
    de = delta_e00(np.broadcast_to(colour.lab(mean), lab.shape), lab)
    de_rms = np.sqrt(np.sum(de ** 2, axis=0) / (k - 1))
    return {"band": band / div, "Y": y_rel / div, "ΔE00": de_rms / div}


@dataclass
class AtTarget:
    """One side's render of one quantity at its target."""

    quantity: str
    target: float
    achieved: float              # the noise measured there
    size: str                    # "8192 paths" / "256 spp × 40 batches"
    time_s: dict[str, float]     # per configuration, wall and CPU
    lower_bound: bool = False    # fast only: the smallest count already beat the target
    ladder: list[tuple[int, float]] = field(default_factory=list)


def interpolate_count(ladder: Sequence[tuple[int, float]], target: float) -> tuple[int, bool]:
    """The path count where the measured noise crosses `target`, log–log between the two
    ladder points around it: (count, lower_bound); lower_bound when the first point already
    beats it.  Never beyond the ladder's ends."""
    n0, e0 = ladder[0]
    if e0 <= target:
        return int(n0), True
    for (na, ea), (nb, eb) in itertools.pairwise(ladder):
        if eb <= target:
            if ea <= eb:                          # noise did not fall: take the larger count
                return int(nb), False
            f = (math.log(ea) - math.log(target)) / (math.log(ea) - math.log(eb))
            return round(math.exp(math.log(na) + f * (math.log(nb) - math.log(na)))), False
    raise ValueError(f"the ladder never reached {target} (last {ladder[-1]})")


def _round_paths(n: float) -> int:
    return max(FAST_MIN_PATHS, math.ceil(n / FAST_PATH_STEP) * FAST_PATH_STEP)


def _timed(fn: Callable[[], Any]) -> tuple[Any, dict[str, float]]:
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, {"wall": time.perf_counter() - t0, "CPU": time.process_time() - c0}


def fast_to_target(render: Callable[[int, int], np.ndarray], colour: Colour,
                   targets: dict[str, float], *, seeds: Sequence[int], per_config: int
                   ) -> dict[str, AtTarget]:
    """`render(n_paths, seed)` → spectra [patch, band] (one patch, or all of an angle);
    the limiting patch's noise counts; times divided by `per_config`."""

    def measure(n: int, seed_list: Sequence[int]) -> tuple[dict[str, float], dict[str, float]]:
        outs, times = [], []
        for s in seed_list:
            r, t = _timed(lambda s=s: render(n, s))
            outs.append(r)
            times.append(t)
        nz = noise(np.array(outs), colour, of_mean=False)
        worst = {q: float(np.max(nz[q])) for q in QUANTITIES}
        med = {c: float(np.median([t[c] for t in times])) / per_config for c in CLOCKS}
        return worst, med

    ladder: list[tuple[int, dict[str, float]]] = []
    n = FAST_MIN_PATHS
    while True:
        worst, _ = measure(n, seeds)
        ladder.append((n, worst))
        if all(worst[q] <= targets[q] for q in QUANTITIES) or n >= FAST_MAX_PATHS:
            break
        n *= 2
    out = {}
    fresh = [s + 7919 for s in seeds]
    for q in QUANTITIES:
        lad = [(m, w[q]) for m, w in ladder]
        count, lower = interpolate_count(lad, targets[q])
        count = _round_paths(count)
        for _ in range(4):
            worst, med = measure(count, fresh)
            if worst[q] <= TOLERANCE * targets[q]:
                break
            lower = False
            count = _round_paths(count * (worst[q] / targets[q]) ** 2)
        out[q] = AtTarget(q, targets[q], worst[q], f"{count} paths", med, lower, lad)
    return out


def stock_to_target(render: Callable[[int, int, int], Any], colour: Colour,
                    targets: dict[str, float], *, seed: int) -> dict[str, AtTarget]:
    """`render(spp, batches, seed)` → a `RenderResult` with its batches [batch, band]."""
    pilot_spp, pilot_b = 64, STOCK_MIN_BATCHES
    pilot = render(pilot_spp, pilot_b, seed)
    per_batch = {q: float(v) * math.sqrt(pilot_b) for q, v in
                 noise(pilot.batches, colour, of_mean=True).items()}
    out = {}
    for qi, q in enumerate(QUANTITIES):
        # the largest spp that still needs ≥ 16 batches (fewest calls), else 16 spp × 16
        # batches
        spp, batches = STOCK_SPP[0], STOCK_MIN_BATCHES
        for s in STOCK_SPP:
            need = (per_batch[q] * math.sqrt(pilot_spp / s) / targets[q]) ** 2
            if need >= STOCK_MIN_BATCHES:
                spp, batches = s, math.ceil(need)
        render(spp, 1, seed)                      # the kernel for this spp (not timed)
        for attempt in range(4):
            res, t = _timed(lambda spp=spp, b=batches, s=seed + 100 * qi + 10 * attempt + 1:
                            render(spp, b, s))
            got = float(noise(res.batches, colour, of_mean=True)[q][()])
            low = got < LOW_TOLERANCE * targets[q] and batches > STOCK_MIN_BATCHES
            if got <= TOLERANCE * targets[q] and not low:
                break
            batches = max(STOCK_MIN_BATCHES,
                          math.ceil(batches * (got / targets[q]) ** 2 * 1.05))
        out[q] = AtTarget(q, targets[q], got, f"{spp} spp × {batches} batches", t)
    return out


def spread(values: Sequence[float], fmt: str = "{:.0f}") -> str:
    """'median× (min–max, ±x %)' of a few repeats (x: half the range over the median)."""
    v = np.asarray(values, dtype=np.float64)
    med = float(np.median(v))
    half = 50.0 * float(v.max() - v.min()) / med if med else 0.0
    return (f"{fmt.format(med)}× ({fmt.format(float(v.min()))}–{fmt.format(float(v.max()))}"
            f", ±{half:.0f} %)")


def _fmt_noise(q: str, x: float) -> str:
    return f"{x:.3f}" if q == "ΔE00" else f"{100 * x:.3f} %"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="normbox-lab bench predict", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--target", type=float, default=0.002,
                   help="band-RMS relative noise per band (default 0.002)")
    p.add_argument("--target-luminance", type=float, default=0.002,
                   help="relative noise of the luminance Y (default 0.002)")
    p.add_argument("--target-de00", type=float, default=0.04,
                   help="RMS ΔE00 noise (default 0.04)")
    p.add_argument("--seeds", type=int, default=12,
                   help="independent fast renders per path count (default 12)")
    p.add_argument("--no-amortised", action="store_true",
                   help="only the configuration rendered alone")
    p.add_argument("--quick", action="store_true",
                   help="patch 19 at 30° and 24 at 90°, targets 1 % / 1 % / 0.2, one repeat,"
                        " 6 seeds (a smoke run)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    return p


@dataclass
class _Sweep:
    """What every configuration of a bench run shares: the output, the renderers, the scene."""

    emit: Callable[[str], None]
    box: Any                              # FastNormbox
    stock_view: Callable[..., Any]        # predict.render.render_view
    quality: Callable[..., Any]           # predict.render.Quality
    sweep: list[Any]                      # the 24 patch materials
    wall: Any
    lamp: Any
    colour: Colour
    targets: dict[str, float]
    amortised: bool
    warm_up_from_s: float                 # perf_counter at the fast warm-up's start


def run_bench_predict(out: TextIO = sys.stdout, *, argv: Sequence[str] | None = None,
                      baseline: Sequence[tuple[int, float]] | None = None) -> int:
    """Run the benchmark (options as on the command line); print to `out`."""
    from normbox_lab.core.machine import machine_header

    a = _parser().parse_args(list(argv) if argv is not None else [])
    header = machine_header()                 # before the first render: cache cold / warm
    targets = {"band": a.target, "Y": a.target_luminance, "ΔE00": a.target_de00}
    n_rep, n_seeds = a.repeats, a.seeds
    configs = list(baseline or BASELINE)
    if a.quick:
        targets = {"band": 0.01, "Y": 0.01, "ΔE00": 0.2}
        n_rep, n_seeds = 1, 6
        configs = list(baseline or ((19, 30.0), (24, 90.0)))

    def emit(line: str = "") -> None:
        print(line, file=out, flush=True)

    emit(header)
    b = _set_up(emit, targets, amortised=not a.no_amortised)
    emit(f"bench predict: {len(configs)} configurations, {n_rep} repeat(s), fit-family "
         f"materials, 81 bands; targets band {100 * targets['band']:.2f} %, Y "
         f"{100 * targets['Y']:.2f} %, ΔE00 {targets['ΔE00']:.3f}; fast {_fast_variant()}"
         f" ({n_seeds} seeds a path count), stock {_stock_variant()}; set-up and fast warm-up "
         f"{time.perf_counter() - b.warm_up_from_s:.1f} s")
    emit("  each row: the noise reached (target), the size that reached it, the time of one "
         "configuration wall / CPU, the ratio stock / fast wall / CPU")
    ratios: dict[tuple[str, str, str], list[float]] = {}   # (way, quantity, clock) → repeats
    per_config: dict[tuple[int, float, str, str], list[float]] = {}
    for r in range(n_rep):
        sums: dict[tuple[str, str, str], list[float]] = {}
        for p, ang in configs:
            seeds = [1000 * (a.seed + r) + k for k in range(n_seeds)]
            _bench_config(b, r, p, ang, seeds, 100000 * (a.seed + r + 1), sums, per_config)
        for key, (s_sum, f_sum) in sums.items():
            ratios.setdefault(key, []).append(s_sum / max(f_sum, 1e-12))
    _emit_ratios(b, configs, ratios, per_config)
    emit(machine_header().replace("machine:", "machine at the end:", 1))
    head = "amortised" if b.amortised else "alone"
    emit(f"ratio: {np.median(ratios[(head, 'band', 'CPU')]):.1f}")
    return 0


def _fast_variant() -> str:
    from normbox_lab.predict.mitsuba_setup import jit_variant

    return jit_variant("mono")


def _stock_variant() -> str:
    from normbox_lab.predict.render import ensure_variant

    return ensure_variant()


def _set_up(emit: Callable[[str], None], targets: dict[str, float], *,
            amortised: bool) -> _Sweep:
    """The fit-family materials, the fast renderer warmed up, and the colour reference (the
    white patch at 30°)."""
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.fastrender import FastNormbox
    from normbox_lab.predict.render import BAND_CENTRES_NM, Lamp, Quality
    from normbox_lab.predict.render import render_view as stock_view

    wall = mats.truth_wall("model")
    lamp = Lamp()
    sweep = [mats.truth_patch(p, "model") for p in PATCHES]
    box = FastNormbox()
    t0 = time.perf_counter()
    white = box.render_view(patch=sweep[18], wall=wall, angle_deg=30.0, lamp=lamp,
                            n_paths=1 << 17, seed=99).radiance
    return _Sweep(emit, box, stock_view, Quality, sweep, wall, lamp,
                  Colour(BAND_CENTRES_NM, white), targets, amortised, t0)


def _bench_config(b: _Sweep, r: int, p: int, ang: float, seeds: list[int], stock_seed: int,
                  sums: dict[tuple[str, str, str], list[float]],
                  per_config: dict[tuple[int, float, str, str], list[float]]) -> None:
    """One configuration (patch p at `ang`) in repeat r: fast alone (and amortised over the 24
    patches) and stock to the targets; print its rows, add its times to `sums` and its
    ratios to `per_config`."""
    mat = b.sweep[p - 1]

    def alone(n: int, s: int) -> np.ndarray:
        return b.box.render_view(patch=mat, wall=b.wall, angle_deg=ang, lamp=b.lamp,
                                 n_paths=n, seed=s).radiance[None]

    def together(n: int, s: int) -> np.ndarray:
        return np.array([x.radiance for x in b.box.render_patches(
            patches=b.sweep, wall=b.wall, angle_deg=ang, lamp=b.lamp, n_paths=n, seed=s)])

    b.box.render_patches(patches=b.sweep, wall=b.wall, angle_deg=ang, lamp=b.lamp,
                         n_paths=FAST_MIN_PATHS)          # this angle's scene, untimed
    fast = {"alone": fast_to_target(alone, b.colour, b.targets, seeds=seeds, per_config=1)}
    if b.amortised:
        fast["amortised"] = fast_to_target(together, b.colour, b.targets, seeds=seeds,
                                           per_config=len(b.sweep))

    def stock(spp: int, batches: int, s: int) -> Any:
        return b.stock_view(patch=mat, wall=b.wall, angle_deg=ang, lamp=b.lamp,
                            quality=b.quality("bench", spp=spp, batches=batches), cache=False,
                            seed=s)

    st = stock_to_target(stock, b.colour, b.targets, seed=stock_seed)
    for q in QUANTITIES:
        s_at = st[q]
        b.emit(f"  repeat {r + 1} {mat.name}@{ang:g} {q}: stock "
               f"{_fmt_noise(q, s_at.achieved)} ({_fmt_noise(q, s_at.target)}) at "
               f"{s_at.size}, {s_at.time_s['wall']:.2f} / {s_at.time_s['CPU']:.2f} s")
        for way, res in fast.items():
            f_at = res[q]
            rat = {c: s_at.time_s[c] / max(f_at.time_s[c], 1e-9) for c in CLOCKS}
            ge = "≥" if f_at.lower_bound else ""
            b.emit(f"      fast {way:9s} {_fmt_noise(q, f_at.achieved)} at {f_at.size}"
                   f", {1e3 * f_at.time_s['wall']:.2f} / {1e3 * f_at.time_s['CPU']:.2f}"
                   f" ms → {ge}{rat['wall']:.0f}× / {ge}{rat['CPU']:.0f}×")
            for c in CLOCKS:
                acc = sums.setdefault((way, q, c), [0.0, 0.0])
                acc[0] += s_at.time_s[c]
                acc[1] += f_at.time_s[c]
                per_config.setdefault((p, ang, way, q + " " + c), []).append(rat[c])


def _emit_ratios(b: _Sweep, configs: list[tuple[int, float]],
                 ratios: dict[tuple[str, str, str], list[float]],
                 per_config: dict[tuple[int, float, str, str], list[float]]) -> None:
    """The summary: per configuration, then over all of them, for each way and quantity."""
    b.emit("ratio stock / fast at equal noise, median (range) ±half-range over the repeats; "
           "per configuration, then the sum of the stock times over the sum of the fast ones")
    ways = ["alone"] + (["amortised"] if b.amortised else [])
    for way in ways:
        for q in QUANTITIES:
            cells = [f"{b.sweep[p - 1].name}@{ang:g} CPU "
                     f"{spread(per_config[(p, ang, way, q + ' CPU')])}"
                     for p, ang in configs]
            b.emit(f"  {way:9s} {q:4s}: " + "; ".join(cells))
            b.emit(f"  {way:9s} {q:4s}: all, wall {spread(ratios[(way, q, 'wall')])}, CPU "
                   f"{spread(ratios[(way, q, 'CPU')])}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_bench_predict(sys.stdout, argv=list(argv) if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
