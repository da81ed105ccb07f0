"""`normbox-lab qa RUN_ID [--store FILE]`: the quality flags of a run, one line each.

The last line is ``N flags: E errors, W warnings``; the exit status is 1 when there are error
flags, 0 otherwise; an unknown run or store is an error that names it (exit 1, on stderr).
"""

from __future__ import annotations

import argparse

from normbox_lab.commands.common import add_store_argument, require_store


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("qa", help="list the quality flags of a run",
                       description="One line per quality flag of a run (its readings and the "
                                   "fits/predictions made from it): severity, reading key or "
                                   "artifact, gate, measured value, limit, message.  Last line "
                                   "'N flags: E errors, W warnings'; exit 1 on error flags.")
    p.add_argument("run", metavar="RUN_ID", help="run id or uuid (prefix)")
    p.add_argument("--recheck", action="store_true",
                   help="apply the acquisition gates again (limits of the run's lab config)")
    add_store_argument(p)
    p.set_defaults(handler=_qa)


def _qa(args: argparse.Namespace) -> int:

    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze import qa

    require_store(args.store)
    with Store(args.store, read_only=not args.recheck) as store:   # only --recheck writes
        rec = store.get_run(args.run)           # an unknown run: StoreError naming it
        if args.recheck:
            qa.recheck_run(store, rec.id)
        found = qa.flags(store, rec.id)
        print(f"run {rec.id} ({rec.uuid[:8]}, {rec.protocol}): {qa.run_status(store, rec.id)}")
        for f in found:
            print(f.line())
        s = qa.summary(store, rec.id)
    print(s.line())
    return 1 if s.errors else 0
