"""The whole virtual campaign (`normbox-lab demo`, `make demo`).

    1. a simulated lab (every instrument a wire-level emulator; the virtual Normbox behind them)
    2. brdf-inplane: 153 geometries × 25 materials (24 patches + wall) on the gonioreflectometer
    3. fit: Cook-Torrance/GGX per material (artifacts)
    4. light-map: the 25 points of the opal panel
    5. reference-sweep: 24 patches × 13 angles = 312 radiometer readings
    6. predict: every patch × angle rendered with the fitted materials
    7. compare (+ error model)
    8. images: the box seen from its open side, truth vs fitted materials, per-pixel ΔE00 and
       the Wilkie–Weidlich white balance (the paper's Fig. 1), PNGs + spectral EXR
    9. the HTML report

Everything goes through the same code the lab uses: the engine drives the drivers, the drivers
talk bytes to the emulators, the store keeps every reading, the pipeline reads the store.

Rendering: by default both the world (truth materials, `sim.fast_world.FastVirtualNormbox`) and
the prediction (fitted materials) use the band-vector renderer `fastrender.FastNormbox` with
seeds from independent streams, one scene per process: the truth one render per configuration
(its materials are dispersive), the prediction every patch of an angle from one set of paths
(`PredictionRender.angle`); `--renderer stock`
uses Mitsuba's own spectral path tracer (`render.render_view`, cached on disk), slower.  `--quick` is the reduced version for tests: 4 patches × 3 angles,
coarse renders.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from normbox_lab.core.jit_stats import KernelLog, KernelStats

if TYPE_CHECKING:
    from normbox_lab.acquire.store_api import Store

QUICK_PATCHES = [19, 13, 7, 24]
#: the virtual camera's view (the paper's Fig. 1): the orange patch at 45°
CAMERA_PATCH = 7
CAMERA_ANGLE_DEG = 45.0
QUICK_ANGLES = [30, 60, 90]
#: the timing row of the prewarm child: its compile time is on the other core, in no stage's
#: wall time (and not in the campaign's)
BACKGROUND_STAGE = "prewarm (background)"
FULL_ANGLES = list(range(30, 91, 5))


@dataclass
class DemoOptions:
    quick: bool = False
    truth: str = "default"          # default | model (closure) | paper
    noise: bool = True              # instrument noise of the emulators
    errors: str | None = None       # error-source spec (core.error_sources); "paper": PAPER_SPEC
    store: str | None = None
    out_dir: str = "demo-out"
    renderer: str = "fast"          # fast | stock
    seed: int = 1
    #: compile the later stages' kernels in a low-priority child while the first stages run
    #: (`demo_prewarm`): a cold kernel cache costs less wall time
    prewarm: bool = True


@dataclass
class DemoResult:
    report: Path
    store: Path
    runs: dict[str, int]
    timings_s: dict[str, float] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    #: per stage: the Dr.Jit kernels it compiled or loaded, and the compile time
    kernels: dict[str, KernelStats] = field(default_factory=dict)


def sweep_patches(opts: DemoOptions) -> list[int]:
    """The patches of the campaign's BRDF runs and reference sweep."""
    return QUICK_PATCHES if opts.quick else list(range(1, 25))


def sweep_angles(opts: DemoOptions) -> list[int]:
    """The reference sweep's sample angles (degrees)."""
    return QUICK_ANGLES if opts.quick else FULL_ANGLES


def error_spec(opts: DemoOptions) -> str | None:
    """The error-source spec of the campaign: `--errors`, on top of the paper's set for
    `--truth paper`; None when neither asks for one (the emulators' own noise only)."""
    from normbox_lab.core.error_sources import (
        PAPER_SPEC,
        error_sources_from_config,
        parse_error_spec,
    )

    if opts.truth != "paper":
        if opts.errors is None:
            return None
        errors = parse_error_spec(opts.errors, seed=opts.seed)
    else:
        base = type("Cfg", (), {"render": {"errors": PAPER_SPEC}, "seed": opts.seed})()
        errors = error_sources_from_config(base, opts.errors)
    text = errors.spec()
    # `spec()` names the sources only: a `seed=N` of --errors other than the lab's seed (the
    # world's draws' seed when the spec names none) is written with them, so the lab config,
    # the stored run and a re-run draw the same errors
    if errors.seed != opts.seed and text != "off":
        text += f",seed={errors.seed}"
    return text


def _with_query(port: str, **params: str) -> str:
    sep = "&" if "?" in port else "?"
    return port + sep + "&".join(f"{k}={v}" for k, v in params.items())


def demo_config(opts: DemoOptions, quality: str, cache_dir: Path) -> Any:
    """The demo's lab: the simulated lab of `normbox-lab init --sim` with the demo's seed,
    render quality, truth and cache, and (with ``--noise off``) noiseless emulators."""
    from dataclasses import replace

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config

    base = parse_config(SIM_CONFIG_TEMPLATE)
    instruments = dict(base.instruments)
    spec = error_spec(opts)
    if not opts.noise or spec is not None:
        # with an error spec the world applies the radiometer's and the lamp's errors (so the
        # spec is the whole story); the emulators' own draws are off
        for role in ("radiometer", "spectrometer", "sphere"):
            inst = instruments[role]
            instruments[role] = replace(inst, port=_with_query(inst.port, noise="off"))
    render = {**base.render, "quality": quality, "truth": opts.truth,
              "cache_dir": str(cache_dir)}
    if opts.renderer == "fast":
        from normbox_lab.sim.fast_world import TRUTH_REL_SE

        # the truth's own Monte-Carlo noise (independent of the prediction's): the budget reads it
        render["truth_rel_se"] = TRUTH_REL_SE[quality]
    if spec is not None:
        render["errors"] = spec
    return replace(base, seed=opts.seed, instruments=instruments, render=render)


def make_world(config: Any, opts: DemoOptions, quality: str, *,
               truth_rel_se: float | None = None,
               prediction_rel_se: float | None = None) -> tuple[Any, Callable | None]:
    """The virtual Normbox, and the prediction's renders (`PredictionRender`; None for the
    stock renderer).

    Fast renderer: the world renders the truth with its own random numbers
    (`sim.world.TRUTH_RENDER_SEED`), the prediction with `PREDICTION_SEED`: the
    comparison sees both Monte-Carlo errors, as a measurement would.  Their targets (largest
    relative standard error per band): `truth_rel_se` (default: the lab config's ``[render]
    truth_rel_se``, which `demo_config` sets from `sim.fast_world.TRUTH_REL_SE`) and
    `prediction_rel_se` (default `FAST_TARGET_REL_SE[quality]`)."""
    from normbox_lab.sim.world import VirtualNormbox

    if opts.renderer == "stock":
        return VirtualNormbox(config=config), None
    from normbox_lab.predict.fastrender import FAST_TARGET_REL_SE, FastNormbox
    from normbox_lab.sim.fast_world import FastVirtualNormbox

    target = prediction_rel_se if prediction_rel_se is not None else FAST_TARGET_REL_SE[quality]
    world = FastVirtualNormbox(config=config, target_rel_se=truth_rel_se)
    # the truth geometry (perturbed by the `geometry`/`homogeneity` error sources, if on)
    fast = world.fast if world.geometry == config.geometry else FastNormbox(config.geometry)
    return world, PredictionRender(fast, target, world.cache_dir)


@dataclass
class PredictionRender:
    """The demo's prediction renders (fitted materials, nominal geometry, `PREDICTION_SEED`'s
    stream), kept in the render cache.  Called for one configuration (the light shares, or
    `predict_run` without `render_angle`); `angle` renders every patch of an angle from one set
    of paths (all patches per path: the patches' estimates are correlated with one another,
    each is unbiased with its own standard error, none shares the truth's random numbers)."""

    fast: Any
    target_rel_se: float
    cache_dir: str | None

    def __call__(self, geometry: Any, *, patch: Any, wall: Any, holder: Any,
                 angle_deg: float, lamp: Any = None, quality: str | None = None,
                 direct_only: bool = False) -> Any:
        from normbox_lab.predict.fastrender import config_seed
        from normbox_lab.sim.fast_world import PREDICTION_SEED

        return self.fast.render_view(
            patch=patch, wall=wall, holder=holder, angle_deg=angle_deg, lamp=lamp,
            target_rel_se=self.target_rel_se, direct_only=direct_only,
            seed=config_seed(PREDICTION_SEED, f"{config_name(patch.name)}@{float(angle_deg):g}"),
            cache_dir=self.cache_dir)

    def angle(self, geometry: Any, *, patches: list[Any], wall: Any, holder: Any,
              angle_deg: float, lamp: Any = None, quality: str | None = None) -> list[Any]:
        from normbox_lab.predict.fastrender import config_seed
        from normbox_lab.sim.fast_world import PREDICTION_SEED

        return self.fast.render_patches(
            patches=patches, wall=wall, holder=holder, angle_deg=angle_deg, lamp=lamp,
            target_rel_se=self.target_rel_se,
            seed=config_seed(PREDICTION_SEED, f"all patches@{float(angle_deg):g}"),
            cache_dir=self.cache_dir)


def config_name(fit_name: str) -> str:
    """Fit artifact names (p07, wall) → the truth material names (patch-7, wall): truth and
    prediction name a configuration alike, so their seeds differ only by the stream's base
    (`TRUTH_RENDER_SEED` vs `PREDICTION_SEED`), and a world given ``render_seed =
    PREDICTION_SEED`` shares the prediction's random numbers exactly."""
    if fit_name.startswith("p") and fit_name[1:].isdigit():
        return f"patch-{int(fit_name[1:])}"
    return fit_name


def start_prewarm(opts: DemoOptions, config_path: Path) -> Any:
    """The kernel prewarm child (`demo_prewarm`), at the lowest CPU priority, or None (stock
    renderer, or `opts.prewarm` off).  After the kernels it renders the sweep's truth ahead,
    from the sweep's end, into the lab config's render cache (`--ahead`)."""
    import os
    import subprocess
    import sys

    if not opts.prewarm or opts.renderer != "fast":
        return None
    stats = Path(opts.out_dir) / "prewarm.json"
    stats.unlink(missing_ok=True)
    child = subprocess.Popen(
        [sys.executable, "-m", "normbox_lab.demo_prewarm", "--truth", opts.truth,
         "--nice", "--stats-json", str(stats), "--ahead", str(config_path),
         "--patches", ",".join(str(p) for p in sweep_patches(opts)),
         "--angles", ",".join(f"{a:g}" for a in sweep_angles(opts))], stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, env=dict(os.environ))
    child.stats_json = stats
    return child


def stop_prewarm(child: Any) -> KernelStats | None:
    """End the prewarm child if it still runs (what it compiled stays in the cache); what it
    compiled, when it finished (its compile time is the campaign's too, on the other core)."""
    import json
    import subprocess

    if child is None:
        return None
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
    try:
        d = json.loads(child.stats_json.read_text())
    except (OSError, ValueError):
        return None
    return KernelStats(launches=int(d["launches"]), compiled=int(d["compiled"]),
                       from_disk=int(d["from_disk"]), compile_s=float(d["compile_s"]),
                       ir_ops_max=int(d["ir_ops_max"]))


def run_protocol(lab: Any, store: Store, protocol: str, params: dict[str, Any],
                 on_progress: Callable[[str, int, int], None]) -> Any:
    from normbox_lab.acquire.engine import open_run

    engine = open_run(protocol, lab=lab, store=store, params=params).engine

    def on_event(ev: Any) -> None:
        if ev.kind == "progress":
            on_progress(protocol, int(ev.data["done"]), int(ev.data["planned"]))
    engine.subscribe(on_event)
    result = engine.run()
    if result.status != "done":
        from normbox_lab.core.errors import NormboxError

        raise NormboxError(f"{protocol} ended {result.status} ({result.done}/{result.planned}); "
                           f"resume with: normbox-lab run --resume {result.uuid}")
    return result


def run_demo(opts: DemoOptions, on_progress: Callable[[str, int, int], None] | None = None,
             log: Callable[[str], None] = print) -> DemoResult:
    from normbox_lab.acquire.config import format_config, parse_config
    from normbox_lab.acquire.store import Store
    from normbox_lab.sim.labsim import build_lab

    progress = on_progress or (lambda stage, done, total: None)
    out = Path(opts.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    store_path = Path(opts.store) if opts.store else out / "normbox-demo.sqlite"
    quality = "quick" if opts.quick else "default"
    config_path = out / "lab.toml"
    config_path.write_text(format_config(demo_config(opts, quality, out / "render-cache")))
    config = parse_config(config_path.read_text(), str(config_path))
    stages = _Stages(log)
    stages.kernel_log.start()
    prewarm = start_prewarm(opts, config_path)
    world, render = stages.timed("set-up", lambda: make_world(config, opts, quality))
    lab = build_lab(config, world=world)
    # simulated readings: a commit survives a crash (kill -9), not a power cut (no fsync each)
    store = Store(store_path, durable="crash")
    try:
        done = _campaign(stages, _Scene(lab, store, config, world, render, quality, out),
                         opts, progress)
    finally:
        lab.close()
        store.close()
        stages.kernel_log.stop()
        background = stop_prewarm(prewarm)
        if background is not None:
            # compiled on the other core while the first stages ran (not in any stage's wall)
            stages.kernels[BACKGROUND_STAGE] = background
            stages.timings[BACKGROUND_STAGE] = 0.0
    return DemoResult(done.report, store_path, done.runs, stages.timings, _summary(done),
                      stages.kernels)


class _Stages:
    """The demo's stages, timed: wall time and kernel counts of each, logged as it ends."""

    def __init__(self, log: Callable[[str], None]) -> None:
        self.log = log
        self.timings: dict[str, float] = {}
        self.kernels: dict[str, KernelStats] = {}
        self.kernel_log = KernelLog()

    def timed(self, name: str, fn: Callable[[], Any]) -> Any:
        before = self.kernel_log.snapshot()
        t0 = time.perf_counter()
        value = fn()
        self.timings[name] = time.perf_counter() - t0
        self.kernels[name] = k = self.kernel_log.snapshot() - before
        self.log(f"{name}: {self.timings[name]:.1f} s (work {self.timings[name] - k.compile_s:.1f}"
                 f" s, {k.line()})" if k.launches else f"{name}: {self.timings[name]:.1f} s")
        return value


@dataclass
class _Scene:
    """The simulated lab the demo's campaign runs in, and where its files go."""

    lab: Any
    store: Store
    config: Any
    world: Any
    render: Any
    quality: str
    out: Path


@dataclass
class _Campaign:
    """What the stages produced: the report, the runs and what the summary reads."""

    report: Path
    runs: dict[str, int]
    comparison: Any
    images: Any
    flags: dict[str, Any]
    fit_errors: dict[str, float]


def _campaign(stages: _Stages, sc: _Scene, opts: DemoOptions,
              progress: Callable[[str, int, int], None]) -> _Campaign:
    """The stages in order: measure the BRDFs, fit, map the light, sweep, predict, compare,
    the camera's images and the report; then the runs' flags and the fit errors."""
    import numpy as np

    from normbox_lab.acquire.queries import lamp_from_light_map
    from normbox_lab.analyze import qa
    from normbox_lab.analyze.budget_store import record_truth_se
    from normbox_lab.analyze.pipeline import (
        camera_figures_run,
        compare_run,
        fit_run,
        predict_run,
        report_run,
    )

    timed, store, lab, out = stages.timed, sc.store, sc.lab, sc.out
    patches, angles = sweep_patches(opts), sweep_angles(opts)
    runs: dict[str, int] = {}
    brdf = timed("brdf-inplane", lambda: run_protocol(
        lab, store, "brdf-inplane", {"materials": [*patches, "wall"]}, progress))
    runs["brdf-inplane"] = brdf.run_id
    # the demo goes on through flagged data (recorded in each artifact's provenance) and
    # prints the flags at the end; `demo --strict` fails on any error flag
    timed("fit", lambda: fit_run(store, brdf.run_id, 2.0, progress, accept_flagged=True))
    light = timed("light-map", lambda: run_protocol(lab, store, "light-map", {}, progress))
    runs["light-map"] = light.run_id
    ref = timed("reference-sweep", lambda: run_protocol(
        lab, store, "reference-sweep", {"angles_deg": angles, "patches": patches},
        progress))
    runs["reference-sweep"] = ref.run_id
    # the truth's render noise as achieved, with the sweep (the budget's `render` term)
    record_truth_se(store, ref.run_id, patches, np.array(angles, dtype=float),
                    sc.world.wavelength_nm, sc.world.truth_relative_se(patches, angles))
    lamp = lamp_from_light_map(store, light.run_id)
    timed("predict", lambda: predict_run(store, ref.run_id, geometry=sc.config.geometry,
                                         quality=sc.quality, lamp=lamp, render=sc.render,
                                         render_angle=sc.render.angle if sc.render is not None else None,
                                         progress=progress, accept_flagged=True))
    comparison = timed("compare", lambda: compare_run(store, ref.run_id, brdf.run_id,
                                                      accept_flagged=True))
    camera_size = (80, 60, 16) if opts.quick else (320, 240, None)
    images = timed("images", lambda: camera_figures_run(
        store, ref.run_id, patch=CAMERA_PATCH, angle_deg=CAMERA_ANGLE_DEG, truth=opts.truth,
        lamp=lamp, geometry=sc.config.geometry, width=camera_size[0], height=camera_size[1],
        spp=camera_size[2], seed=opts.seed, out_dir=out / "images",
        cache_dir=sc.config.render.get("cache_dir")))
    notes = [(f"Virtual campaign: truth={opts.truth}, instrument noise "
              f"{'on' if opts.noise else 'off'}, renderer {opts.renderer}, "
              f"quality {sc.quality}, error sources {error_spec(opts) or 'off'}."),
             "Timing (s): " + ", ".join(f"{k} {v:.1f}" for k, v in stages.timings.items())]
    report = timed("report", lambda: report_run(store, ref.run_id, out / "report.html",
                                                brdf.run_id, notes))
    flags = {name: qa.flags(store, run_id) for name, run_id in runs.items()}
    fit_errors = {a.name: float(a.metadata["fit_error_pct"])
                  for a in {a.name: a for a in store.artifacts("fit", run_ref=brdf.run_id)
                            }.values()}
    return _Campaign(report, runs, comparison, images, flags, fit_errors)


def _summary(done: _Campaign) -> dict[str, Any]:
    """The figures `DemoResult.summary` carries: ΔE00 and NRMSE, ratings, camera, fits, flags."""
    import numpy as np

    comparison = done.comparison
    de, nr = comparison.delta_e00, comparison.nrmse
    return {"delta_e00_mean": float(np.nanmean(de)), "delta_e00_max": float(np.nanmax(de)),
            "nrmse_mean_pct": 100 * float(np.nanmean(nr)),
            "nrmse_max_pct": 100 * float(np.nanmax(nr)),
            "nrmse_by_angle_pct": {f"{a:g}": 100 * float(np.nanmean(nr[:, i]))
                                   for i, a in enumerate(comparison.angle_deg)},
            "ratings": comparison.rating_counts(),
            "camera_delta_e00": done.images.delta_e00,
            "camera_files": {k: str(v) for k, v in done.images.files.items()},
            "fit_error_pct": done.fit_errors,
            "flags": done.flags}
