"""Indices that are valid in every lane, and radiance that is a number, for every kernel.

A gather or scatter with an index outside its array is undefined behaviour: on one CPU it reads
garbage quietly, on another it kills the process.  Inactive lanes are no exception (a masked
gather still forms its address on some back ends, and Dr.Jit's bounds checks test every lane),
and an index formed from a NaN or an infinite float is arbitrary (x86 turns it into
0x80000000).  So every index in the project's kernels comes from one of these two functions:

- `cell_index(x, n)`: the cell ⌊x⌋ of a float coordinate, clipped to 0 … n − 1, and 0 where x
  is not finite or the lane is inactive;
- `lane_index(i, active)`: an integer index where the lane is active, 0 elsewhere.

`require_finite` turns a non-finite value in a render's output into a typed error
(`core.errors.RenderError`) on the host.  `tests/kernel_paths.py` renders every kernel path
under Dr.Jit's bounds checks (`JitFlag.Debug`) to prove the rule holds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from normbox_lab.core.errors import RenderError


def cell_index(dr: Any, m: Any, x: Any, n: Any, active: Any = True) -> Any:
    """UInt32 ⌊x⌋ clipped to [0, n − 1] (n a Python or opaque JIT float), 0 where `x` is NaN
    or infinite or the lane is not `active`."""
    ok = dr.isfinite(x) & active
    return m.UInt32(dr.clip(dr.floor(dr.select(ok, x, 0.0)), 0.0, n - 1.0))


def lane_index(dr: Any, index: Any, active: Any) -> Any:
    """`index` where `active`, 0 elsewhere: an inactive lane never carries an arbitrary index."""
    return dr.select(active, index, 0)


def require_finite(values: Any, what: str) -> np.ndarray:
    """`values` as an array (its own dtype), or `RenderError` naming `what` and how many
    entries are NaN or infinite (and the first one's position)."""
    arr = np.asarray(values)
    if not np.isfinite(arr).all():
        bad = ~np.isfinite(arr)
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise RenderError(f"{what}: {int(bad.sum())} of {arr.size} values are NaN or "
                          f"infinite (first at index {first}); the estimate is not returned")
    return arr


#: Dr.Jit's LLVM back end gathers (value, slope) pairs with one packet load only from a source
#: that is 64-byte aligned; an array made from a NumPy buffer keeps NumPy's address, so the
#: same code compiled a packet kernel in one process and separate gathers in the next (a new
#: kernel, 10-25 s on a 2-core AVX2 CPU, in a second run with the same options).
JIT_ALIGN_BYTES = 64


def jit_table(array_type: Any, values: Any, dtype: Any = np.float32) -> Any:
    """A Dr.Jit array (`array_type`: m.Float, m.UInt32, ...) holding `values`, from a
    64-byte-aligned buffer: every kernel that gathers from it is the same kernel in every
    process (packet gathers where the element count allows)."""
    a = np.ascontiguousarray(values, dtype=dtype).ravel()
    item = a.dtype.itemsize
    buf = np.empty(a.size + JIT_ALIGN_BYTES // item, dtype=a.dtype)
    off = (-buf.ctypes.data % JIT_ALIGN_BYTES) // item
    out = buf[off:off + a.size]
    out[:] = a
    return array_type(out)
