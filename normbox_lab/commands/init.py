"""`normbox-lab init LAB.toml [--sim] [--force]`."""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("init", help="write a lab config",
                       description="Write a lab config. --sim: every instrument emulated "
                                   "(sim:// ports), ready for `normbox-lab run`.")
    p.add_argument("path", metavar="LAB.toml")
    p.add_argument("--sim", action="store_true", help="every instrument emulated")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(handler=_init)


def _init(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.config import load_config, write_sim_config
    from normbox_lab.commands.common import output_path

    if not args.sim:
        print("normbox-lab: init writes simulated labs (--sim); for real instruments run "
              "`normbox-lab lab discover --write LAB.toml` (docs/first-contact.md)",
              file=sys.stderr)
        return 2
    path = write_sim_config(output_path(args.path, "PATH"), overwrite=args.force)
    cfg = load_config(path)  # what we write must load
    print(f"wrote {path}: {len(cfg.instruments)} simulated instruments "
          f"({', '.join(cfg.instruments)})")
    return 0
