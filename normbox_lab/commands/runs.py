"""`normbox-lab runs [--store FILE]`: one line per run."""

from __future__ import annotations

import argparse
import time

from normbox_lab.commands.common import add_store_argument, store_exists


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("runs", help="list the runs in the store",
                       description="One line per run: id, uuid prefix, protocol, status, "
                                   "readings done/planned, last update, quality flags.")
    add_store_argument(p)
    p.set_defaults(handler=_runs)


#: the column names over `format_run_line`
RUNS_HEADER = (f"{'id':>4}  {'uuid':<8}  {'protocol':<18} {'status':<11} "
               f"{'done':>5}/{'planned':<5} {'updated':<19}  flags")


def format_run_line(run, flags=None, status: str | None = None) -> str:
    """One run; `flags` (a `qa.QaSummary`) adds its flag count, and a done run with flags
    reads "completed with flags"; `status` is the one to show (`Store.shown_status`)."""
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(run.updated_s))
    status = status or run.status
    tail = ""
    if flags is not None and flags.flags:
        status = "completed with flags" if run.status == "done" else status
        tail = f"  {flags.flags} flags ({flags.errors} errors)"
    return (f"{run.id:>4}  {run.uuid[:8]}  {run.protocol:<18} {status:<11} "
            f"{run.done:>5}/{run.planned:<5} {when}{tail}")


def _runs(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.store import Store

    if not store_exists(args.store):
        print(f"no store at {args.store} (nothing measured yet)")
        return 0
    with Store(args.store, read_only=True) as store:     # a listing never writes
        runs = store.runs()
        if not runs:
            print("no runs")
        from normbox_lab.analyze.qa import summaries_by_run

        counts = summaries_by_run(store)
        if runs:
            print(RUNS_HEADER)
        for run in runs:
            print(format_run_line(run, counts.get(run.id), store.shown_status(run)))
    return 0
