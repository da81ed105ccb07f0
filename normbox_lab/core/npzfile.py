"""A .npz file written whole or not at all (temporary file in the same folder, then rename):
a reader never sees half a file, and a writer that dies leaves none behind."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any


def write_npz(path: Path, **arrays: Any) -> None:
    """Write `arrays` (NumPy's .npz, uncompressed) to `path`, whole or not at all; raises
    `OSError` when it cannot (no partial or temporary file is left)."""
    import numpy as np

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def keep_npz(path: Path, **arrays: Any) -> None:
    """`write_npz` for a cache: a folder that cannot be written (read-only, full) only costs
    computing again next time."""
    try:
        write_npz(path, **arrays)
    except OSError:
        pass
