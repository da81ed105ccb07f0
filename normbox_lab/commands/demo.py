"""`normbox-lab demo [--quick] [--truth default|model|paper] [--errors SPEC] [--noise on|off]
[--store FILE]`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from normbox_lab.demo import DemoOptions, DemoResult


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="run the whole virtual campaign (BRDFs, fits, light map, sweep, report)",
        description="The whole virtual campaign through the real code path: BRDF runs for 25 "
                    "materials, fits, light map, the 312-reading reference sweep, predictions "
                    "with the fitted materials, comparison and the HTML report. The last line "
                    "is 'report: PATH'.")
    p.add_argument("--quick", action="store_true",
                   help="reduced version: 4 patches × 3 angles, coarse renders (for tests)")
    p.add_argument("--truth", choices=("default", "model", "paper"), default="default",
                   help="truth materials: richer than the fit model (default), inside it "
                        "(model: the closure test), or the paper scenario (paper: calibrated "
                        "materials and every error source at the paper's magnitude)")
    p.add_argument("--errors", metavar="SPEC",
                   help="error sources of the virtual Normbox, e.g. "
                        "'angle=1,angle-offset=65:+0.7;80:-0.7,cs1000=0.02' (x: uniform ±x; "
                        "+x/-x: fixed; off; 'paper': all at the paper's magnitudes; see "
                        "docs/error-budget.md); with a spec the emulators' own radiometer and "
                        "lamp noise is off")
    p.add_argument("--noise", choices=("on", "off"), default="on",
                   help="instrument noise of the emulators")
    p.add_argument("--renderer", choices=("fast", "stock"), default="fast",
                   help="fast: band-vector renderer (default); stock: Mitsuba's spectral path "
                        "tracer")
    p.add_argument("--out", default="demo-out", metavar="DIR",
                   help="where the lab config, the store and the report go (default demo-out)")
    p.add_argument("--store", metavar="FILE", help="default: DIR/normbox-demo.sqlite")
    p.add_argument("--no-prewarm", action="store_true",
                   help="do not compile the renderer's kernels ahead in a low-priority child "
                        "process while the first stages run (they are then compiled when "
                        "needed)")
    p.add_argument("--timings-json", metavar="FILE",
                   help="also write each stage's wall and compile time and kernel counts, and "
                        "the machine, as JSON (what `bench demo` reads)")
    p.add_argument("--strict", action="store_true",
                   help="exit non-zero when any quality flag is an error (the demo itself "
                        "goes on through flagged data and prints the flags)")
    p.set_defaults(handler=_demo)


def _demo(args: argparse.Namespace) -> int:
    from normbox_lab.core.machine import machine_header
    from normbox_lab.demo import DemoOptions

    machine = machine_header()             # before the first kernel: cold or warm cache
    if args.errors is not None:
        from normbox_lab.core.error_sources import parse_error_spec

        parse_error_spec(args.errors)       # a bad spec fails before anything runs
    opts = DemoOptions(quick=args.quick, truth=args.truth, noise=args.noise == "on",
                       errors=args.errors,
                       store=args.store, out_dir=args.out, renderer=args.renderer,
                       prewarm=not args.no_prewarm)
    result = _run_with_progress(opts, machine)
    print(machine)
    _print_timings(result)
    n_err = _print_summary(result)
    if args.timings_json:
        _write_timings_json(Path(args.timings_json), machine, bool(args.quick), result)
    if args.strict and n_err:
        print(f"normbox-lab: error: --strict: {n_err} error flags", file=sys.stderr)
        return 1
    return 0


def _run_with_progress(opts: DemoOptions, machine: str) -> DemoResult:
    """The demo with a progress bar per stage on stderr (the machine line first)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from normbox_lab.demo import run_demo

    console = Console(stderr=True)
    console.print(machine)
    tasks: dict[str, int] = {}
    with Progress(TextColumn("[bold]{task.description:<16}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console) as progress:
        def on_progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = progress.add_task(stage, total=total)
            progress.update(tasks[stage], completed=done, total=total)

        return run_demo(opts, on_progress, log=lambda s: progress.console.print(s))


def _print_timings(result: DemoResult) -> None:
    """The timing breakdown: wall, share, work and compile time and kernels per stage."""
    total = sum(result.timings_s.values())
    print("timing breakdown (work = wall - kernel compilation):")
    print(f"  {'stage':<16} {'wall':>8}    {'%':>5}   {'work':>8}  {'compile':>8}  kernels "
          f"compiled / from disk / launches")
    from normbox_lab.demo import BACKGROUND_STAGE

    compiled = compile_s = in_wall_s = 0.0
    for k, v in result.timings_s.items():
        ks = result.kernels.get(k)
        c = ks.compile_s if ks else 0.0
        counts = f"{ks.compiled} / {ks.from_disk} / {ks.launches}" if ks else "-"
        compiled += ks.compiled if ks else 0
        compile_s += c
        if k == BACKGROUND_STAGE:           # on the other core: in no stage's wall time
            print(f"  {k:<16} {'-':>8}    {'-':>5}   {'-':>8}  {c:8.1f} s  {counts}")
            continue
        in_wall_s += c
        print(f"  {k:<16} {v:8.1f} s  {100 * v / total:5.1f} %  {v - c:8.1f} s {c:8.1f} s  "
              f"{counts}")
    print(f"  {'total':<16} {total:8.1f} s          {total - in_wall_s:8.1f} s "
          f"{compile_s:8.1f} s  {int(compiled)} kernels compiled")


def _print_summary(result: DemoResult) -> int:
    """The figures, the flags, the store and the report (last line); returns the number of
    error flags."""
    s = result.summary
    print(f"ΔE00 mean {s['delta_e00_mean']:.2f} (max {s['delta_e00_max']:.2f}); "
          f"NRMSE mean {s['nrmse_mean_pct']:.2f} % (max {s['nrmse_max_pct']:.2f} %)")
    print("NRMSE by angle (%): " + ", ".join(f"{a}° {v:.2f}"
                                            for a, v in s["nrmse_by_angle_pct"].items()))
    print("ratings: " + ", ".join(f"{k}: {v}" for k, v in s["ratings"].items()))
    c = s["camera_delta_e00"]
    print(f"virtual camera (Fig. 1): ΔE00 over the box (block means, as the report) mean "
          f"{c['converged_mean']:.2f}, p95 {c['converged_p95']:.2f}; "
          f"region means patch {c.get('patch_region', float('nan')):.2f}, "
          f"wall {c.get('wall_region', float('nan')):.2f}; images: "
          f"{Path(s['camera_files']['truth_png']).parent}")
    fe = s.get("fit_error_pct", {})
    if fe:
        import statistics

        med = statistics.median(fe.values())
        worst = max(fe, key=fe.get)
        print(f"fit error: median {med:.2f} %, worst {worst} {fe[worst]:.2f} % "
              f"({fe[worst] / med:.2f} × median)")
    n_err = n_all = 0
    for name, found in s.get("flags", {}).items():
        for f in found:
            print(f"flag [{name}] {f.line()}")
        n_all += len(found)
        n_err += sum(1 for f in found if f.severity == "error")
    print(f"{n_all} flags: {n_err} errors, {n_all - n_err} warnings")
    print(f"store: {result.store} (runs {result.runs})")
    print(f"report: {result.report}")
    return n_err


def _write_timings_json(path: Path, machine: str, quick: bool, result: DemoResult) -> None:
    """Each stage's wall and compile time and kernel counts, and the machine (what
    `bench demo` reads)."""
    import json

    from normbox_lab.core.jit_stats import KernelStats

    none = KernelStats()                    # a stage without kernels: zeros
    stages = {}
    for k, v in result.timings_s.items():
        ks = result.kernels.get(k, none)
        stages[k] = {"wall_s": v, "compile_s": ks.compile_s, "compiled": ks.compiled,
                     "from_disk": ks.from_disk, "launches": ks.launches,
                     "ir_ops_max": ks.ir_ops_max}
    path.write_text(json.dumps({"machine": machine, "quick": quick, "stages": stages},
                               indent=1))
