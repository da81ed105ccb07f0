"""Arguments several subcommands share."""

from __future__ import annotations

import argparse


def add_store_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--store", default="normbox.sqlite", metavar="FILE",
                   help="the measurement store (SQLite; default: normbox.sqlite here)")


def require_store(path: str) -> None:
    """A command that reads a store refuses a missing file (opening would create it): the
    path a person gave (or the default one) names no store, a refusal (exit 2)."""

    from normbox_lab.core.errors import BadPath

    if not store_exists(path):
        raise BadPath(f"no store at {path}")


def store_exists(path: str) -> bool:
    """Whether a store file is there; a path the system refuses to look up (a NUL byte, a
    name too long) is refused with one line (`BadPath`, exit 2)."""
    from pathlib import Path

    from normbox_lab.core.errors import BadPath

    try:
        return Path(path).exists()
    except (OSError, ValueError) as exc:
        raise BadPath(f"{path}: cannot be a store ({exc})") from None


def output_path(path: str, what: str) -> str:
    """A file a person names to be written, as given; refused with one line (`BadPath`,
    exit 2) before anything is computed when it cannot be written: empty, a directory, in a
    folder that does not exist, a name over 255 bytes, a NUL byte."""
    from pathlib import Path

    from normbox_lab.core.errors import BadPath

    if not path.strip():
        raise BadPath(f"{what}: an empty path names no file")
    if "\x00" in path:
        raise BadPath(f"cannot write {path}: a file name has no NUL byte")
    target = Path(path)
    try:
        if len(target.name.encode("utf-8", "surrogateescape")) > 255:
            raise BadPath(f"{path}: the file name is over 255 bytes")
        if target.is_dir():
            raise BadPath(f"cannot write {path}: it is a directory")
        if not target.parent.is_dir():
            raise BadPath(f"cannot write {path}: no folder {target.parent}")
    except (OSError, ValueError) as exc:
        raise BadPath(f"cannot write {path} ({exc})") from None
    return path


def input_path(path: str, what: str, *, directory: bool = False) -> str:
    """A file a person names to be read, as given; refused with one line (`BadPath`, exit 2)
    when the text is empty or names no regular file (with `directory`: nor a directory).  A
    device such as /dev/zero or a FIFO would be read without end, or wait for a writer."""
    import stat
    from pathlib import Path

    from normbox_lab.core.errors import BadPath

    if not path.strip():
        raise BadPath(f"{what}: an empty path names no file")
    try:
        mode = Path(path).stat().st_mode
    except FileNotFoundError:
        raise BadPath(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise BadPath(f"{path}: cannot read ({exc})") from None
    if stat.S_ISREG(mode) or (directory and stat.S_ISDIR(mode)):
        return path
    raise BadPath(f"{path}: not a regular file{' or directory' if directory else ''}")


def renderer_name(text: str) -> str:
    """An argparse ``type=`` for ``--renderer NAME`` (an imported renderer's name): the rule
    `import prediction` stores names by (letters, digits and . _ + -, at most 64), so a name
    of any other text is one line and exit 2, never a lookup of text SQLite cannot hold."""
    import argparse

    from normbox_lab.core.errors import one_line
    from normbox_lab.predict.renderers import RENDERER_NAME_RE

    if not RENDERER_NAME_RE.match(text):
        shown = one_line(text if len(text) <= 24 else text[:23] + "…")
        raise argparse.ArgumentTypeError(f"{shown!r} is not a renderer name (letters, digits "
                                         "and . _ + -, at most 64)")
    return text
