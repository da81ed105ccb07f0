"""Random streams of the band-vector renderers: a seed per chunk of paths, and one
independent PCG32 generator per lane.

`chunk_seed(seed, chunk_no)`: the renders draw their paths in chunks; each chunk's seed is a
hash of the render's seed and the chunk's number, so a render is deterministic for a seed and
its chunks are independent.  `lane_rng`: see its doc.  `FirstBounceDraws`: the first bounce of
`bandpath.BandPathTracer._path_loop` on the caller's quasi-random numbers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def chunk_seed(seed: int, chunk_no: int) -> int:
    return (int(seed) * 0x9E3779B1 + chunk_no * 0x85EBCA6B + 0x2545F491) & 0xFFFFFFFFFFFF


def lane_rng(m: Any, dr: Any, seed: int, lane: Any) -> Any:
    """One PCG32 generator per lane, `lane` (UInt32 or UInt64) the lane's index in the whole
    render, initial state and stream both hashed from (seed, lane) with TEA
    (`mitsuba.sample_tea_64`), as Mitsuba's own samplers seed theirs.

    Not PCG32(initstate=seed, initseq=lane): streams that share their state and differ only in
    the increment are correlated.  Measured on the radiometer view at 90° (16 384 paths, 100
    renders): the spread of the means was 0.68 of the per-path standard error (negatively
    correlated lanes), 0.90–0.97 with hashed seeds."""
    s = int(seed) & 0xFFFFFFFFFFFFFFFF
    key = dr.opaque(m.UInt32, (s ^ (s >> 32) * 0x9E3779B1) & 0xFFFFFFFF)
    lo = m.UInt32(lane)
    hi = m.UInt32(m.UInt64(lane) >> 32)
    state = m.sample_tea_64(lo ^ key, hi ^ dr.opaque(m.UInt32, 0x6A09E667))
    stream = m.sample_tea_64(hi ^ key, lo ^ dr.opaque(m.UInt32, 0xBB67AE85))
    rng = m.PCG32(size=dr.width(lo))
    rng.seed(initstate=state, initseq=stream)
    return rng


#: how many uniform numbers `_path_loop`'s first bounce draws with `patches` (the patch pick,
#: the light sample 2, the direction 3); without `patches` the first is not drawn
FIRST_BOUNCE_DRAWS = 6


class FirstBounceDraws:
    """A generator stand-in for one bounce: `next_float32()` gives the next of `values` where
    `use` (the first bounce), the generator's number elsewhere; the generator always advances."""

    def __init__(self, rng: Any, use: Any, values: Sequence[Any]) -> None:
        import drjit as dr

        self.rng, self.use, self.values, self.dr = rng, use, list(values), dr

    def next_float32(self) -> Any:
        u = self.rng.next_float32()
        return self.dr.select(self.use, self.values.pop(0), u) if self.values else u
