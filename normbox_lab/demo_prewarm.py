"""Compile the campaign's kernels ahead, on the core the campaign leaves idle.

`python -m normbox_lab.demo_prewarm [--truth default|model|paper]`

A first run on a new machine compiles every Dr.Jit kernel of the fast renderer and the camera
(10-25 s each on a 2-core AVX2 CPU), one after another, when the stage that needs it starts.
The campaign's first stages (the BRDF runs, the fits, the light map) run no kernel and keep one
core busy, so `normbox-lab demo` starts this module in a low-priority child process at once: it
renders each kernel path of the later stages at a token size (a few thousand paths, an 8×6
image), which compiles the kernels into Dr.Jit's on-disk cache, where the stages then find
them.  The kernels are the stages' own, because the renders go through the same calls with
materials of the same families:

- the truth's radiometer view (`FastNormbox.render_view` with the truth materials: the sweep
  and the white reference);
- the prediction's (the fit model's family: all patches per path, with one patch and with the
  sweep's patch count, `--patches`), and its direct light alone (the light shares);
- the camera with and without layers (one set for truth and prediction: `CameraTracer`'s
  general materials).

It changes nothing but the cache; a kernel the stage needs before the child compiled it is
compiled by the stage itself, as without it.  With a warm cache it finishes in seconds.

With ``--ahead LAB_TOML``, the child then renders the reference sweep's truth ahead
(`render_truth_ahead`): the virtual Normbox of that lab config, every patch × angle of the
sweep, in the reverse of the sweep's order, into the lab config's render cache.  The sweep
renders from its start and the child from its end; they meet in between.  Each render is
traced once: the cache's per-render lock (`render.cached_render`) makes the one that comes
second wait and read what the other saved, and both compute the same thing (the same world,
the same per-configuration seeds), so the campaign's numbers do not depend on which process
traced a configuration.  The BRDF runs and the fits keep one core only: the child fills the
other (in the sweep itself both processes share the cores).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

#: the angle and the patch the token renders use (any: angles and materials are data)
ANGLE_DEG = 45.0
PATCH = 7


def prewarm_kernels(truth: str = "default", *, camera: bool = True, n_patches: int = 24,
                    on_step: Callable[[str, float], None] | None = None
                    ) -> list[tuple[str, float]]:
    """Render every kernel path of the campaign at a token size; (path, seconds) each
    (`on_step` is told after each one: the demo may end this process at any time).
    `n_patches`: the sweep's patch count, which the prediction renders per path (all
    patches per path compiles kernels per count)."""
    from normbox_lab.images.normbox_view import normbox_camera_renderer
    from normbox_lab.predict import materials as mats

    box = normbox_camera_renderer().box
    done: list[tuple[str, float]] = []

    def step(name: str, fn) -> None:
        t0 = time.perf_counter()
        fn()
        done.append((name, time.perf_counter() - t0))
        if on_step is not None:
            on_step(*done[-1])

    truth_patch, truth_wall = mats.truth_patch(PATCH, truth), mats.truth_wall(truth)
    fit_patch, fit_wall = mats.truth_patch(PATCH, "model"), mats.truth_wall("model")
    step("truth radiometer view", lambda: box.render_view(
        patch=truth_patch, wall=truth_wall, angle_deg=ANGLE_DEG, n_paths=2048, seed=1))
    step("prediction radiometer view", lambda: box.render_view(
        patch=fit_patch, wall=fit_wall, angle_deg=ANGLE_DEG, n_paths=2048, seed=2))
    step(f"prediction, {n_patches} patches per path", lambda: box.render_patches(
        patches=[fit_patch] * n_patches, wall=fit_wall, angle_deg=ANGLE_DEG, n_paths=2048,
        seed=2))
    step("prediction, direct light only", lambda: box.render_view(
        patch=fit_patch, wall=fit_wall, angle_deg=ANGLE_DEG, n_paths=2048, seed=3,
        direct_only=True))
    if camera:
        nc = normbox_camera_renderer()
        for layers in (True, False):
            step(f"camera ({'layers' if layers else 'radiance only'})", lambda layers=layers:
                 nc.render(patch=truth_patch, wall=truth_wall, angle_deg=ANGLE_DEG, width=8,
                           height=6, spp=2, seed=3, layers=layers))
    return done


def render_truth_ahead(config_path: str | Path, patches: list[int], angles_deg: list[float],
                       on_step: Callable[[str, float], None] | None = None) -> int:
    """Render the sweep's truth (`patches` × `angles_deg`) of the lab config's virtual Normbox
    into its render cache, last configuration first; the renders done.  Nothing when the
    config names no render cache, or when error sources are on (their sample-angle errors
    move the rendered angles, which only the sweep itself knows)."""
    from normbox_lab.acquire.config import parse_config
    from normbox_lab.sim.fast_world import FastVirtualNormbox

    config = parse_config(Path(config_path).read_text(), str(config_path))
    world = FastVirtualNormbox(config=config)
    if world.cache_dir is None or world.errors.spec() != "off":
        return 0
    done = 0
    for angle in reversed(angles_deg):
        t0 = time.perf_counter()
        for patch in reversed(patches):
            world.render(patch, angle)
            done += 1
        if on_step is not None:
            on_step(f"truth ahead at {angle:g}°", time.perf_counter() - t0)
    return done


def _numbers(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m normbox_lab.demo_prewarm",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--truth", choices=("default", "model", "paper"), default="default")
    p.add_argument("--no-camera", action="store_true", help="the radiometer views only")
    p.add_argument("--nice", action="store_true", help="run at the lowest CPU priority")
    p.add_argument("--ahead", metavar="LAB_TOML",
                   help="then render the sweep's truth of this lab config ahead, last first")
    p.add_argument("--patches", type=_numbers, default=[],
                   help="the sweep's patches, comma-separated (with --ahead)")
    p.add_argument("--angles", type=_numbers, default=[],
                   help="the sweep's angles in degrees, comma-separated (with --ahead)")
    p.add_argument("--stats-json", metavar="FILE",
                   help="write the kernels compiled and their compile time as JSON")
    args = p.parse_args(argv)
    if args.nice and hasattr(os, "nice"):
        os.nice(19)
    from normbox_lab.core.jit_stats import KernelLog

    log = KernelLog()
    log.start()
    t0 = time.perf_counter()

    def report(name: str, seconds: float) -> None:
        stats = log.snapshot()
        print(f"prewarm: {name} {seconds:.1f} s; {stats.line()}", flush=True)
        if args.stats_json:
            tmp = Path(args.stats_json + ".tmp")
            tmp.write_text(json.dumps({
                "wall_s": time.perf_counter() - t0, "compile_s": stats.compile_s,
                "compiled": stats.compiled, "from_disk": stats.from_disk,
                "launches": stats.launches, "ir_ops_max": stats.ir_ops_max}))
            tmp.replace(args.stats_json)          # whole, even if the demo ends us now

    prewarm_kernels(args.truth, camera=not args.no_camera,
                    n_patches=len(args.patches) or 24, on_step=report)
    if args.ahead:
        render_truth_ahead(args.ahead, [int(p) for p in args.patches], args.angles,
                           on_step=report)
    log.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
