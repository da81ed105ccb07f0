"""`normbox-lab runs [--store FILE]`: one line per run."""

from __future__ import annotations

import argparse
import time

from normbox_lab.commands.common import add_store_argument


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("runs", help="list the runs in the store",
                       description="One line per run: id, uuid prefix, protocol, status, "
                                   "readings done/planned, last update.")
    add_store_argument(p)
    p.set_defaults(handler=_runs)


def format_run_line(run) -> str:
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(run.updated_s))
    return (f"{run.id:>4}  {run.uuid[:8]}  {run.protocol:<18} {run.status:<11} "
            f"{run.done:>5}/{run.planned:<5} {when}")


def _runs(args: argparse.Namespace) -> int:
    from pathlib import Path

    from normbox_lab.acquire.store import Store

    if not Path(args.store).exists():
        print(f"no store at {args.store} (nothing measured yet)")
        return 0
    with Store(args.store) as store:
        runs = store.runs()
        if not runs:
            print("no runs")
        for run in runs:
            print(format_run_line(run))
    return 0
