"""`normbox-lab sim serve DEVICE --pty | --tcp 127.0.0.1:PORT [--faults SPEC]`."""

from __future__ import annotations

import argparse
import signal
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="serve simulated instruments to outside programs")
    simsub = p.add_subparsers(dest="sim_command", metavar="SUBCOMMAND")
    s = simsub.add_parser(
        "serve", help="serve one emulator on a pty or a loopback TCP port",
        description="Serve one wire-level emulator until SIGTERM/SIGINT. The first line on "
                    "stdout names the endpoint: 'pty: /dev/pts/N' or 'tcp: 127.0.0.1:PORT'.")
    s.add_argument("device", metavar="DEVICE",
                   help="cs1000a, cs2000a, rotator-apt, rotator-zaber, sphere")
    where = s.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="create a pseudo-terminal")
    where.add_argument("--tcp", metavar="127.0.0.1:PORT",
                       help="listen on a loopback TCP port (PORT 0 picks a free one)")
    s.add_argument("--faults", default="", metavar="SPEC",
                   help="fault injection, e.g. 'no-reply=0.1,garble=0.05,disconnect@7'")
    s.add_argument("--seed", type=int, default=0, help="seed of the emulator's randomness")
    s.add_argument("--option", action="append", default=[], metavar="K=V",
                   help="an emulator option, as in the sim:// URL (e.g. noise=off, "
                        "time_factor=0.05 for the radiometers); repeatable")
    s.set_defaults(handler=_serve)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _serve(args: argparse.Namespace) -> int:
    from normbox_lab.sim import core, transport

    if args.device not in core.known_devices():
        print(f"normbox-lab: unknown device {args.device!r}; known: "
              f"{', '.join(core.known_devices()) or '(none yet)'}", file=sys.stderr)
        return 2

    def _stop(signum, frame):
        raise SystemExit(0)

    options = {}
    for item in args.option:
        key, sep, value = item.partition("=")
        if not sep or not key:
            print(f"normbox-lab: --option wants K=V, got {item!r}", file=sys.stderr)
            return 2
        options[key] = value
    signal.signal(signal.SIGTERM, _stop)
    try:
        if args.pty:
            transport.serve_pty(args.device, faults=args.faults, seed=args.seed,
                                options=options)
        else:
            host, _, port = args.tcp.rpartition(":")
            transport.serve_tcp(args.device, host, int(port), faults=args.faults,
                                seed=args.seed, options=options)
    except KeyboardInterrupt:
        pass
    except (TypeError, ValueError) as exc:   # a bad --option, refused by the emulator
        print(f"normbox-lab: cannot serve {args.device}: {exc}", file=sys.stderr)
        return 2
    return 0
