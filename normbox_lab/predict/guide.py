"""A guide for direction sampling: small bright rectangles a path vertex also samples by area.

In the Normbox the four 19 mm side faces of the ceiling aperture are lit by the panel from
millimetres away: about 2 % of the light on the sample, and most of the variance of a path
tracer that finds them only by BSDF sampling.  A vertex with a guide sends `GUIDE_SHARE` of its
direction samples to a point on the faces (a face picked by area × the share of its corners in
front of the vertex, the point uniform), the rest to its BSDF; the direction's pdf is the
mixture of both (one-sample multiple importance sampling, balance heuristic), the light
sample's MIS weight uses the same pdf, so every estimate stays unbiased.

Used by `bandpath.BandPathTracer._path_loop` at every vertex and by `patchset` at the patch
vertex, when the tracer's `guide` is set (`fastrender.FastNormbox`: `scene.aperture_sides_m`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class GuideRects:
    """Small bright rectangles a path vertex also samples directly (by area, one-sample MIS with
    the BSDF mixture): each (corner, edge 1, edge 2) in metres."""

    rects: tuple[tuple[tuple[float, float, float], tuple[float, float, float],
                       tuple[float, float, float]], ...]

    @property
    def areas_m2(self) -> np.ndarray:
        return np.array([np.linalg.norm(np.cross(e1, e2)) for _, e1, e2 in self.rects])


#: the share of a vertex's direction samples that go to the guide rectangles
GUIDE_SHARE = 0.1


class GuideKernel:
    """`GuideRects` in a kernel, at the vertex o with normal `normal`: a rectangle picked with
    probability ∝ its area × the share of its corners in front of the vertex's plane (a face
    behind the patch is never picked; all behind: by area), a point uniform on it, and the
    solid-angle pdf of any direction (every rectangle the ray crosses, occluded or not)."""

    def __init__(self, m: Any, dr: Any, guide: GuideRects, o: Any, normal: Any) -> None:
        self.m, self.dr, self.o = m, dr, o
        self.rects = []
        weights = []
        for (corner, e1, e2), area in zip(guide.rects, guide.areas_m2, strict=True):
            c, a, b = (np.asarray(v, dtype=np.float64) for v in (corner, e1, e2))
            front = m.Float(0.0)
            for q in (c, c + a, c + b, c + a + b):
                front += dr.select(dr.dot(self._vec(q) - o, normal) > 0, 0.25, 0.0)
            weights.append(front * float(area))
            n = np.cross(a, b) / area
            self.rects.append((self._vec(c), self._vec(a), self._vec(b), self._vec(n),
                               1.0 / float(np.dot(a, a)), 1.0 / float(np.dot(b, b)),
                               float(area)))
        total = weights[0]
        for w in weights[1:]:
            total = total + w
        none = total <= 0
        all_area = float(np.sum(guide.areas_m2))
        self.prob = [dr.select(none, r[6] / all_area, w / dr.select(none, 1.0, total))
                     for r, w in zip(self.rects, weights, strict=True)]

    def _vec(self, v: Any) -> Any:
        f = self.dr.opaque
        return self.m.Vector3f(*(f(self.m.Float, float(x)) for x in v))

    def sample(self, u_rect: Any, u_s: Any, u_t: Any) -> Any:
        """A world direction from o to a point uniform on a rectangle picked by `prob`."""
        dr = self.dr
        corner, e1, e2 = self.rects[-1][:3]
        cum = self.m.Float(0.0)
        picked = self.m.Bool(False)
        for k in range(len(self.rects) - 1):
            cum = cum + self.prob[k]
            pick = ~picked & (u_rect < cum)
            c, a, b = self.rects[k][:3]
            corner, e1, e2 = (dr.select(pick, c, corner), dr.select(pick, a, e1),
                              dr.select(pick, b, e2))
            picked = picked | pick
        return dr.normalize(corner + u_s * e1 + u_t * e2 - self.o)

    def mixture_pdf(self, bsdf_pdf: Any, w: Any) -> Any:
        """The pdf of the world direction w under the vertex's choice: the BSDF's sampling
        (density `bsdf_pdf`) with probability 1 − `GUIDE_SHARE`, the guide otherwise."""
        return (1.0 - GUIDE_SHARE) * bsdf_pdf + GUIDE_SHARE * self.pdf(w)

    def pdf(self, w: Any) -> Any:
        """Solid-angle pdf at o of the world direction w."""
        dr, m, o = self.dr, self.m, self.o
        pdf = m.Float(0.0)
        for (corner, e1, e2, n, inv1, inv2, area), prob in zip(self.rects, self.prob,
                                                                 strict=True):
            cos_n = dr.dot(w, n)
            t = dr.dot(corner - o, n) / dr.select(cos_n != 0, cos_n, 1.0)
            rel = o + t * w - corner
            s, r = dr.dot(rel, e1) * inv1, dr.dot(rel, e2) * inv2
            hit = (cos_n != 0) & (t > 0) & (s >= 0) & (s <= 1) & (r >= 0) & (r <= 1)
            pdf += dr.select(hit, prob * t * t / (dr.abs(cos_n) * area), 0.0)
        return pdf
