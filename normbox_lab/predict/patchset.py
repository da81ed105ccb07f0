"""All patches per path: one set of traced paths estimates the radiometer spectrum of every
patch at one sample angle.

At one angle the 24 configurations of a sweep differ only in the patch's material; the geometry
is the same.  `PatchSetTracer` traces each radiometer path once, with a sampling density that
does not depend on the patch, and evaluates the throughput of all P patch materials × all bands
along it.  Every estimate stays unbiased; the estimates of different patches share paths and
are therefore correlated (their standard errors are each correct, but a difference of two
patches' estimates is more precise than the two SEs suggest).

How (δ + step = k + frac is the path's wavelength offset, `BandPathTracer._wavelength_offset`):

- **First vertex on the patch** (the radiometer looks at it: nearly every path).  The patch's
  BRDF is linear in its spectra:  f_p,b = kd_p,b/π + ks_p,b·S_p + kb_p,b·K_p − c_p, where the
  geometric factors S_p (GGX D·G·F/(4 cos cos) with the patch's α, η) and K_p (backscatter) are
  per-path scalars.  The kernel keeps the patch factor out of the path and returns, for the
  light sample (NEE) and the BSDF sample at that vertex: the weight w (emitter · MIS · cos / pdf,
  resp. cos / pdf) and the P scalars w·S_p, w·K_p.  Directions there come from the *defensive
  mixture*: the average over the P patches of each patch's own sampling density (cosine + GGX
  with its α), so the pdf — and the MIS weights — do not depend on the patch.  The rest of the
  path runs `BandPathTracer._path_loop` with throughput 1.
- **Later hits of the patch** (light that returns to it after a wall bounce: rare) pick one
  patch p* uniformly with weight P (`_path_loop`'s `patches`); what the path finds afterwards
  counts for p* only.
- **On the host** the per-patch, per-band estimate is assembled with matrix products: for each
  band b and patch p, Σ over paths of kd_p(λ_b + δ)·A·W_b + ks_p(λ_b + δ)·S_p·W_b + …, where
  W_b is the lamp spectrum (NEE) or the continuation's radiance, both per band.  The spectra
  are linear in frac inside a 1 nm table cell, so each term splits into a value part and a
  slope part (× frac).
- **Wavelength strata.**  So that the 1 nm table cell k is the same for a block of paths, the
  lanes of every sub-batch of `SUB_BATCH` paths are split into the 2·step cells of the
  triangular offset in proportion to their probabilities (stratified sampling: unbiased, and
  never noisier), frac drawn from the triangle's density inside the cell.
- **Standard error** from the sub-batches (each an independent stratified estimate of the
  same mean): SE = sd(sub-batch means) / √(number of sub-batches), per patch and band.

Patches with a λ-dependent Fresnel η (the dispersive truth materials) do not separate; for
them `FastNormbox` renders each configuration on its own (`BandPathTracer.render`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from normbox_lab.predict.bandpath import (
    BandEstimate,
    BandPathTracer,
    fresnel,
    ggx_d,
    max_rel_se,
    smith_g1,
)
from normbox_lab.predict.guide import GUIDE_SHARE, GuideKernel
from normbox_lab.predict.kernel_safety import cell_index, jit_table, require_finite
from normbox_lab.predict.streams import FIRST_BOUNCE_DRAWS, chunk_seed, lane_rng

#: paths per sub-batch: one stratified estimate; its spread gives the standard error
SUB_BATCH = 256
#: random numbers of the first vertex taken from a randomised quasi-Monte-Carlo net (the
#: radiometer ray 2, the light sample 2, the mixture's patch 1, the direction 3), then those of
#: the continuation's first bounce (`streams.FIRST_BOUNCE_DRAWS`)
FIRST_VERTEX_DRAWS = 8
QMC_DIMS = FIRST_VERTEX_DRAWS + FIRST_BOUNCE_DRAWS
#: the fewest sub-batches of a render (so that their spread is an error estimate at all)
MIN_SUB_BATCHES = 4
_NONE = 0xFFFFFFFF
#: sub-batch groups per chunk for the standard error: a chunk of more sub-batches sums them in
#: groups (one matrix product per group and wavelength cell), at least this many groups
SE_GROUPS_PER_CHUNK = 64


def _group_size(sub_batches: int) -> int:
    """Sub-batches per group: the largest power of two that divides `sub_batches` and leaves at
    least `SE_GROUPS_PER_CHUNK` groups (1 for a small chunk)."""
    g = 1
    while sub_batches % (2 * g) == 0 and sub_batches // (2 * g) >= SE_GROUPS_PER_CHUNK:
        g *= 2
    return g


@dataclass(frozen=True)
class WavelengthStrata:
    """The 2·step 1 nm cells of the triangular offset δ + step ∈ (0, 2·step), and how many
    lanes of a sub-batch each gets."""

    step_nm: int
    probability: np.ndarray        # (K,) P(δ + step ∈ [k, k + 1))
    counts: np.ndarray             # (K,) lanes per sub-batch
    bounds: np.ndarray             # (K + 1,) lane offsets of the cells in a sub-batch

    @classmethod
    def build(cls, step_nm: int, sub_batch: int = SUB_BATCH) -> WavelengthStrata:
        s = int(step_nm)
        k = np.arange(2 * s)
        mirror = np.where(k < s, k, 2 * s - 1 - k)
        prob = (2.0 * mirror + 1.0) / (2.0 * s * s)
        raw = prob * sub_batch
        counts = np.maximum(np.floor(raw).astype(np.int64), 1)
        order = np.argsort(-(raw - np.floor(raw)))
        for i in order[:max(0, sub_batch - int(counts.sum()))]:
            counts[i] += 1
        if int(counts.sum()) != sub_batch:
            raise ValueError(f"sub-batch of {sub_batch} lanes is too small for {2 * s} strata")
        return cls(s, prob, counts, np.concatenate([[0], np.cumsum(counts)]))

    @property
    def cell_of_lane(self) -> np.ndarray:
        """The cell k of each lane of a sub-batch."""
        return np.repeat(np.arange(self.counts.size), self.counts).astype(np.uint32)

    @property
    def weight(self) -> np.ndarray:
        """Per-lane weight of each cell: P(k) / lanes in k (a sub-batch's estimate is
        Σ_k weight_k · Σ_lanes in k)."""
        return self.probability / self.counts


@functools.lru_cache(maxsize=4)
def sobol_net(points: int, dims: int) -> np.ndarray:
    """(points, dims) uint32: an Owen-scrambled Sobol' net (fixed seed: the same net in every
    process); each sub-batch XORs it with its own random digital shift."""
    from scipy.stats import qmc

    m = round(float(np.log2(points)))
    if 1 << m != points:
        raise ValueError(f"a Sobol' net needs a power of two points, not {points}")
    u = qmc.Sobol(d=dims, scramble=True, seed=0x5EED).random_base2(m)
    return np.minimum(np.floor(u * 4294967296.0), 4294967295.0).astype(np.uint32)


class _Draws:
    """`next_float32()` from prepared arrays, in order (the kernel's QMC dimensions)."""

    def __init__(self, values: Sequence[Any]) -> None:
        self.values = list(values)

    def next_float32(self) -> Any:
        return self.values.pop(0)


class PatchSetTracer(BandPathTracer):
    """`BandPathTracer` (radiometer view) with `render_patches`: every patch per path."""

    patch_slot_name = "patch"
    #: the first vertex's and first bounce's random numbers from a randomised Sobol' net
    qmc = True

    # ---- per-patch tables --------------------------------------------------------------
    def separable(self, patch: Any) -> bool:
        """Whether `patch` can be rendered here (no λ-dependent Fresnel η)."""
        return self.material_tables(patch)["deta"] == 0.0

    def _patch_tables(self, patches: Sequence[Any]) -> SimpleNamespace:
        mats = [self.material_tables(p) for p in patches]
        if any(t["deta"] != 0.0 for t in mats):
            raise ValueError("a patch with a λ-dependent Fresnel η does not separate; render "
                             "it on its own (BandPathTracer.render)")

        def stack(key: str) -> np.ndarray:
            return np.stack([t[key] for t in mats])

        def slope(t: np.ndarray) -> np.ndarray:
            return np.diff(t, axis=-1, append=t[..., -1:])

        kd, ks, kb = stack("kd"), stack("ks"), stack("kb")
        return SimpleNamespace(
            count=len(mats), kd=kd, kd_slope=slope(kd), ks=ks, ks_slope=slope(ks), kb=kb,
            kb_slope=slope(kb), has_kb=bool(np.any(kb)),
            c=np.array([t["c"] for t in mats]), alpha=[t["alpha"] for t in mats],
            eta=[t["eta"] for t in mats], p_spec=[t["p_spec"] for t in mats],
            inv_sigma2=[t["inv_sigma2"] for t in mats])

    # ---- the kernels of one chunk ------------------------------------------------------
    def _trace_patches(self, tab: Mapping[str, Any], pt: SimpleNamespace, n: int, seed: int,
                       strata: WavelengthStrata) -> dict[str, np.ndarray]:
        """n paths (a multiple of the sub-batch): the per-lane pieces of the estimate."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        step = float(self.grid.step_nm)
        n_p = pt.count
        c = self._consts()

        def f(v: float) -> Any:
            return dr.opaque(m.Float, float(v))

        idx = dr.arange(m.UInt32, n)
        rng = lane_rng(m, dr, seed, idx)
        # the wavelength cell of the lane, and frac from the triangle's density inside it
        sub = int(strata.counts.sum())
        k = dr.gather(m.UInt32, jit_table(m.UInt32, strata.cell_of_lane, np.uint32),
                      idx % dr.opaque(m.UInt32, sub))
        kf = m.Float(k)
        upper = kf >= step
        a = dr.select(upper, (2.0 * step - 1.0) - kf, kf)
        x = dr.sqrt(a * a + rng.next_float32() * (2.0 * a + 1.0)) - a
        frac = dr.clip(dr.select(upper, 1.0 - x, x), 0.0, 1.0)
        delta = kf + frac - step
        # the first vertex's random numbers: a scrambled Sobol' net per sub-batch, digitally
        # shifted by the sub-batch's own random vector (randomised QMC: every lane uniform,
        # sub-batches independent, so their spread is still the standard error)
        if self.qmc:
            net = jit_table(m.UInt32, sobol_net(sub, QMC_DIMS), np.uint32)
            shift = np.random.default_rng(int(seed)).integers(
                0, 1 << 32, size=(n // sub, QMC_DIMS), dtype=np.uint32)
            shifts = jit_table(m.UInt32, shift, np.uint32)
            lane = (idx % dr.opaque(m.UInt32, sub)) * QMC_DIMS
            block = (idx // dr.opaque(m.UInt32, sub)) * QMC_DIMS
            draws = _Draws([m.Float((dr.gather(m.UInt32, net, lane + d)
                                     ^ dr.gather(m.UInt32, shifts, block + d)) >> 8)
                            * (1.0 / 16777216.0) for d in range(QMC_DIMS)])
        else:
            draws = _Draws([rng.next_float32() for _ in range(QMC_DIMS)])
        later = draws.values[FIRST_VERTEX_DRAWS:]
        draws.values = draws.values[:FIRST_VERTEX_DRAWS]
        ray = self._radiometer_ray(draws)
        hit = self._intersect(c, ray, m.Bool(True))
        first = hit.surf & (hit.slot == self.slot_names.index(self.patch_slot_name))
        frame, wi, o = self._frame(hit, ray)
        # light sample and the defensive mixture's BSDF sample at the patch vertex
        wl, em_w, pdf_l, ok = self._light_sample(c, frame, o, draws, first)
        # one uniform picks the technique: the guide with probability β, else the mixture
        # (and its patch, from the same uniform rescaled)
        beta = GUIDE_SHARE if self.guide is not None else 0.0
        u_pick = draws.next_float32()
        u_mix = dr.clip((u_pick - beta) / (1.0 - beta), 0.0, 1.0) if beta else u_pick
        q = cell_index(dr, m, u_mix * f(n_p), f(n_p))
        alphas = [f(v) for v in pt.alpha]
        p_specs = [f(v) for v in pt.p_spec]
        alpha_q = dr.gather(m.Float, jit_table(m.Float, pt.alpha + [pt.alpha[-1]]), q)
        pspec_q = dr.gather(m.Float, jit_table(m.Float, pt.p_spec + [pt.p_spec[-1]]), q)
        guide = GuideKernel(m, dr, self.guide, o, frame.n) if beta else None
        if guide is not None:
            u_face, u_s, u_t = draws.values[:3]        # the direction's three numbers
            wo_guide = frame.to_local(guide.sample(u_face, u_s, u_t))
        wo = self._sample_direction(wi, alpha_q, pspec_q, draws)
        if guide is not None:
            wo = dr.select(u_pick < beta, wo_guide, wo)
        if draws.values:
            raise AssertionError("QMC_DIMS does not match the first vertex's draws")

        def technique_pdf(w: Any, pdf_mixture: Any) -> Any:
            """The pdf of the direction w (local) under the guide-or-mixture choice."""
            if guide is None:
                return pdf_mixture
            return guide.mixture_pdf(pdf_mixture, frame.to_world(w))

        def per_patch(w: Any) -> tuple[Any, list[Any], list[Any], Any]:
            """(mixture pdf of w, GGX·F factor per patch, backscatter factor per patch,
            validity) at the patch vertex for the outgoing local direction w."""
            h = dr.normalize(wi + w)
            cb = dr.clip(dr.dot(wi, h), 0.0, 1.0)
            woh = dr.fmax(dr.abs(dr.dot(w, h)), 1e-12)
            valid = (wi.z > 0) & (w.z > 0)
            cosw = dr.select(valid, wi.z * w.z, 1.0)
            pdf = m.Float(0.0)
            geo, back = [], []
            for p in range(n_p):
                a2 = alphas[p] * alphas[p]
                d = ggx_d(a2, h.z)
                pdf += p_specs[p] * d * h.z / (4.0 * woh) + (1.0 - p_specs[p]) * w.z / np.pi
                g = d * smith_g1(a2, wi.z) * smith_g1(a2, w.z) / (4.0 * cosw)
                geo.append(dr.select(valid, g * fresnel(f(pt.eta[p]), cb), 0.0))
                if pt.has_kb:
                    back.append(dr.exp((dr.dot(wi, w) - 1.0) * f(pt.inv_sigma2[p])) / np.pi)
            return dr.select(valid, pdf / n_p, 0.0), geo, back, valid

        pdf_wl, geo_l, back_l, valid_l = per_patch(wl)
        pdf_wl = technique_pdf(wl, pdf_wl)
        mis = dr.square(pdf_l) / dr.fmax(dr.square(pdf_l) + dr.square(pdf_wl), 1e-30)
        w_nee = dr.select(first & ok & valid_l, em_w * mis * wl.z, 0.0)
        pdf_wo, geo_o, back_o, valid_o = per_patch(wo)
        pdf_wo = dr.select(valid_o, technique_pdf(wo, pdf_wo), 0.0)
        go_on = first & valid_o & (pdf_wo > 0)
        w_bsdf = dr.select(go_on, wo.z / dr.fmax(pdf_wo, 1e-30), 0.0)
        rows_nee = [w_nee / np.pi] + [w_nee * g for g in geo_l] + [w_nee * b for b in back_l]
        rows_bsdf = [w_bsdf / np.pi] + [w_bsdf * g for g in geo_o] + [w_bsdf * b for b in back_o]
        # the continuation: from the patch vertex (vertex 1 next), or the camera ray itself
        # when the radiometer's ray met something else first
        d_start = dr.select(first, frame.to_world(wo), ray.d)
        start = m.Ray3f(dr.select(first, o, ray.o), d_start)
        depth = dr.select(first, m.UInt32(1), m.UInt32(0))
        active = dr.select(first, go_on & (1 < c.max_depth), m.Bool(True))
        prev_pdf = dr.select(first, pdf_wo, 0.0)
        dr.eval(rows_nee, rows_bsdf, first, frac, delta, k, start.o, start.d, depth, active,
                prev_pdf, rng)
        lookup = self._lookup(tab, k, frac)
        patches = SimpleNamespace(
            slot=dr.opaque(m.UInt32, self.slot_names.index(self.patch_slot_name)),
            base=dr.opaque(m.UInt32, len(self.slot_names)), count_f=f(n_p))
        res = self._path_loop(tab, c, lookup, delta, start, active, depth, prev_pdf, rng,
                              patches=patches, first_draws=later)
        post, late = self._band_rows(n, [res.acc, res.late], (tab, lookup))
        dr.eval(post, late, res.pstar)           # one kernel: the whole path loop
        # light that came back to the patch (rare): only those lanes leave the device
        lanes = np.asarray(dr.compress(res.pstar != dr.opaque(m.UInt32, _NONE)),
                           dtype=np.int64)
        late_idx = (np.arange(n_b, dtype=np.int64)[:, None] * n + lanes[None, :]).ravel()
        late = dr.gather(m.Float, late, jit_table(m.UInt32, late_idx, np.uint32)
                         if late_idx.size else m.UInt32())
        dr.eval(late)

        def np32(values: Sequence[Any] | Any, lanes: int | None = None) -> np.ndarray:
            """(lanes, rows) float32 as a transposed view of a row-major stack: `values` a
            list of rows, or one flat array of `lanes`-long band rows (`_band_rows`); a NaN or
            infinite value in any lane is a `RenderError`."""
            if lanes is None:
                a = np.stack([np.asarray(v, dtype=np.float32) for v in values]).T
            else:
                a = np.asarray(values, dtype=np.float32).reshape(n_b, lanes).T
            require_finite(a, f"all patches per path ({self.variant}), seed {seed}")
            return a

        return {"post": np32(post, n), "late": np32(late, lanes.size),
                "late_lanes": lanes,
                "rows_nee": np32(rows_nee), "rows_bsdf": np32(rows_bsdf),
                "first": np.asarray(first, dtype=bool), "frac": np.asarray(frac, np.float32),
                "pstar": np.asarray(res.pstar, dtype=np.uint32)[lanes]}

    def _group_sums(self, out: Mapping[str, np.ndarray], pt: SimpleNamespace,
                    strata: WavelengthStrata, group: int) -> np.ndarray:
        """(G, P, B): per group of `group` consecutive sub-batches, the sum of their estimates
        of every patch's band radiance (G = sub-batches / group).

        Per wavelength cell k and group: the light sample's factor is the lamp spectrum,
        linear in frac inside the cell like the patch tables, so its part needs only the
        sums Σ x, Σ x·frac, Σ x·frac² of each row x; the BSDF sample's part meets the
        continuation's radiance per band (one matrix product over the group's lanes)."""
        n_p, n_b, step = pt.count, self.grid.n_bands, self.grid.step_nm
        sub = int(strata.counts.sum())
        n = out["frac"].size
        n_g = n // (sub * group)
        est = np.zeros((n_g, n_p, n_b))
        n_rows = out["rows_nee"].shape[1]

        def lanes(a: np.ndarray, lo: int, hi: int) -> np.ndarray:
            """(G, lanes of cell [lo, hi) in the group, columns) of a per-lane array."""
            a = a.reshape(n_g, group, sub, -1)[:, :, lo:hi]
            return a.reshape(n_g, group * (hi - lo), a.shape[-1])

        frac = out["frac"][:, None]
        non_first = (~out["first"]).astype(np.float32)[:, None]
        spectra = [(pt.kd - np.pi * pt.c[:, None], pt.kd_slope, 0),
                   (pt.ks, pt.ks_slope, 1)]
        if pt.has_kb:
            spectra.append((pt.kb, pt.kb_slope, 1 + n_p))
        for kk in range(strata.counts.size):
            lo, hi = int(strata.bounds[kk]), int(strata.bounds[kk + 1])
            cols = kk + step * np.arange(n_b)
            fk = lanes(frac, lo, hi)
            w = strata.weight[kk]
            lv, ls = pt.le[cols], pt.le_slope[cols]
            # light sample: Σ x·frac^i, i = 0, 1, 2 → (G, R, 3)
            powers = np.concatenate([np.ones_like(fk), fk, fk * fk], axis=2)
            a = np.matmul(lanes(out["rows_nee"], lo, hi).transpose(0, 2, 1),
                          powers).astype(np.float64) * w
            # BSDF sample: Σ x·W_b and Σ x·frac·W_b → (G, 2R, B)
            x = lanes(out["rows_bsdf"], lo, hi)
            mm = np.matmul(np.concatenate([x, x * fk], axis=2).transpose(0, 2, 1),
                           lanes(out["post"], lo, hi)).astype(np.float64) * w
            for table, table_slope, r0 in spectra:
                tv, ts = table[:, cols], table_slope[:, cols]            # (P, B)
                r = slice(0, 1) if r0 == 0 else slice(r0, r0 + n_p)   # kd: one row (A)
                rs = slice(n_rows + r.start, n_rows + r.stop)
                est += (a[:, r, 0:1] * (tv * lv) + a[:, r, 1:2] * (tv * ls + ts * lv)
                        + a[:, r, 2:3] * (ts * ls))
                est += tv[None] * mm[:, r] + ts[None] * mm[:, rs]
            post = np.matmul(lanes(out["post"], lo, hi).transpose(0, 2, 1),
                             lanes(non_first, lo, hi))[..., 0]
            est += (post.astype(np.float64) * w)[:, None, :]
        # light that came back to the patch: for the picked patch p* only
        lanes_late = out["late_lanes"]
        if lanes_late.size:
            local = lanes_late % sub
            cell = strata.cell_of_lane[local].astype(np.int64)
            cols = cell[:, None] + step * np.arange(n_b)[None, :]
            p = out["pstar"].astype(np.int64)
            fr = out["frac"][lanes_late, None].astype(np.float64)
            late = out["late"].astype(np.float64)
            rows = out["rows_bsdf"][lanes_late].astype(np.float64)
            k = np.arange(lanes_late.size)
            factor = ((pt.kd[p[:, None], cols] + fr * pt.kd_slope[p[:, None], cols]
                       - np.pi * pt.c[p, None]) * rows[:, :1]
                      + (pt.ks[p[:, None], cols] + fr * pt.ks_slope[p[:, None], cols])
                      * rows[k, 1 + p][:, None])
            if pt.has_kb:
                factor += ((pt.kb[p[:, None], cols] + fr * pt.kb_slope[p[:, None], cols])
                           * rows[k, 1 + n_p + p][:, None])
            factor = np.where(out["first"][lanes_late, None], factor, 1.0)
            np.add.at(est, (lanes_late // (sub * group), p),
                      factor * late * strata.weight[cell][:, None])
        return est

    # ---- public ------------------------------------------------------------------------
    def render_patches(self, patches: Sequence[Any], materials: Mapping[str, Any],
                       emitter_wavelength_nm: Any, emitter_radiance: Any, *,
                       n_paths: int | None = None, target_rel_se: float | None = None,
                       seed: int = 0, max_paths: int = 1 << 23,
                       pilot_paths: int = 1 << 14) -> list[BandEstimate]:
        """The radiometer spectrum of each patch in `patches` (materials of the fit family,
        no λ-dependent η), the other slots from `materials`, from one set of paths.

        Either a fixed `n_paths` (rounded up to whole sub-batches, at least
        `MIN_SUB_BATCHES`), or `target_rel_se`: paths
        are added until every patch's largest relative SE over the bands is at or below it (or
        `max_paths`).  Deterministic for a given seed.  `BandEstimate.time_s` is the shared
        wall time divided by the number of patches."""
        if n_paths is None and target_rel_se is None:
            raise ValueError("give n_paths or target_rel_se")
        if not patches:
            raise ValueError("no patches")
        t0 = time.perf_counter()
        pt = self._patch_tables(patches)
        pt.le = self.grid.table(emitter_wavelength_nm, emitter_radiance)
        pt.le_slope = np.diff(pt.le, append=pt.le[-1:])
        slots = {**materials, self.patch_slot_name: patches[0]}
        tab = self._tables(slots, emitter_wavelength_nm, emitter_radiance, extra_slots=patches)
        strata = WavelengthStrata.build(self.grid.step_nm)
        sub = int(strata.counts.sum())
        chunk = max(sub, self.chunk_paths // sub * sub)
        n_p, n_b = pt.count, self.grid.n_bands
        s1 = np.zeros((n_p, n_b))
        s2 = np.zeros((n_p, n_b))
        n_j = 0
        n_g = 0
        chunk_no = 0

        def whole(v: int) -> int:
            return max(MIN_SUB_BATCHES * sub, -(-int(v) // sub) * sub)

        goal = whole(n_paths if n_paths is not None else min(pilot_paths, max_paths))
        while True:
            while n_j * sub < goal:
                n = min(chunk, goal - n_j * sub)
                out = self._trace_patches(tab, pt, n, chunk_seed(seed, chunk_no), strata)
                chunk_no += 1
                # one BLAS thread: the sums' order, and so every bit, the same in any process
                # (dask workers run with one BLAS thread, a plain process with several)
                group = _group_size(n // sub)
                with threadpool_limits(1, user_api="blas"):
                    est = require_finite(self._group_sums(out, pt, strata, group),
                                         f"all patches per path ({self.variant}), seed {seed}")
                s1 += est.sum(axis=0)
                s2 += np.einsum("gpb,gpb->pb", est, est) / group
                n_j += est.shape[0] * group
                n_g += est.shape[0]
            mean = s1 / n_j
            # groups of k sub-batches: their means y have variance σ²/k, and
            # Σ k·(y − mean)² = s2 − n_j·mean² has expectation (groups − 1)·σ²
            var = np.maximum(s2 - n_j * mean * mean, 0.0) / max(n_g - 1, 1)
            se = np.sqrt(var / n_j)
            if target_rel_se is None:
                break
            rel = max(max_rel_se(mean[p], se[p]) for p in range(n_p))
            if rel <= target_rel_se or n_j * sub >= max_paths:
                break
            need = int(np.ceil(n_j * sub * (rel / target_rel_se) ** 2 * 1.05))
            goal = whole(min(int(max_paths), max(need, n_j * sub + sub)))
        dt = (time.perf_counter() - t0) / n_p
        return [BandEstimate(self.grid.centres_nm, mean[p], se[p], n_j * sub, dt)
                for p in range(n_p)]
