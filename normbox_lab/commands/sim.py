"""`normbox-lab sim serve DEVICE --pty | --tcp 127.0.0.1:PORT [--faults SPEC]`."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from normbox_lab.acquire.params import (
    PROBABILITY,
    SEED,
    WORKERS,
    Number,
    ParameterError,
    check_emulator_options,
    option,
    parse_fault_spec,
)

SERVE_EPILOG = """\
The emulator is loaded completely (its colorimetric tables included) before the endpoint line
is printed, and it keeps running while no client is connected. A new TCP connection, or a client
opening the pty, starts from a clean line. Linux ptys cannot carry RTS/DTR (the modem-line
ioctls fail on them): clients that set or pulse RTS/DTR themselves (some Thorlabs APT drivers
pulse RTS on connect) should use --tcp and pyserial's socket://HOST:PORT URL.
IPv6 loopback: --tcp ::1:0 (printed as tcp: [::1]:PORT)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="serve simulated instruments to outside programs")
    simsub = p.add_subparsers(dest="sim_command", metavar="SUBCOMMAND")
    _add_serve(simsub)
    _add_faults(simsub)
    _add_latency(simsub)
    _add_campaign(simsub)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _add_serve(simsub: argparse._SubParsersAction) -> None:
    """`sim serve DEVICE --pty | --tcp HOST:PORT`: one emulator for outside programs."""
    from normbox_lab.sim.core import EMULATORS

    s = simsub.add_parser(
        "serve", help="serve one emulator on a pty or a loopback TCP port",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Serve one wire-level emulator until SIGTERM/SIGINT. The first line on "
                    "stdout names the endpoint: 'pty: /dev/pts/N' or 'tcp: 127.0.0.1:PORT'.",
        epilog=SERVE_EPILOG)
    s.add_argument("device", metavar="DEVICE",
                   help=", ".join(EMULATORS))
    where = s.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true",
                       help="create a pseudo-terminal (no RTS/DTR: use --tcp for clients "
                            "that set modem lines)")
    where.add_argument("--tcp", metavar="127.0.0.1:PORT",
                       help="listen on a loopback TCP port: 127.0.0.1, localhost or ::1 "
                            "(PORT 0 picks a free one); reach it with socket://HOST:PORT")
    s.add_argument("--rfc2217", action="store_true",
                   help="with --tcp: speak RFC 2217 (reach it with rfc2217://HOST:PORT): "
                        "in_waiting counts every byte, so read_all() clients such as "
                        "colour-specio work; socket:// reports at most 1 byte")
    s.add_argument("--faults", default="", metavar="SPEC",
                   help="fault injection, e.g. 'no-reply=0.1,garble=0.05,disconnect@7': the "
                        "kinds DEVICE declares, within their ranges (`sim faults DEVICE` "
                        "lists them)")
    s.add_argument("--seed", type=option(SEED, "--seed"),
                   default=0, help="seed of the emulator's randomness")
    s.add_argument("--option", action="append", default=[], metavar="K=V",
                   help="an emulator option, as in the sim:// URL (e.g. noise=off, "
                        "time_factor=0.05 for the radiometers); repeatable")
    s.set_defaults(handler=_serve)


def _add_faults(simsub: argparse._SubParsersAction) -> None:
    """`sim faults [DEVICE]`: the fault kinds each emulator declares."""
    fl = simsub.add_parser(
        "faults", help="the fault kinds each emulator declares: range, distribution, detector",
        description="The fault registry (sim.core.fault_table): what `sim serve --faults`, "
                    "the sim:// URLs and the campaign accept and draw.")
    fl.add_argument("device", nargs="?", metavar="DEVICE",
                    help="one device (default: every emulated device)")
    fl.set_defaults(handler=_faults)


def _add_latency(simsub: argparse._SubParsersAction) -> None:
    """`sim latency DEVICE`: a served radiometer's first measurement from a cold start."""
    from normbox_lab.sim.core import devices_for

    lat = simsub.add_parser(
        "latency", help="first-measurement latency of a served radiometer from a cold start",
        description="Start `sim serve DEVICE --tcp 127.0.0.1:0` in a new process (noise off, "
                    "the default 100 cd/m² light), connect as soon as the endpoint line "
                    "appears, enter remote mode and time the first measurement against the "
                    "emulator's timing model. Last line: the ratio measured / model.")
    lat.add_argument("device", choices=devices_for("radiometer"), metavar="DEVICE",
                     help=" or ".join(devices_for("radiometer")))
    lat.set_defaults(handler=_latency)


def _add_campaign(simsub: argparse._SubParsersAction) -> None:
    """`sim campaign`: deterministic simulation testing of the whole lab."""
    camp = simsub.add_parser(
        "campaign", help="deterministic simulation testing of the whole lab",
        description="Draw N scenarios from the seed (a protocol and its parameters, a fault "
                    "schedule over every emulator's fault kinds, the operator's answers, "
                    "pauses, emergency stops and kill -9 followed by --resume), run each "
                    "through normbox-lab itself in the simulated lab and check the "
                    "invariants: the world's truth, typed failures, no hang, consistent "
                    "state, exact resume.  A failing scenario is shrunk and printed with the "
                    "command that reproduces it.  Last line: 'N scenarios: V violations' "
                    "(V counts scenario x violation class); exit 1 when V > 0.")
    camp.add_argument("--scenarios", type=option(Number(1, 1_000_000, whole=True), "--scenarios"),
                      default=30, metavar="N",
                      help="number of scenarios (default 30)")
    camp.add_argument("--seed", type=option(SEED, "--seed"), default=0, metavar="S",
                      help="campaign seed (scenario i of seed S is always the same)")
    camp.add_argument("--jobs", type=option(WORKERS, "--jobs"), default=1, metavar="J",
                      help="scenarios run in J parallel processes")
    camp.add_argument("--keep", metavar="DIR",
                      help="keep every scenario's lab, store, output and journals under DIR")
    camp.add_argument("--replay", metavar="JSON",
                      help="run one scenario given as JSON (what a failure prints)")
    camp.add_argument("--normbox-share", type=option(PROBABILITY, "--normbox-share"),
                      default=0.1, metavar="P",
                      help="share of radiometer scenarios on the Mitsuba world, the others "
                           "on the analytic world (default 0.1)")
    camp.add_argument("--max-faults", type=option(Number(0, 100, whole=True), "--max-faults"),
                      default=3, metavar="K",
                      help="at most K fault rules per scenario (default 3)")
    camp.add_argument("--no-shrink", dest="shrink", action="store_false",
                      help="report failing scenarios without shrinking them")
    camp.add_argument("--quiet", action="store_true",
                      help="print only failing scenarios and the summary")
    camp.set_defaults(handler=_campaign)


def _fail(message: str) -> int:
    from normbox_lab.core.errors import one_line

    print(f"normbox-lab: {one_line(message)}", file=sys.stderr)
    return 2


def check_fault_spec(spec: str) -> None:
    """Every number of a `--faults` spec through the one parser (``garble@-1`` never fired,
    ``garble=NaN`` never fired either): a refusal is one line naming the rule.  The same
    reading as a lab config's ``sim://…?faults=`` (`acquire.params.parse_fault_spec`)."""
    parse_fault_spec(spec, "--faults")


def _one_of(field: str, value: Any, allowed: Any) -> None:
    from normbox_lab.acquire.params import show

    if not isinstance(value, str) or value not in allowed:
        raise ParameterError(f"{field}: {show(value)} is not one of {', '.join(allowed)}")


def check_replay_scenario(scenario: Any) -> None:
    """A replayed scenario's fields as a campaign draws them (JSON gives any type: params
    "x" failed in `describe` with a traceback): whole numbers, a shipped protocol with its
    own parameters within their limits, the lab's devices, world, policy and quality;
    `ParameterError`, one line."""
    from normbox_lab.acquire.params import check_parameters, show
    from normbox_lab.acquire.plan import PROTOCOL_NAMES, load_protocol
    from normbox_lab.sim.core import devices_for

    for field, value, kind in (("seed", scenario.seed, SEED),
                               ("index", scenario.index, Number(0, 10**9, whole=True))):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ParameterError(f"{field}: {show(value)} is not a whole number")
        kind.check(field, value, {}, None)
    _one_of("protocol", scenario.protocol, [p for p in PROTOCOL_NAMES if p != "lab-check"])
    _one_of("world", scenario.world, ("analytic", "normbox", "none"))
    _one_of("radiometer", scenario.radiometer, devices_for("radiometer"))
    _one_of("rotator", scenario.rotator, devices_for("rotator"))
    _one_of("policy", scenario.policy, ("retry", "skip", "abort"))
    _one_of("quality", scenario.quality, ("quick", "default", "high"))
    _one_of("radiometer_format", scenario.radiometer_format, ("ascii", "binary", "hex"))
    if not isinstance(scenario.params, dict) or not isinstance(scenario.extra, dict):
        raise ParameterError("params and extra: expected JSON objects")
    module = load_protocol(scenario.protocol)
    unknown = [k for k in scenario.params if k not in module.PARAMETERS]
    if unknown:
        raise ParameterError(f"params: {show(unknown[0])} is no parameter of "
                             f"{scenario.protocol}")
    check_parameters(vars(module).get("LIMITS") or {}, scenario.params)
    for action in scenario.actions:
        if not (isinstance(action.what, str) and isinstance(action.event, str)
                and isinstance(action.nth, int) and not isinstance(action.nth, bool)
                and 1 <= action.nth <= 10**6):
            raise ParameterError(f"action {show(action.what)}: what and event are names, "
                                 "nth a whole number from 1")


def check_replay_faults(scenario: Any) -> None:
    """A replayed scenario's faults (JSON numbers: NaN, 1e400 and a huge count parse) through
    the same kinds as a ``--faults`` spec, then the device's own table (kinds and ranges):
    `ParameterError`, one line."""
    from normbox_lab.acquire.params import FaultRuleText, check_fault_values, show
    from normbox_lab.sim import core

    for fault in scenario.faults:
        field = f"fault of {show(fault.role)}"
        if not isinstance(fault.role, str):
            raise ParameterError(f"{field}: the role must be a name")
        try:
            device = scenario.device_of(fault.role)
        except KeyError:
            raise ParameterError(f"{field}: not a role of a campaign's lab") from None
        check_fault_values(FaultRuleText(fault.kind, fault.mode, fault.value, fault.param),
                           field)
        try:
            core.FaultInjector(fault.spec(), 0, core.fault_table(device)[device])
        except ValueError as exc:
            raise ParameterError(f"{field} ({device}): {exc}") from None


def _serve(args: argparse.Namespace) -> int:
    from normbox_lab.core.clock import RealClock
    from normbox_lab.sim import core, serve

    if args.device not in core.known_devices():
        return _fail(f"unknown device {args.device!r}; known: "
                     f"{', '.join(core.known_devices()) or '(none yet)'}")
    options = {}
    for item in args.option:
        key, sep, value = item.partition("=")
        if not sep or not key:
            return _fail(f"--option wants K=V, got {item!r}")
        options[key] = value
    endpoint = None
    if args.rfc2217 and args.tcp is None:
        return _fail("--rfc2217 goes with --tcp")
    if args.tcp is not None:
        try:
            endpoint = serve.parse_tcp_endpoint(args.tcp)
        except serve.EndpointError as exc:
            return _fail(str(exc))
    try:
        check_fault_spec(args.faults)
        check_emulator_options(options, "--option")
    except ParameterError as exc:
        return _fail(str(exc))
    try:
        emulator = core.create(args.device, clock=RealClock(), faults=args.faults,
                               seed=args.seed, **options)
    except (TypeError, ValueError) as exc:   # a bad --option or --faults, refused
        return _fail(f"cannot serve {args.device}: {exc}")
    emulator.prepare()
    try:
        server = serve.PtyServer(emulator) if endpoint is None else \
            serve.TcpServer(emulator, *endpoint, rfc2217=args.rfc2217)
    except serve.EndpointError as exc:
        return _fail(str(exc))
    print(server.endpoint, flush=True)
    serve.serve_until_signalled(server)       # SIGTERM/SIGINT: the process ends there
    return 0


def _faults(args: argparse.Namespace) -> int:
    from normbox_lab.sim import core

    try:
        table = core.fault_table(args.device)
    except ValueError as exc:
        return _fail(str(exc))
    for device, kinds in table.items():
        print(f"{device}:")
        for _, k in sorted(kinds.items()):
            print("  " + k.row().strip("|").replace(" | ", "  |  ").strip())
    return 0


def _campaign(args: argparse.Namespace) -> int:
    from normbox_lab.campaign.campaign import run_campaign

    if args.scenarios < 1 or args.jobs < 1 or args.max_faults < 0:
        return _fail("--scenarios and --jobs must be at least 1, --max-faults at least 0")
    if not 0.0 <= args.normbox_share <= 1.0:
        return _fail("--normbox-share must be within [0, 1]")
    if args.replay is not None:
        from normbox_lab.campaign.scenario import Scenario

        try:
            scenario = Scenario.from_json(args.replay)
        except (ValueError, TypeError, KeyError, RecursionError) as exc:   # [[[[…: too deep
            return _fail(f"--replay wants a scenario as printed by a campaign: {exc}")
        try:
            check_replay_scenario(scenario)
            check_replay_faults(scenario)
        except ParameterError as exc:
            return _fail(f"--replay: {exc}")
    results = run_campaign(args.scenarios, args.seed, args.jobs, args.keep,
                           shrink_failures=args.shrink, normbox_share=args.normbox_share,
                           replay=args.replay, verbose=not args.quiet,
                           max_faults=args.max_faults)
    return 1 if any(r.violations for r in results) else 0


def _read_to(stream: Any, end: bytes) -> bytes:
    """Bytes up to and including `end` (or what came before the connection closed)."""
    buf = b""
    while not buf.endswith(end):
        byte = stream.read(1)
        if not byte:
            break
        buf += byte
    return buf


def _shown(reply: bytes) -> str:
    """A reply for the console: its text, or the name of a control byte (ACK, BEL, NAK)."""
    names = {b"\x06": "ACK", b"\x07": "BEL", b"\x15": "NAK"}
    return names.get(reply.strip(), reply.strip().decode(errors="replace"))


def _latency(args: argparse.Namespace) -> int:
    import socket
    import subprocess
    import time

    from normbox_lab.sim import core
    from normbox_lab.sim.radiometer_common import DEFAULT_LUMINANCE_CD_M2

    model = core.create(args.device, noise="off")
    # the emulator says which bytes take the line, start a measurement and end its replies
    remote, remote_end, measure, first_end, final = type(model).latency_script
    module = sys.modules[type(model).__module__]
    model_s = (model.measure_time_s(DEFAULT_LUMINANCE_CD_M2)
               + module.COMMAND_DELAY_S * model.time_factor + model.line_time_s(len(final)))
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "normbox_lab", "sim", "serve", args.device,
                             "--tcp", "127.0.0.1:0", "--option", "noise=off"],
                            stdout=subprocess.PIPE, text=True)
    try:
        endpoint = proc.stdout.readline().strip()
        ready_s = time.monotonic() - t0
        if not endpoint.startswith("tcp: "):
            return _fail(f"sim serve {args.device} printed {endpoint!r}, not an endpoint")
        port = int(endpoint.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=60) as conn:
            lines = conn.makefile("rb")
            conn.sendall(remote)
            _read_to(lines, remote_end)
            t_meas = time.monotonic()
            conn.sendall(measure)
            first = _read_to(lines, first_end)
            t_first = time.monotonic() - t_meas
            last = _read_to(lines, final)
            took_s = time.monotonic() - t_meas
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    print(f"{args.device}: endpoint line after {ready_s:.2f} s (cold start)")
    print(f"first reply {_shown(first)} after {t_first:.3f} s; "
          f"final {_shown(last)} after {took_s:.3f} s")
    print(f"timing model {model_s:.3f} s (pre-measurement + measurement + final reply)")
    print(f"ratio {took_s / model_s:.3f}")
    return 0
