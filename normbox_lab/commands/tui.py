"""`normbox-lab tui [--lab LAB.toml] [--store FILE] [--world normbox|analytic|none]`: the operator
console.  Textual is imported only inside the handler (`normbox-lab --help` stays fast)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_STORE = "normbox.sqlite"     # = normbox_lab.acquire.store.DEFAULT_STORE, without importing numpy


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tui", help="the operator console (instruments, run, spectrum, runs, results)",
        description="A keyboard-first terminal console: run, pause, resume and abort protocols, "
                    "answer operator and fault prompts, watch spectra and the ΔE00 results. "
                    "Quitting mid-run pauses the run after the current reading; resume it here "
                    "or with `normbox-lab run --resume ID`.")
    p.add_argument("--lab", metavar="LAB.toml",
                   help="lab config (default: ./lab.toml, else the simulated template)")
    p.add_argument("--store", default=None, metavar="FILE",
                   help="measurement store (default: normbox.sqlite)")
    p.add_argument("--world", choices=("normbox", "analytic", "none"), default="normbox",
                   help="simulated labs: the virtual Normbox (Mitsuba, loaded after the first "
                        "paint), the closed-form analytic world, or none")
    p.add_argument("--time-scale", type=_time_scale,
                   default=None, metavar="S",
                   help="simulated labs: override the lab's time scale (0 = instant)")
    p.add_argument("--virtual-operator", action="store_true",
                   help="simulated labs: let the virtual operator answer prompts (default: "
                        "you answer them in the console)")
    p.add_argument("--protocol", default="reference-sweep", metavar="PROTOCOL",
                   help="protocol preselected in the Run tab (name or .py file)")
    p.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="prefill a parameter in the Run tab (as for `normbox-lab run`)")
    p.add_argument("--no-resume-offer", action="store_true",
                   help="do not offer to resume interrupted runs at start")
    p.add_argument("--exit-after-first-paint", action="store_true",
                   help=argparse.SUPPRESS)   # startup measurement (docs/tui.md)
    p.set_defaults(handler=_tui)


def _time_scale(text: str) -> float:
    """--time-scale through the one parser (imported when the option is given: its module
    is no part of the console's start, measured to its first paint)."""
    from normbox_lab.acquire.params import TIME_SCALE, option

    return option(TIME_SCALE, "--time-scale")(text)


_time_scale.__name__ = "number"


def _load_config(lab: str | None):
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, load_config, parse_config

    if lab is not None:
        return load_config(lab)
    if Path("lab.toml").exists():
        return load_config("lab.toml")
    return parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")


def _tui(args: argparse.Namespace) -> int:
    from normbox_lab.tui.app import NormboxConsole
    from normbox_lab.tui.controller import Session

    # the lab config (its checks import the drivers and the protocols), the store (numpy) and
    # the lab (its world) are read and opened after the first paint; a config the console
    # cannot use ends it with one line and exit 2, as before it painted
    if args.lab is not None and not Path(args.lab).is_file():
        _load_config(args.lab)            # the one line: no such file
    session = Session(None, args.store or DEFAULT_STORE, world=args.world,
                      virtual_operator=args.virtual_operator, time_scale=args.time_scale,
                      load_config=lambda: _load_config(args.lab))
    prefill = {}
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            from normbox_lab.acquire.params import ParameterError, show

            raise ParameterError(f"--param expects K=V, got {show(item)}")
        prefill[key.strip()] = value
    app = NormboxConsole(session, exit_after_paint=args.exit_after_first_paint,
                         offer_resume=not args.no_resume_offer, protocol=args.protocol,
                         prefill=prefill)
    app.run()
    if app.startup_error is not None:
        raise app.startup_error
    if args.exit_after_first_paint:
        print(f"first-paint-wall-time {app.first_paint_wall_s:.6f} "
              f"mitsuba-imported {'mitsuba' in sys.modules} "
              f"cpu-s {app.first_paint_cpu_s:.3f}")
        session.close()
        return 0
    if session.busy:
        # the window closed while a run was still going: withdraw any prompt, let a reading
        # under way be committed, and end the segment paused (resumable)
        session.quit()
        print("pausing the run (a reading under way is committed first)…", file=sys.stderr)
        try:
            session.wait(600.0)
        except KeyboardInterrupt:             # Ctrl+C while waiting: abort, still resumable
            print("interrupted: aborting the run (resumable)…", file=sys.stderr)
            session.abort()
            session.wait(30.0)
    result = session.result
    engine = session.engine
    if engine is not None and engine.run_uuid:
        rec = session.open_store().get_run(engine.run_uuid)
        print(f"run {rec.uuid} (id {rec.id}): {rec.status}, {rec.done}/{rec.planned} readings")
        if rec.status != "done":
            from normbox_lab.commands.run import resume_command

            lab = args.lab or (str(Path("lab.toml").resolve()) if Path("lab.toml").exists()
                               else None)
            world = session.world_kind if session.world_kind != "none" else None
            print("resume with: " + resume_command(rec.protocol, rec.uuid, store=args.store,
                                                   lab=lab, world=world,
                                                   time_scale=args.time_scale))
            print("(or in the console: r)")
    session.close()
    return 0 if result is None or result.status in ("done", "paused") else 1
