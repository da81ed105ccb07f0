"""`normbox-lab bench engine | fit | predict`: figures, and the ratio to an in-run baseline on the last line.

`bench engine` runs the 312-reading reference sweep against the wire-level emulators (sim://,
virtual clock at time scale 0, so instrument delays cost nothing) with the analytic world and
the virtual operator, committing every reading durably (WAL, synchronous=FULL, one transaction
per reading).  It prints the wall-clock ms per reading split into instruments (driver +
emulator), store and engine, and the same sweep with the store on ``:memory:``.  The baseline
is the same moves and measurements as direct driver calls (no engine, no store) in the same
process; the last line is the ratio engine sweep / driver-only.
"""

from __future__ import annotations

import argparse

from normbox_lab.acquire.params import SEED, Number, option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks (figures; last line: ratio to a baseline)")
    bsub = p.add_subparsers(dest="bench_command", metavar="BENCH")
    e = bsub.add_parser("engine", help="312-reading sweep against zero-delay emulators",
                        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("--store", default=None, metavar="FILE",
                   help="durable store file (default: a temporary file)")
    e.add_argument("--repeat", type=option(Number(1, 1000, whole=True), "--repeat"),
                   default=2, help="sweeps per variant (best is kept)")
    e.set_defaults(handler=_engine)
    f = bsub.add_parser("fit", help="BRDF fit benchmark (normbox_lab.analyze.bench)")
    f.add_argument("--grid-step-nm",
                   type=option(Number(0, 50, unit="nm", above=True), "--grid-step-nm"),
                   default=None, help="wavelength grid step")
    f.add_argument("--materials", type=option(Number(1, 25, whole=True), "--materials"),
                   default=None, help="number of materials")
    f.add_argument("--w", type=option(Number(0, 10), "--w"),
                   default=None, help="cos^w θi weight exponent")
    f.set_defaults(handler=_fit)
    pr = bsub.add_parser("predict", help="fast spectral prediction vs stock Mitsuba "
                         "(normbox_lab.predict.bench)")
    pr.add_argument("--target", type=option(Number(0, 1, above=True), "--target"), default=None,
                    help="band-RMS relative noise per band to reach (default 0.002)")
    pr.add_argument("--target-luminance",
                    type=option(Number(0, 1, above=True), "--target-luminance"), default=None,
                    help="relative noise of the luminance to reach (default 0.002)")
    pr.add_argument("--target-de00", type=option(Number(0, 100, above=True), "--target-de00"),
                    default=None,
                    help="RMS ΔE00 noise to reach (default 0.04)")
    pr.add_argument("--seeds", type=option(Number(2, 1000, whole=True), "--seeds"), default=None,
                    help="independent fast renders per path count (default 12)")
    pr.add_argument("--no-amortised", action="store_true",
                    help="only the configuration rendered alone (not all patches per path)")
    pr.add_argument("--quick", action="store_true", help="a smoke run (2 configurations, "
                    "loose targets, one repeat)")
    pr.add_argument("--repeats", type=option(Number(1, 1000, whole=True), "--repeats"),
                    default=None, help="repeats (default 3)")
    pr.add_argument("--seed", type=option(SEED, "--seed"), default=None)
    pr.set_defaults(handler=_predict)
    d = bsub.add_parser("demo", help="the virtual campaign from a cold, then a warm kernel "
                        "cache: compile and work time per stage (normbox_lab.demo_bench)",
                        description=__import__("normbox_lab.demo_bench",
                                               fromlist=["x"]).__doc__,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    d.add_argument("--quick", action="store_true", help="the reduced campaign (4 patches × 3 "
                   "angles): the kernel-count goal only")
    d.add_argument("--warm", action="store_true", help="keep the machine's own kernel cache "
                   "(default: an empty one, as on a fresh machine)")
    d.set_defaults(handler=_demo)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _demo(args: argparse.Namespace) -> int:
    from normbox_lab.demo_bench import run_bench_demo

    result = run_bench_demo(quick=args.quick, warm=args.warm)
    return 0 if all(ok for _, _, ok in result["goals"]) else 1


class _TimedCalls:
    """Adds up the wall time spent in an instrument's capability methods (those the engine may
    call: the members of `core.capabilities` and the lamp monitor), by wrapping them on the
    instance itself (only the outermost call of a nesting counts): the engine still sees the
    driver object, so its capability checks cost what they cost in a real run.  A driver's
    other public methods (the per-line exchanges inside a reading) are left unwrapped, so the
    timing adds no per-line cost of its own."""

    def __init__(self, inst, timer) -> None:
        from normbox_lab.core.capabilities import CAPABILITIES

        self.spent_s = 0.0
        self._depth = 0
        names = {n for cap in CAPABILITIES for n in vars(cap)
                 if not n.startswith("_")}
        for name in sorted(names):
            if callable(getattr(type(inst), name, None)):
                setattr(inst, name, self._wrap(getattr(inst, name), timer))

    def _wrap(self, method, timer):
        def timed(*a, **k):
            if self._depth:
                return method(*a, **k)
            self._depth += 1
            t0 = timer()
            try:
                return method(*a, **k)
            finally:
                self.spent_s += timer() - t0
                self._depth -= 1
        return timed


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


def _sim_lab():
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.sim.labsim import build_lab

    lab = build_lab(parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>"), world="analytic")
    for role in ("radiometer", "rotator", "sphere"):
        lab.instrument(role)              # open the ports outside the timed part
    return lab


def sweep_once(store_path: str) -> dict:
    """One 312-reading sweep through the engine; wall seconds in total, in the store and in
    the instruments (driver + emulator), per reading."""
    import time

    from normbox_lab.acquire.engine import open_run
    from normbox_lab.acquire.store import Store

    lab = _sim_lab()
    timer = time.perf_counter
    instruments = {role: _TimedCalls(inst, timer) for role, inst in lab._open.items()}
    store = Store(store_path)
    timed = _TimedStore(store, timer)
    try:
        opened = open_run("reference-sweep", lab=lab, store=timed, lab_defaults=False)
        plan = opened.plan
        engine = opened.engine
        t0 = timer()
        result = engine.run()
        total_s = timer() - t0
    finally:
        lab.close()
        store.close()
    if result.status != "done" or result.done != plan.planned:
        raise RuntimeError(f"bench sweep ended {result.status} with {result.done} readings")
    n = result.done
    inst_s = sum(t.spent_s for t in instruments.values())
    return {"readings": n, "total_s": total_s, "store_s": timed.spent_s,
            "instrument_s": inst_s, "ms": 1e3 * total_s / n, "store_ms": 1e3 * timed.spent_s / n,
            "instrument_ms": 1e3 * inst_s / n,
            "engine_ms": 1e3 * (total_s - inst_s - timed.spent_s) / n,
            "virtual_s": result.elapsed_s}


def drivers_only() -> dict:
    """The baseline: the same moves, patch changes and 312 measurements by direct driver
    calls — no engine, no store."""
    import time

    from normbox_lab.acquire import engine as eng

    lab = _sim_lab()
    try:
        params = eng.load_protocol("reference-sweep").PARAMETERS
        rot, rad, lamp = (lab.instrument(r) for r in ("rotator", "radiometer", "sphere"))
        t0 = time.perf_counter()
        rad.set_remote(True)
        if not rot.is_homed():
            rot.home(wait=True)
        lamp.set_output(True)
        while not lamp.is_stable():
            lab.clock.sleep(1.0)
        n = 0
        for a in params["angles_deg"]:
            rot.move_to(float(a), wait=True)
            for p in params["patches"]:
                lab.world.place_patch(int(p))
                rad.measure()
                n += 1
        total_s = time.perf_counter() - t0
    finally:
        lab.close()
    return {"readings": n, "total_s": total_s, "ms": 1e3 * total_s / n}


def _engine(args: argparse.Namespace) -> int:
    import os
    import tempfile

    from normbox_lab.acquire.engine import format_duration
    from normbox_lab.core.machine import machine_header

    print(machine_header())             # every bench names its machine first
    reps = max(1, args.repeat)
    warm = _sim_lab()                 # first measurement imports colour-science: not timed
    try:
        warm.instrument("radiometer").measure()
    finally:
        warm.close()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.store or os.path.join(tmp, "bench.sqlite")
        base = min((drivers_only() for _ in range(reps)), key=lambda r: r["total_s"])
        d = min((sweep_once(path if i == 0 else f"{path}.{i}") for i in range(reps)),
                key=lambda r: r["total_s"])
        m = min((sweep_once(":memory:") for _ in range(reps)), key=lambda r: r["total_s"])
    overhead_ms = d["ms"] - d["instrument_ms"]
    print("bench engine: reference-sweep, 312 readings; CS-1000A, K10CR1 and sphere drivers "
          "against their emulators over sim:// (virtual clock, time scale 0: zero delay); "
          "analytic world; virtual operator")
    print(f"virtual lab time of the sweep: {format_duration(d['virtual_s'])} "
          f"({d['virtual_s']:.0f} s); wall time {d['total_s']:.2f} s")
    print(f"durable store (WAL, synchronous=FULL, 1 transaction/reading): {d['ms']:.2f} ms per "
          f"reading = instruments (driver+emulator) {d['instrument_ms']:.2f} + store "
          f"{d['store_ms']:.2f} ({100 * d['store_s'] / d['total_s']:.0f} %) + engine "
          f"{d['engine_ms']:.2f}")
    print(f"same sweep, store on :memory: : {m['ms']:.2f} ms per reading (store "
          f"{m['store_ms']:.2f})")
    print(f"engine + durable store overhead: {overhead_ms:.2f} ms per reading "
          f"(target ≤ 2 ms: {'met' if overhead_ms <= 2.0 else 'missed'})")
    print(f"baseline, driver calls only (no engine, no store): {base['ms']:.2f} ms per reading")
    print(f"ratio engine sweep (durable) / driver-only baseline: {d['ms'] / base['ms']:.2f}")
    return 0


def _forward(args: argparse.Namespace, names: tuple[str, ...]) -> list[str]:
    """The options given on our command line, as the bench module's own argv."""
    argv: list[str] = []
    for name in names:
        value = getattr(args, name.replace("-", "_"))
        if value is None or value is False:
            continue
        argv += [f"--{name}"] if value is True else [f"--{name}", str(value)]
    return argv


def _fit(args: argparse.Namespace) -> int:
    from normbox_lab.core.machine import machine_header

    print(machine_header())             # every bench names its machine first
    try:
        from normbox_lab.analyze.bench import run_bench_fit
    except ModuleNotFoundError as exc:
        if exc.name != "normbox_lab.analyze.bench":
            raise
        print("normbox-lab: bench fit is not available in this installation")
        return 2
    return int(run_bench_fit(_forward(args, ("grid-step-nm", "materials", "w"))) or 0)


def _predict(args: argparse.Namespace) -> int:
    import sys

    try:
        from normbox_lab.predict.bench import run_bench_predict
    except ModuleNotFoundError as exc:
        if exc.name != "normbox_lab.predict.bench":
            raise
        print("normbox-lab: bench predict is not available in this installation")
        return 2
    argv = _forward(args, ("target", "target-luminance", "target-de00", "seeds",
                           "no-amortised", "quick", "repeats", "seed"))
    return int(run_bench_predict(sys.stdout, argv=argv) or 0)
