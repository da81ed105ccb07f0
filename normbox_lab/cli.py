"""The `normbox-lab` command line.

Start-up must stay fast (`--help` ≤ 0.3 s): this module imports only argparse and the
standard library.  Every subcommand lives in its own `normbox_lab.commands.<name>` module that
exposes ``register(subparsers)``; heavy libraries are imported inside the handlers.

A command line imports only the module of the command it names (`build_parser(argv)`): the
other commands are listed by name and help line from `COMMANDS`, so `--help` imports no
command module at all (some import numpy while they register: 0.1–0.2 s of CPU), and
`sim serve` starts without the pipeline's modules.  `build_parser()` without argv registers
every module (the whole tree; tests check `COMMANDS` against it).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import typing
from collections.abc import Sequence

from normbox_lab import __version__

#: every command, in the order `--help` lists it: (name, the `normbox_lab.commands` module that
#: registers it, its help line as that module gives it)
COMMANDS: tuple[tuple[str, str, str], ...] = (
    ("init", "init", "write a lab config"),
    ("sim", "sim", "serve simulated instruments to outside programs"),
    ("run", "run", "run (or resume, or dry-run) a measurement protocol"),
    ("runs", "runs", "list the runs in the store"),
    ("qa", "qa", "list the quality flags of a run"),
    ("export", "export", "export a run to NetCDF, CSV or JSON"),
    ("import", "import_", "import measured data into the store"),
    ("fit", "pipeline", "fit Cook-Torrance/GGX BRDFs to a gonio run"),
    ("predict", "pipeline", "render a reference run with the fitted materials"),
    ("compare", "pipeline", "compare a prediction with its reference run"),
    ("report", "pipeline", "write the HTML report of a compared reference run"),
    ("demo", "demo", "run the whole virtual campaign (BRDFs, fits, light map, sweep, report)"),
    ("budget", "budget", "error budget per source, 95 %% intervals, sample-angle offsets"),
    ("bench", "bench", "benchmarks (figures; last line: ratio to a baseline)"),
    ("tui", "tui", "the operator console (instruments, run, spectrum, runs, results)"),
    ("image", "image", "spectral images: virtual camera, Fig. 1, MIST, W&W, EXR"),
    ("scene", "scene", "renderer-neutral scene packages of a campaign"),
    ("lab", "lab", "find the instruments, check them, list their calibrations"),
)
#: subcommand modules, in the order `--help` lists their commands; each adds its own parsers
COMMAND_MODULES: tuple[str, ...] = tuple(dict.fromkeys(module for _, module, _ in COMMANDS))

EPILOG = """\
The default store is normbox.sqlite in the working directory; --store picks another.
Start with:  normbox-lab init lab.toml --sim   then   normbox-lab run reference-sweep --lab lab.toml
"""


class OneLineParser(argparse.ArgumentParser):
    """A parser whose refusal of the command line is one line and exit 2 (argparse prints its
    usage first; scripts and the operator want the line that says what is wrong).  Subcommand
    parsers are made of the same class."""

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> typing.Any:
        # `--time-scale=--`: argparse (3.11) drops the "--" and hands the option an empty
        # list, unchecked by its type (a traceback later); the text goes to the type instead
        if arg_strings == ["--"] and action.nargs is None and action.option_strings:
            return self._get_value(action, "--")
        return super()._get_values(action, arg_strings)

    def error(self, message: str) -> typing.NoReturn:
        from normbox_lab.core.errors import one_line

        flat = one_line(" ".join(str(message).split()))
        self.exit(2, f"normbox-lab: error: {self.prog.removeprefix('normbox-lab ')}: {flat}\n"
                  if self.prog != "normbox-lab" else f"normbox-lab: error: {flat}\n")


def command_module(argv: Sequence[str]) -> str | None:
    """The module of the command `argv` names (its first word that is not an option; the
    top-level options take no value), or None (``--help``, ``--version``, nothing, a typo)."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return next((module for name, module, _ in COMMANDS if name == word), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command-line parser.  With `argv`, only the module of the command it names
    registers; every other command is a stub with its help line (enough for ``--help`` and
    for refusing a misspelt command).  Without, every module registers."""
    parser = OneLineParser(
        prog="normbox-lab",
        description="Acquisition, instrument control and validation for the Normbox "
                    "(spectral ground truth for predictive rendering).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"normbox-lab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    wanted = command_module(argv) if argv is not None else None
    registered: set[str] = set()
    for name, module, help_text in COMMANDS:
        if argv is not None and module != wanted:
            sub.add_parser(name, help=help_text)
        elif module not in registered:
            registered.add(module)
            importlib.import_module(f"normbox_lab.commands.{module}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from normbox_lab.core.errors import NormboxError, one_line

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    try:
        return int(args.handler(args) or 0)
    except NormboxError as exc:
        print(f"normbox-lab: error: {one_line(str(exc))}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("normbox-lab: interrupted", file=sys.stderr)
        return 130
