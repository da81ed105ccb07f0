"""`normbox-lab bench engine | fit`: figures, and the ratio to an in-run baseline on the last line.

`bench engine` runs the 312-reading reference sweep against the wire-level emulators (sim://,
virtual clock at time scale 0, so instrument delays cost nothing) with the analytic world and
the virtual operator, committing every reading durably (WAL, synchronous=FULL, one transaction
per reading).  It prints the wall-clock ms per reading and the store's share of it.  The
baseline is the same sweep in the same process with the store on ``:memory:`` (no disk, no
fsync); the last line is the ratio durable / baseline.
"""

from __future__ import annotations

import argparse
import inspect


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks (figures; last line: ratio to a baseline)")
    bsub = p.add_subparsers(dest="bench_command", metavar="BENCH")
    e = bsub.add_parser("engine", help="312-reading sweep against zero-delay emulators",
                        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("--store", default=None, metavar="FILE",
                   help="durable store file (default: a temporary file)")
    e.add_argument("--repeat", type=int, default=1, help="sweeps per variant (best is kept)")
    e.set_defaults(handler=_engine)
    f = bsub.add_parser("fit", help="BRDF fit benchmark (normbox_lab.bench_fit)")
    f.add_argument("rest", nargs=argparse.REMAINDER, help="options passed to the fit bench")
    f.set_defaults(handler=_fit)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


class _TimedStore:
    """Forwards to a Store and adds up the wall time spent inside it."""

    def __init__(self, store, timer) -> None:
        self._store = store
        self._timer = timer
        self.spent_s = 0.0

    def __getattr__(self, name: str):
        attr = getattr(self._store, name)
        if not callable(attr):
            return attr

        def timed(*a, **k):
            t0 = self._timer()
            try:
                return attr(*a, **k)
            finally:
                self.spent_s += self._timer() - t0
        return timed


def sweep_once(store_path: str) -> dict:
    """One 312-reading sweep; wall seconds in total, in the store, and per reading."""
    import time

    from normbox_lab import engine as eng
    from normbox_lab.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.lab import build_lab
    from normbox_lab.store import Store

    config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    lab = build_lab(config, world="analytic")
    store = Store(store_path)
    timed = _TimedStore(store, time.perf_counter)
    try:
        plan = eng.build_plan("reference-sweep", None, lab)
        engine = eng.Engine(lab, timed, plan)
        for role in ("radiometer", "rotator", "sphere"):
            lab.instrument(role)          # open the ports outside the timed sweep
        t0 = time.perf_counter()
        result = engine.run()
        total_s = time.perf_counter() - t0
    finally:
        lab.close()
        store.close()
    if result.status != "done" or result.done != plan.planned:
        raise RuntimeError(f"bench sweep ended {result.status} with {result.done} readings")
    n = result.done
    return {"readings": n, "total_s": total_s, "store_s": timed.spent_s,
            "ms_per_reading": 1e3 * total_s / n, "store_ms_per_reading": 1e3 * timed.spent_s / n,
            "virtual_s": result.elapsed_s}


def _engine(args: argparse.Namespace) -> int:
    import os
    import tempfile

    from normbox_lab.engine import format_duration

    with tempfile.TemporaryDirectory() as tmp:
        path = args.store or os.path.join(tmp, "bench.sqlite")
        durable = min((sweep_once(path) for _ in range(max(1, args.repeat))),
                      key=lambda r: r["total_s"])
        memory = min((sweep_once(":memory:") for _ in range(max(1, args.repeat))),
                     key=lambda r: r["total_s"])
    d, m = durable, memory
    print("bench engine: reference-sweep, 312 readings, CS-1000A / K10CR1 / sphere emulators over "
          "sim:// (virtual clock, time scale 0), analytic world, virtual operator")
    print(f"virtual lab time of the sweep: {format_duration(d['virtual_s'])} "
          f"({d['virtual_s']:.0f} s), wall time: {d['total_s']:.3f} s")
    print(f"durable store (WAL, synchronous=FULL, 1 transaction/reading): "
          f"{d['ms_per_reading']:.3f} ms per reading, store {d['store_ms_per_reading']:.3f} ms "
          f"({100 * d['store_s'] / d['total_s']:.0f} %)")
    print(f"baseline, same sweep with the store on :memory: : {m['ms_per_reading']:.3f} ms per "
          f"reading, store {m['store_ms_per_reading']:.3f} ms "
          f"({100 * m['store_s'] / m['total_s']:.0f} %)")
    target = "meets" if d["ms_per_reading"] <= 2.0 else "misses"
    print(f"target ≤ 2 ms per reading with durable commit: {target}")
    print(f"ratio durable/in-memory baseline: {d['ms_per_reading'] / m['ms_per_reading']:.2f}")
    return 0


def _fit(args: argparse.Namespace) -> int:
    try:
        from normbox_lab.bench_fit import run_bench_fit
    except ModuleNotFoundError as exc:
        if exc.name != "normbox_lab.bench_fit":
            raise
        print("normbox-lab: bench fit is not available in this installation")
        return 2

    params = inspect.signature(run_bench_fit).parameters
    if params:
        return int(run_bench_fit(list(args.rest)) or 0)
    return int(run_bench_fit() or 0)
