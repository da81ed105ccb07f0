"""`normbox-lab lab discover | check | calibrations`: first contact with a real lab.

    normbox-lab lab discover [ENDPOINT ...] [--write lab.toml]   find the instruments
    normbox-lab lab check [--lab lab.toml] [--store FILE]         prove each one works
    normbox-lab lab calibrations [--lab lab.toml] [--strict]      the certificates in force

docs/first-contact.md walks through them from unpacked instruments to the first reading.
"""

from __future__ import annotations

import argparse
import sys

from normbox_lab.acquire.params import Number, option
from normbox_lab.commands.common import add_store_argument


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("lab", help="find the instruments, check them, list their calibrations")
    labsub = p.add_subparsers(dest="lab_command", metavar="SUBCOMMAND")

    d = labsub.add_parser(
        "discover", help="find the instruments on serial ports, given endpoints and USB",
        description="Probe the serial ports pyserial lists (with their USB VID:PID and serial "
                    "number), the ENDPOINTs given (device paths, ptys, socket://HOST:PORT) and "
                    "USB (seabreeze). Each port is asked only the identification commands the "
                    "driver registry declares, at each driver's baud rates: nothing that "
                    "moves, switches a lamp or measures. Prints a table; --write writes a lab "
                    "config that names each instrument by a stable key.")
    d.add_argument("endpoints", nargs="*", metavar="ENDPOINT",
                   help="a port to probe besides the listed ones (path, pty, socket://…)")
    d.add_argument("--no-scan", dest="scan", action="store_false",
                   help="probe only the ENDPOINTs, not the ports pyserial lists")
    d.add_argument("--no-usb", dest="usb", action="store_false", help="skip the USB scan")
    d.add_argument("--usb-backend", default="cseabreeze",
                   choices=("cseabreeze", "pyseabreeze"), help="seabreeze backend")
    d.add_argument("--pyusb-backend", default=None, metavar="NAME",
                   help="pyseabreeze's pyusb backend (e.g. libusb1)")
    d.add_argument("--timeout-s", type=option(Number(0, 60, unit="s", above=True),
                                              "--timeout-s"), default=0.3, metavar="S",
                   help="wait this long for each identification reply (default 0.3)")
    d.add_argument("--write", metavar="LAB.toml", help="write a lab config of what was found")
    d.add_argument("--force", action="store_true", help="overwrite the --write file")
    d.set_defaults(handler=_discover)

    c = labsub.add_parser(
        "check", help="run the lab's self-test protocol and store its results",
        description="Run the lab-check protocol through the engine (results are stored as a "
                    "run and reported): per instrument a few safe checks, each against a limit "
                    "with its source. Prints pass/fail per check; exit 1 when any fails.")
    c.add_argument("--lab", metavar="LAB.toml", default="lab.toml",
                   help="lab config (default ./lab.toml)")
    add_store_argument(c)
    c.add_argument("--roles", default=None, metavar="R1,R2",
                   help="check only these instruments (default: every one configured)")
    c.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="a lab-check parameter (e.g. sphere_level_percent=50)")
    c.add_argument("--strict", action="store_true",
                   help="an expired calibration fails its check (default: a warning)")
    c.add_argument("--world", choices=("normbox", "analytic", "none"), default="analytic",
                   help="simulated labs: the world behind the emulators (default analytic)")
    c.set_defaults(handler=_check)

    k = labsub.add_parser(
        "calibrations", help="list each instrument's calibration and its due date",
        description="One line per instrument: certificate, date, due date, laboratory, stated "
                    "uncertainty, responsivity file. An expired calibration is a warning; with "
                    "--strict an error (exit 1).")
    k.add_argument("--lab", metavar="LAB.toml", default="lab.toml")
    k.add_argument("--strict", action="store_true", help="exit 1 on an expired calibration")
    k.set_defaults(handler=_calibrations)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _discover(args: argparse.Namespace) -> int:
    import time

    from normbox_lab.acquire import discover

    t0 = time.monotonic()
    findings = discover.discover(args.endpoints, scan_serial=args.scan, usb=args.usb,
                                 usb_backend=args.usb_backend,
                                 pyusb_backend=args.pyusb_backend, timeout_s=args.timeout_s)
    print(discover.format_table(findings))
    found = sum(f.status == "found" for f in findings)
    print(f"{found} instrument(s) found on {len(findings)} port(s) in "
          f"{time.monotonic() - t0:.1f} s")
    if args.write:
        path = discover.write_lab_config(findings, args.write, overwrite=args.force)
        print(f"wrote {path}: check it with `normbox-lab lab check --lab {path}`")
    return 0 if found else 1


def _roles(text: str) -> list[str]:
    """--roles R1,R2 as the one parser reads a list (an empty item, ``radiometer,,rotator``,
    is refused as ``30,,60`` is), each role once, at least one; which roles the lab has is
    the protocol's check."""
    from normbox_lab.acquire.params import ParameterError, parse_items, show

    roles = parse_items(text, "--roles")
    if not roles:
        raise ParameterError("--roles: empty; name at least one instrument (or leave the "
                             "option out: every one configured)")
    for k, role in enumerate(roles):
        if role in roles[:k]:
            raise ParameterError(f"--roles: {show(role)} is given twice")
    return roles


def _check(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.config import load_config
    from normbox_lab.commands.run import _parse_overrides

    config = load_config(args.lab)
    overrides = _parse_overrides("lab-check", args.param)
    if args.roles is not None:
        overrides["roles"] = _roles(args.roles)
    overrides["strict"] = bool(args.strict)
    from normbox_lab.protocols import lab_check
    from normbox_lab.sim.labsim import build_lab

    def terminal_operator(lab):
        # a real lab: the operator places the white patch at the terminal
        from normbox_lab.acquire.operator import TerminalOperator

        return TerminalOperator(world=lab.world)

    report = lab_check.run_check(config, args.store, overrides, make_lab=build_lab,
                                 world=args.world, make_operator=terminal_operator)
    for line in report.lines():
        print(line)
    return 0 if report.passed else 1


def _calibrations(args: argparse.Namespace) -> int:
    import datetime

    from normbox_lab.acquire.config import load_config

    config = load_config(args.lab)
    today = datetime.date.today()
    expired = 0
    for role, inst in config.instruments.items():
        cal = inst.calibration
        if cal is None:
            print(f"{role}: no calibration recorded")
            continue
        state = "in force"
        if cal.expired(today):
            expired += 1
            state = f"EXPIRED {(today - cal.due).days} days ago"
        extra = f", responsivity {cal.responsivity_file}" if cal.responsivity_file else ""
        print(f"{role}: certificate {cal.certificate} of {cal.date} by {cal.laboratory}, "
              f"±{cal.uncertainty_percent:g} % (k={cal.coverage_k:g}), due {cal.due}: "
              f"{state}{extra}")
    if expired:
        what = "error" if args.strict else "warning"
        print(f"{what}: {expired} expired calibration(s)", file=sys.stderr)
        return 1 if args.strict else 0
    return 0
