"""`normbox-lab fit | predict | compare | report`: the pipeline steps on stored runs."""

from __future__ import annotations

import argparse
import sys

from normbox_lab.acquire.params import WORKERS, Number, option
from normbox_lab.commands.common import add_store_argument, renderer_name, require_store
from normbox_lab.predict.precision import PRESETS, RENDERERS, STATISTIC, parse_target_se


def register(sub: argparse._SubParsersAction) -> None:
    f = sub.add_parser("fit", help="fit Cook-Torrance/GGX BRDFs to a gonio run",
                       description="Fit every material of a brdf-inplane (or imported) run; "
                                   "the fits are stored as artifacts.")
    f.add_argument("run", metavar="BRDF_RUN_ID")
    f.add_argument("-w", "--weight-exponent", type=option(Number(0, 10), "--weight-exponent"),
                   default=2.0,
                   help="cost weight cos^w θi (paper: 1…4, sometimes 6; default 2)")
    _accept_flagged(f)
    add_store_argument(f)
    f.set_defaults(handler=_fit)

    p = sub.add_parser("predict", help="render a reference run with the fitted materials",
                       description="Render every patch × angle of a reference sweep with the "
                                   "latest fits (spectral, with Monte-Carlo standard error).")
    p.add_argument("run", metavar="REFERENCE_RUN_ID")
    p.add_argument("--quality", default="default", choices=tuple(PRESETS),
                   help="a preset of the target precision: "
                        + ", ".join(f"{k} {100 * v:g} %%" for k, v in PRESETS.items())
                        + " (default: default)")
    p.add_argument("--target-se", type=_target_se, default=None, metavar="SE",
                   help="target relative standard error per band, e.g. 0.15%% or 0.0015: "
                        f"the {STATISTIC}; both renderers stop on it (overrides --quality)")
    p.add_argument("--renderer", choices=RENDERERS, default="fast",
                   help="fast: the band-vector renderer (default); mitsuba: the stock "
                        "Mitsuba renderer, one configuration after the other, in process")
    p.add_argument("--executor", choices=("inprocess", "dask"), default=None,
                   help="where the fast renderer's independent jobs run: this process "
                        "(default) or a dask.distributed cluster")
    p.add_argument("--workers", type=option(WORKERS, "--workers"), default=2, metavar="N",
                   help="dask: worker processes of a new local cluster (default 2)")
    p.add_argument("--address", metavar="URL", default=None,
                   help="dask: an existing cluster's scheduler, e.g. tcp://scheduler:8786")
    p.add_argument("--light-map", metavar="RUN_ID",
                   help="take the lamp luminance from this light-map run")
    _accept_flagged(p)
    add_store_argument(p)
    p.set_defaults(handler=_predict)

    c = sub.add_parser("compare", help="compare a prediction with its reference run",
                       description="NSE, RMSE, NRMSE, ΔE00 and the rating scale; with --brdf-run "
                                   "also the error model.")
    c.add_argument("run", metavar="REFERENCE_RUN_ID")
    c.add_argument("--brdf-run", metavar="RUN_ID", help="the gonio run the fits came from")
    c.add_argument("--renderer", metavar="NAME", type=renderer_name,
                   help="compare another renderer's prediction (`normbox-lab import "
                        "prediction`) instead of ours")
    _accept_flagged(c)
    add_store_argument(c)
    c.set_defaults(handler=_compare)

    r = sub.add_parser("report", help="write the HTML report of a compared reference run")
    r.add_argument("run", metavar="REFERENCE_RUN_ID",
                   help="the reference sweep (id or uuid prefix) whose prediction was compared")
    r.add_argument("-o", "--output", metavar="PATH", help="default: report-run-ID.html")
    r.add_argument("--brdf-run", metavar="RUN_ID", help="the gonio run (for the BRDF figures)")
    r.add_argument("--renderer", metavar="NAME", type=renderer_name,
                   help="build the report on an imported renderer's comparison (default: "
                        "ours; every renderer's row is in the report either way)")
    _accept_flagged(r)
    add_store_argument(r)
    r.set_defaults(handler=_report)


def _accept_flagged(p: argparse.ArgumentParser) -> None:
    p.add_argument("--accept-flagged", action="store_true",
                   help="use inputs with error quality flags anyway (see `normbox-lab qa`); "
                        "the accepted flags are recorded in the result's provenance")


def _open(args: argparse.Namespace):

    from normbox_lab.acquire.store import Store

    require_store(args.store)
    return Store(args.store)


def _fit(args: argparse.Namespace) -> int:
    from normbox_lab.analyze.pipeline import fit_run

    with _open(args) as store:
        fits = fit_run(store, args.run, args.weight_exponent,
                       progress=lambda s, d, t: print(f"\rfit {d}/{t}", end="", flush=True),
                       accept_flagged=args.accept_flagged)
        print()
        for name, fit in fits.items():
            print(f"{name:>6}  α={fit.alpha:.3f}  η={fit.eta:.3f}  c={fit.c:.4f} sr⁻¹  "
                  f"error {fit.fit_error_pct:.2f} %")
        return _print_artifact_flags(store, "fit")


def _print_artifact_flags(store, kind: str) -> int:
    """The flags the last step put on its artifacts; 0 (flags are data, not failures)."""
    from normbox_lab.analyze import qa

    latest = {a.name: a.id for a in store.artifacts(kind)}
    found = [f for aid in latest.values() for f in qa.flags(store, artifact=aid)]
    for f in found:
        print(f.line())
    if found:
        errors = sum(1 for f in found if f.severity == "error")
        print(f"{len(found)} flags: {errors} errors, {len(found) - errors} warnings")
    return 0


def _target_se(text: str) -> float:
    try:
        return parse_target_se(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _predict(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.queries import lamp_from_light_map
    from normbox_lab.analyze.pipeline import predict_run
    from normbox_lab.core.errors import one_line
    from normbox_lab.predict.executors import make_executor

    if args.address and args.executor != "dask":
        print("normbox-lab predict: error: --address names a dask scheduler: use it with "
              "--executor dask", file=sys.stderr)
        return 2
    if args.executor and args.renderer != "fast":
        print("normbox-lab predict: error: --executor runs the fast renderer's jobs; the "
              "Mitsuba renderer runs in process (drop --executor, or --renderer fast)",
              file=sys.stderr)
        return 2
    with _open(args) as store:
        lamp = lamp_from_light_map(store, args.light_map)
        try:
            executor = (make_executor(args.executor, workers=args.workers,
                                      address=args.address) if args.executor else None)
        except (ImportError, OSError) as exc:       # no dask, or no scheduler at --address
            print(f"normbox-lab predict: error: {one_line(str(exc))}", file=sys.stderr)
            return 2
        try:
            aid = predict_run(store, args.run, quality=args.quality,
                              target_se=args.target_se, renderer=args.renderer, lamp=lamp,
                              progress=lambda s, d, t: print(f"\rpredict {d}/{t}", end="",
                                                             flush=True),
                              accept_flagged=args.accept_flagged, executor=executor)
        finally:
            if executor is not None:
                executor.close()
        print(f"\nprediction stored (artifact {aid})")
    return 0


def _compare(args: argparse.Namespace) -> int:
    import numpy as np

    from normbox_lab.analyze.pipeline import compare_run

    with _open(args) as store:
        c = compare_run(store, args.run, args.brdf_run, accept_flagged=args.accept_flagged,
                        renderer=args.renderer)
    print(f"ΔE00 mean {np.nanmean(c.delta_e00):.2f}, max {np.nanmax(c.delta_e00):.2f}; "
          f"NRMSE mean {100 * np.nanmean(c.nrmse):.2f} %")
    for label, n in c.rating_counts().items():
        print(f"  {label}: {n}")
    return 0


def _report(args: argparse.Namespace) -> int:
    from normbox_lab.analyze import qa
    from normbox_lab.analyze.pipeline import report_run

    with _open(args) as store:
        # a verdict is given only on data without error flags, unless they are accepted
        accepted = [f for run in (args.run, args.brdf_run) if run is not None
                    for f in qa.require_clean(store, run=run, accept_flagged=args.accept_flagged,
                                              step="report")]
        notes = [(f"The verdict rests on data with {len(accepted)} accepted error flag(s) "
                  "(--accept-flagged; see `normbox-lab qa`).")] if accepted else []
        out = report_run(store, args.run, args.output, args.brdf_run, notes=notes,
                         renderer=args.renderer)
    print(f"report: {out}")
    return 0
