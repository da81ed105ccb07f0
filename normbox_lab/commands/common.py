"""Arguments several subcommands share."""

from __future__ import annotations

import argparse


def add_store_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", default="normbox.sqlite", metavar="FILE",
                   help="the measurement store (SQLite; default: normbox.sqlite here)")
