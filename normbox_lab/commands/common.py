"""Arguments several subcommands share."""

from __future__ import annotations

import argparse


def add_store_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", default="normbox.sqlite", metavar="FILE",
                   help="the measurement store (SQLite; default: normbox.sqlite here)")


def require_store(path: str) -> None:
    """A command that reads a store refuses a missing file (opening would create it)."""
    from pathlib import Path

    from normbox_lab.core.errors import StoreError

    if not Path(path).exists():
        raise StoreError(f"no store at {path}")
