"""The `normbox-lab` command line.

Start-up must stay fast (`--help` ≤ 0.3 s): this module imports only argparse and the
standard library.  Every subcommand lives in its own `normbox_lab.commands.<name>` module that
exposes ``register(subparsers)``; heavy libraries are imported inside the handlers.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import typing

from normbox_lab import __version__

#: subcommand modules, in the order `--help` lists them; each adds its own parsers
COMMAND_MODULES: tuple[str, ...] = (
    "init",
    "sim",
    "run",
    "runs",
    "qa",
    "export",
    "import_",
    "pipeline",
    "demo",
    "budget",
    "bench",
    "tui",
    "image",
    "scene",
    "lab",
)

EPILOG = """\
The default store is normbox.sqlite in the working directory; --store picks another.
Start with:  normbox-lab init lab.toml --sim   then   normbox-lab run reference-sweep --lab lab.toml
"""


class OneLineParser(argparse.ArgumentParser):
    """A parser whose refusal of the command line is one line and exit 2 (argparse prints its
    usage first; scripts and the operator want the line that says what is wrong).  Subcommand
    parsers are made of the same class."""

    def error(self, message: str) -> typing.NoReturn:
        flat = " ".join(str(message).split())
        self.exit(2, f"normbox-lab: error: {self.prog.removeprefix('normbox-lab ')}: {flat}\n"
                  if self.prog != "normbox-lab" else f"normbox-lab: error: {flat}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="normbox-lab",
        description="Acquisition, instrument control and validation for the Normbox "
                    "(spectral ground truth for predictive rendering).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"normbox-lab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"normbox_lab.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from normbox_lab.core.errors import NormboxError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        return int(args.handler(args) or 0)
    except NormboxError as exc:
        print(f"normbox-lab: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("normbox-lab: interrupted", file=sys.stderr)
        return 130
