"""`normbox-lab budget REF_RUN [--sources ...]`: the error budget of a compared reference sweep."""

from __future__ import annotations

import argparse

from normbox_lab.acquire.params import Number, option
from normbox_lab.commands.common import add_store_argument, renderer_name, require_store


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "budget", help="error budget per source, 95 %% intervals, sample-angle offsets",
        description="For every patch × angle of a reference sweep (after predict and compare "
                    "--brdf-run), each error source's contribution to NRMSE / ΔE00 / NSE, "
                    "propagated through the comparison (angle, geometry and light through the "
                    "fast renderer's derivatives with common random numbers), 95 % intervals "
                    "on the observed NRMSE and ΔE00, a significance mark, and the estimated "
                    "sample-angle offset per sweep angle. Stored as artifact 'error-budget'. "
                    "The distributions: the run's [render] errors spec (virtual Normbox), else "
                    "the paper's figures.")
    p.add_argument("run", metavar="REF_RUN")
    p.add_argument("--sources", metavar="SPEC",
                   help="names (e.g. angle,cs1000,fit: only these, magnitudes kept) or a full "
                        "error spec (angle=1,cs1000=0.02; see docs/error-budget.md)")
    p.add_argument("--paths", type=option(Number(1, 1 << 30, whole=True), "--paths"),
                   default=1 << 14,
                   help="paths per derivative render (default 16384)")
    p.add_argument("--draws", type=option(Number(2, 100_000, whole=True), "--draws"),
                   default=64, help="draws per source (default 64)")
    p.add_argument("--renderer", metavar="NAME", type=renderer_name,
                   help="the budget of an imported renderer's prediction (`normbox-lab import "
                        "prediction`; compare it first); default: ours")
    p.add_argument("--paper-table", action="store_true",
                   help="print the paper-scenario table (markdown: observation | paper | ours) "
                        "of the compared run instead of computing a budget")
    add_store_argument(p)
    p.set_defaults(handler=_budget)


def _budget(args: argparse.Namespace) -> int:
    import time

    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze.budget_store import budget_run

    require_store(args.store)
    if args.paper_table:
        return _paper_table(args)
    t0 = time.perf_counter()
    with Store(args.store) as store:
        r = budget_run(store, args.run, sources=args.sources, n_paths=args.paths,
                       n_draws=args.draws, renderer=args.renderer)
    print(f"error budget of run {args.run}: {len(r.patches)} patches × {r.angle_deg.size} "
          f"angles; sources: {r.spec}")
    print(f"the truth's render noise in the render term: {r.truth_noise}")
    print("NRMSE contribution per source and angle (%, RMS over patches):")
    print(r.table())
    print("sample-angle offset per sweep angle (deg, 95 % interval, * significant):")
    for a, o, ci, sig in r.angle_offsets.rows():
        print(f"  {a:5g}°  {o:+.2f} ± {ci:.2f}{' *' if sig else ''}")
    n_sig = int(r.significant_nrmse.sum())
    print(f"significant NRMSE (beyond the measurement sources' 95th percentile): {n_sig} of "
          f"{r.significant_nrmse.size}; ΔE00: {int(r.significant_delta_e00.sum())}")
    t = r.timings_s
    print(f"time: derivatives {t.get('derivatives', 0):.1f} s, propagation "
          f"{t.get('propagation', 0):.1f} s, total {time.perf_counter() - t0:.1f} s")
    return 0


def _paper_table(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze.budget_store import paper_observations

    with Store(args.store) as store:
        print("| observation | paper | ours |\n|---|---|---|")
        for name, paper, ours in paper_observations(store, args.run):
            print(f"| {name} | {paper} | {ours} |")
    return 0
