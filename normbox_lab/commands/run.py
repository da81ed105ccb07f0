"""`normbox-lab run PROTOCOL [--lab LAB.toml] [--store FILE] [--resume RUN_ID] [--dry-run]
[--param K=V ...] [--world normbox|analytic|none]`.

Ctrl-C once = pause after the current reading (the run stays resumable); twice = abort now.

Exit status: 0 the run is done (every planned reading stored; flagged ones included, `qa`
lists the flags); 3 the run ended paused and resumable (Ctrl-C once, a pause or stop at a safe
point, an emergency stop): its data are incomplete, and the last line says how to resume;
130 Ctrl-C while a prompt waited for an answer (the run is paused too); 1 aborted, readings
skipped, or an error (one line `normbox-lab: error: …`); 2 a bad command line.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from normbox_lab.acquire.params import TIME_SCALE, option

#: the exit status of a run that ended paused, resumable, with readings missing
EXIT_PAUSED = 3
#: the exit status after Ctrl-C at a prompt (the shell's 128 + SIGINT)
EXIT_INTERRUPTED = 130


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="run (or resume, or dry-run) a measurement protocol",
        description="Run a protocol: reference-sweep, brdf-inplane, light-map, repeatability, or "
                    "a path to a protocol .py file. Every reading is committed to the store "
                    "before the next step; Ctrl-C pauses after the current reading (resume with "
                    "--resume RUN_ID), a second Ctrl-C aborts.")
    p.add_argument("protocol", nargs="?", metavar="PROTOCOL",
                   help="protocol name or .py file (omit with --resume)")
    p.add_argument("--lab", metavar="LAB.toml",
                   help="lab config (default: ./lab.toml, else the simulated template)")
    p.add_argument("--store", default=None, metavar="FILE",
                   help="measurement store (default: normbox.sqlite)")
    p.add_argument("--resume", metavar="RUN_ID",
                   help="continue an interrupted run at its first missing reading")
    p.add_argument("--dry-run", action="store_true",
                   help="list the steps and the ETA from the instruments' timing models")
    p.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="override a protocol parameter (JSON values: angles_deg=[30,60])")
    p.add_argument("--world", choices=("normbox", "analytic", "none"), default=None,
                   help="simulated labs: the virtual Normbox (Mitsuba, the default), the "
                        "closed-form analytic world, or none; a resumed run keeps its world")
    op = p.add_mutually_exclusive_group()
    op.add_argument("--virtual-operator", dest="virtual_operator", action="store_true",
                    default=None, help="answer prompts by simulation (default in simulated labs)")
    op.add_argument("--terminal-operator", dest="virtual_operator", action="store_false",
                    help="ask the prompts on the terminal, also in a simulated lab")
    p.add_argument("--fault-policy", choices=("retry", "skip", "abort"), default="retry",
                   help="the virtual operator's answer to a persistent fault (default retry)")
    p.add_argument("--time-scale", type=option(TIME_SCALE, "--time-scale"),
                   default=None, metavar="S",
                   help="simulated labs: override the lab's time scale (0 = instant)")
    p.add_argument("--force", action="store_true",
                   help="with --resume: resume even under another world or lab config than "
                        "the run recorded (refused otherwise: one run, one simulated truth)")
    p.add_argument("--plain", action="store_true",
                   help="one line per reading instead of a progress bar")
    p.set_defaults(handler=_run)


def _load_lab_config(args: argparse.Namespace, notes: list[str]):
    """The lab config of the run; what it says about the choice (the simulated template, an
    ignored option) goes to `notes`, printed once the run is accepted (a refusal is one
    line)."""
    from dataclasses import replace

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, load_config, parse_config

    if args.lab is not None:              # --lab "" is a path that names no file, refused
        config = load_config(args.lab)
    elif Path("lab.toml").exists():
        config = load_config("lab.toml")
    else:
        notes.append("no --lab and no ./lab.toml: using the simulated lab template "
                     "(normbox-lab init lab.toml --sim writes it)")
        config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    if args.time_scale is not None:
        if not config.simulated:
            notes.append("--time-scale applies to simulated labs only; ignored")
        else:
            config = replace(config, time_scale=args.time_scale)
    return config


def _parse_overrides(protocol: str | None, items: list[str]) -> dict:
    """`--param K=V ...` through the one parser (`normbox_lab.acquire.params`): a refusal is
    one line and exit 2."""
    from normbox_lab.acquire.engine import coerce_param, load_protocol
    from normbox_lab.acquire.params import ParameterError, show

    if not items:
        return {}
    if not protocol:
        raise ParameterError("--param needs a PROTOCOL")
    module = load_protocol(protocol)
    parameters = module.PARAMETERS
    limits = vars(module).get("LIMITS") or {}
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ParameterError(f"--param expects K=V, got {show(item)}")
        if key not in parameters:
            raise ParameterError(f"unknown parameter {show(key)}; known: "
                                 f"{', '.join(parameters)}")
        if key in out:
            raise ParameterError(f"--param {key} is given twice")
        out[key] = coerce_param(parameters[key], value, key, limits.get(key))
    return out


def _run(args: argparse.Namespace) -> int:
    import signal

    from normbox_lab.acquire.engine import open_run
    from normbox_lab.acquire.params import ParameterError
    from normbox_lab.acquire.store import DEFAULT_STORE

    if args.resume and args.param:
        raise ParameterError("--param cannot change a resumed run (its parameters are stored with "
                        "it)")
    if not args.resume and not args.protocol:
        raise ParameterError("name a PROTOCOL (reference-sweep, brdf-inplane, light-map, "
                        "repeatability, or a .py file), or --resume RUN_ID")
    overrides = _parse_overrides(args.protocol, args.param)
    notes: list[str] = []
    config = _load_lab_config(args, notes)
    progress_ref: dict = {}

    def terminal_operator(lab):
        from normbox_lab.acquire.operator import TerminalOperator

        def before() -> None:
            prog = progress_ref.get("progress")
            if prog is not None:
                prog.stop()
        return TerminalOperator(before=before, world=lab.world)

    if args.protocol and args.protocol.endswith(".py"):
        notes.append(f"protocol file {args.protocol}: Python code, run with your rights "
                     "because you named it here (shipped protocols and files named on the "
                     "command line are the only protocols normbox-lab runs)")
    from normbox_lab.acquire.store import Store
    from normbox_lab.core.errors import NormboxError

    store_path = args.store or DEFAULT_STORE
    # a dry run only reads: it never creates or changes the store
    store = Store(store_path, read_only=True) if args.dry_run else store_path
    from normbox_lab.sim.labsim import build_lab

    try:
        opened = open_run(args.protocol, store=store, config=config, make_lab=build_lab,
                          params=overrides, resume=args.resume, world=args.world,
                          virtual_operator=args.virtual_operator,
                          fault_policy=args.fault_policy, make_operator=terminal_operator,
                          force=args.force)
    except NormboxError as exc:
        # a refusal of what was typed (exit 2) is its one line; any other failure comes
        # after the notes, which may explain it (the simulated template, the file)
        if exc.exit_code != 2:
            _print_notes(notes)
        raise
    _print_notes(notes)                 # the run is accepted: the notes, then the run
    with opened:
        if args.dry_run:
            for line in opened.dry_run().lines():
                print(line)
            store.close()
            return 0
        return _execute(opened.engine, opened.lab, opened.store, opened.resume, args,
                        progress_ref, signal)


def _print_notes(notes: list[str]) -> None:
    for note in notes:
        print(note, file=sys.stderr, flush=True)


def _execute(engine, lab, store, run_ref, args, progress_ref, signal) -> int:
    from normbox_lab.acquire.engine import format_duration
    from normbox_lab.acquire.events import fault_text

    interrupts = {"n": 0}

    def on_sigint(signum, frame):
        interrupts["n"] += 1
        if engine.pending_prompt is not None and getattr(engine.operator, "interactive", True):
            raise KeyboardInterrupt      # waiting for a person: nothing is being measured
        if interrupts["n"] == 1:
            print("\npausing after the current reading (Ctrl-C again to abort now)…",
                  file=sys.stderr, flush=True)
            engine.pause()
        else:
            print("\naborting…", file=sys.stderr, flush=True)
            engine.abort()

    previous = signal.signal(signal.SIGINT, on_sigint)
    scale = getattr(lab.clock, "time_scale", None)
    clock_note = "" if scale is None else f" (virtual clock, time scale {scale:g})"
    result = None
    try:
        if args.plain:
            def plain(ev) -> None:
                if ev.kind == "run-started":
                    print(f"run {ev.data['run_uuid']} started: {ev.data['done']}/"
                          f"{ev.data['planned']} done, ETA {format_duration(ev.data['eta_s'])}"
                          f"{clock_note}", flush=True)
                elif ev.kind == "progress":
                    print(f"{ev.key} {ev.data['done']}/{ev.data['planned']} "
                          f"eta {ev.data['eta_s']:.0f}s", flush=True)
                elif ev.kind in ("warning", "fault", "suspended"):
                    what = f"{ev.data.get('role', '')} {fault_text(ev.data)}".strip()
                    print(f"{ev.kind}: {ev.key} {what}", file=sys.stderr, flush=True)
            engine.subscribe(plain)
            result = engine.run(resume=run_ref)
        else:
            result = _run_with_progress(engine, run_ref, progress_ref, clock_note)
    except KeyboardInterrupt:
        print(f"\ninterrupted at a prompt; run {engine.run_uuid} is paused", file=sys.stderr)
    finally:
        signal.signal(signal.SIGINT, previous)
    if result is None:
        print(_paused_line(engine, args))
        return EXIT_INTERRUPTED
    store_arg = f" --store {args.store}" if args.store else ""
    from normbox_lab.analyze import qa

    flagged = qa.summary(store, result.run_id)
    status = qa.run_status(store, result.run_id) if result.status == "done" else result.status
    print(f"run {result.uuid} (id {result.run_id}): {status}, "
          f"{result.done}/{result.planned} readings ({result.taken} taken now)")
    if flagged.flags:
        print(f"{flagged.line()} — see: normbox-lab qa {result.run_id}{store_arg}")
    if result.skipped:
        print(f"skipped: {', '.join(result.skipped)}")
    if result.status == "paused":
        # incomplete data: never exit 0 (a script must not take a paused run for a done one)
        print(_paused_line(engine, args))
        return EXIT_PAUSED
    if result.status != "done":
        print("resume with: " + resume_command(
            engine.plan.protocol, result.uuid, store=args.store, lab=_lab_path(args),
            world=_recorded_world(store, result.run_id), time_scale=args.time_scale))
    return 0 if result.status == "done" else 1


def resume_command(protocol: str, run: int | str, *, store: str | None, lab: str | None,
                   world: str | None, time_scale: float | None = None) -> str:
    """The complete command that resumes `run` in the lab, world and speed it ran in: every
    part quoted for a POSIX shell, so it can be pasted as it is."""
    from shlex import quote

    parts = ["normbox-lab", "run", protocol, "--resume", str(run)]
    for name, value in (("store", store), ("lab", lab), ("world", world)):
        if value:
            parts += [f"--{name}", str(value)]
    if time_scale is not None:
        parts += ["--time-scale", f"{time_scale:g}"]
    return " ".join(quote(p) for p in parts)


def _lab_path(args: argparse.Namespace) -> str | None:
    """The lab config the run used: --lab, else ./lab.toml when it was read (named, so the
    command works from another directory too), else none (the simulated template)."""
    if args.lab:
        return args.lab
    return str(Path("lab.toml").resolve()) if Path("lab.toml").exists() else None


def _recorded_world(store, run_id) -> str | None:
    """The world the run's latest segment recorded (None: not recorded, or a real lab)."""
    if store is None or run_id is None:
        return None
    worlds = [d["world"] for _, k, d in store.events(run_id)
              if k == "segment" and "world" in d]
    return worlds[-1] if worlds and worlds[-1] != "none" else None


def _paused_line(engine, args: argparse.Namespace) -> str:
    """"run N paused before KEY — resume with: normbox-lab run PROTOCOL --resume N …"."""
    run = engine.run_id if engine.run_id is not None else engine.run_uuid
    key = engine.next_key()
    where = f"before {key}" if key else "with every reading stored"
    world = engine.segment_info.get("world")
    command = resume_command(engine.plan.protocol, run, store=args.store, lab=_lab_path(args),
                             world=world if world != "none" else None,
                             time_scale=args.time_scale)
    return f"run {run} paused {where} — resume with: {command}"


def _run_with_progress(engine, run_ref, progress_ref, clock_note):
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from normbox_lab.acquire.engine import format_duration
    from normbox_lab.acquire.events import fault_text

    console = Console(stderr=True)
    progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                        MofNCompleteColumn(), TextColumn("{task.fields[key]}"),
                        TextColumn("ETA {task.fields[eta]}"), console=console, transient=False)
    progress_ref["progress"] = progress
    task = progress.add_task(engine.plan.protocol, total=engine.plan.planned, key="", eta="?")

    def on_event(ev) -> None:
        if ev.kind == "run-started":
            console.print(f"run {ev.data['run_uuid']} segment {ev.data['segment']}: "
                          f"{ev.data['done']}/{ev.data['planned']} done, ETA "
                          f"{format_duration(ev.data['eta_s'])}{clock_note}")
            progress.update(task, completed=ev.data["done"],
                            eta=format_duration(ev.data["eta_s"]))
        elif ev.kind == "progress":
            progress.update(task, completed=ev.data["done"], key=ev.key,
                            eta=format_duration(ev.data["eta_s"]))
        elif ev.kind == "answer":
            progress.start()
        elif ev.kind in ("warning", "suspended", "fault"):
            msg = fault_text(ev.data)
            console.print(f"[yellow]{ev.kind}[/] {ev.key} {msg}")
        elif ev.kind == "paused":
            console.print(f"paused before {ev.key or 'the end'}")

    engine.subscribe(on_event)
    with progress:
        return engine.run(resume=run_ref)
