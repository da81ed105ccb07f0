"""The camera tracer: full spectral images (all 81 bands per path) with light-path layers,
depth, normals and the Wilkie & Weidlich (2009) auxiliary images CWNI and NWCI.

It is `normbox_lab.predict.bandpath.BandPathTracer`'s machinery and its one path loop (Mitsuba mono variant for ray casting,
band tables, λ-independent sampling, NEE + MIS, GGX/cosine mixture, Russian roulette) with a
pinhole camera in place of the 1° radiometer.  Every path carries all bands, so every layer and
both auxiliary images are exact per-path estimators from the same paths.

Image formation is `normbox_lab.images.camera.PinholeCamera`'s (a pixel is a box filter: the mean
radiance over the pixel).  With a square image and `fov_deg` equal to the radiometer's view, the
mean of all pixels estimates exactly what `FastNormbox.render_view` does.

Path structure per sample: the camera ray's first hit x1 is traced in one kernel (its emission,
NEE and BSDF sample, with the BSDF factors split by lobe), then the continuation ray from x1 runs
the usual path loop with throughput 1 in a second kernel, and a third kernel combines them, so
the first-hit factors never sit in registers across the loop.  With L_b the lamp spectrum at the
path's wavelengths, for band b:

    n_b = nd_b + ns_b    NEE at x1: f·cos·(MIS weight)/pdf of the light sample, by lobe
    g_b = gd_b + gs_b    BSDF sample at x1: f·cos/pdf, by lobe
    e0                   x1 is the emitter (camera sees the light), e1: the continuation's first
                         hit is the emitter (MIS weight vs NEE), acc_b: all later vertices

    emission  = e0·L_b                      the directly seen luminaire
    diffuse   = (nd_b + gd_b·e1)·L_b        direct light through x1's diffuse part
    specular  = (ns_b + gs_b·e1)·L_b        direct light through x1's angular lobes
    indirect  = g_b·acc_b·L_b               light that reached x1 after ≥ 1 other bounce
    radiance  = emission + diffuse + specular + indirect   (by construction, per path)

Lobes: "diffuse" is the angle-independent part of the BRDF, kd_b/π − c (the fit model's constant
−c goes with it); "specular" is the rest: the GGX microfacet lobe ks_b·F·D·G/(4 cos cos) and the
truth materials' backscatter lobe kb_b·B(ωi·ωo).  Direct light found by BSDF sampling (the
continuation ray hitting the emitter) is direct light: it goes to diffuse/specular, not indirect.

Wilkie & Weidlich 2009 §3.1, at the first hit only (x1), with avg = the mean over the bands
(equal-energy "neutral" spectrum of the same band mean, i.e. the same brightness in W/nm):

    incoming light at x1:  NEE: L_b (per unit n_b), continuation: inc_b = (e1 + acc_b)·L_b
    CWNI_b = avg(L)·n_b + g_b·avg(inc)        incident light neutralised, BRDF sample kept
    NWCI_b = avg(n)·L_b + avg(g)·inc_b        BRDF sample neutralised (same albedo), light kept

Directly viewed luminaires are omitted (zero) in both, as in the paper's Fig. 4.  Under a neutral
light on neutral materials both equal radiance − emission (up to float rounding).

`depth_m`, `normal`, `slot_id` come from one ray through each pixel centre (not jittered, so a
known plane gives exact values): the distance along that ray to the first hit (+inf where it
misses), the world-space face normal turned towards the camera ((0, 0, 0) where it misses), and
the material slot hit (index into `slot_names`, −1 for a miss).

Public API: CameraTracer(scene, bsdf_slots, emitter, camera, ...).render(...) -> SpectralImage
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from normbox_lab.images.camera import AUX_IMAGES, LAYERS, PinholeCamera, SpectralImage
from normbox_lab.predict.bandpath import (
    BandGrid,
    BandPathTracer,
    RectEmitter,
)
from normbox_lab.predict.kernel_safety import jit_table, require_finite
from normbox_lab.predict.mitsuba_setup import jit_variant
from normbox_lab.predict.streams import FIRST_BOUNCE_DRAWS, lane_rng

#: a path's random numbers taken from each pixel's quasi-random point set: the wavelength
#: offset 2, the jitter in the pixel 2, the light sample 2 and the direction 3 at the first hit,
#: then the continuation's first bounce (`streams.FIRST_BOUNCE_DRAWS`, the first unused)
FIRST_HIT_DRAWS = 9
QMC_DIMS = FIRST_HIT_DRAWS + FIRST_BOUNCE_DRAWS


class _Draws:
    """`next_float32()` from prepared arrays, in order."""

    def __init__(self, values: Sequence[Any]) -> None:
        self.values = list(values)

    def next_float32(self) -> Any:
        return self.values.pop(0)


class CameraTracer(BandPathTracer):
    """`BandPathTracer` with a pinhole camera: spectral image, layers, CWNI/NWCI, depth, normal.

    `scene`, `bsdf_slots`, `emitter` (a down-facing `RectEmitter`), `variant`, `emitter_slot` as
    for `BandPathTracer` (any mono Mitsuba scene of meshes).  The camera, the image size, spp and
    the seed are run-time data (opaque to the JIT), as are the emitter's placement and the path
    depths, so one set of compiled kernels serves every camera and every scene with the same
    material features (backscatter lobe, dispersion).  Deterministic for a given seed: each
    path's random stream depends only on (seed, pixel, sample), not on the chunking.

    Every material goes through the general kernels (backscatter lobe and λ-dependent η on,
    zero where a material has none: `general_materials`): the truth and the fitted materials
    of one figure share one set of compiled kernels instead of two (each 10-25 s to compile on
    a 2-core AVX2 CPU), for about a fifth more work per vertex with fit-model materials.
    """

    general_materials = True

    def __init__(self, scene: Any, bsdf_slots: Sequence[tuple[Any, str]], emitter: RectEmitter,
                 camera: PinholeCamera, *, variant: str | None = None,
                 emitter_slot: str = "panel", grid: BandGrid | None = None,
                 max_depth: int = 12, rr_depth: int = 6, chunk_paths: int = 1 << 16) -> None:
        if int(max_depth) < 2:
            raise ValueError("the camera needs max_depth ≥ 2 (a first hit and its light)")
        if int(rr_depth) < 1:
            raise ValueError("rr_depth must be ≥ 1 (no roulette at the first hit)")
        super().__init__(scene, bsdf_slots, None, emitter, variant=jit_variant("mono", variant),
                         emitter_slot=emitter_slot, grid=grid, max_depth=max_depth,
                         rr_depth=rr_depth, chunk_paths=chunk_paths)
        self.camera = camera
        self._ybar: np.ndarray | None = None
        #: a pixel's samples from a scrambled Sobol' net (randomised QMC, below)
        self.qmc = True

    # ---- run-time constants (opaque: changing them never recompiles) ----------------------
    def _camera_consts(self, camera: PinholeCamera, spp: int) -> SimpleNamespace:
        """`BandPathTracer._consts` plus the camera's, all opaque JIT values."""
        dr, m = self.dr, self.m

        def f(v: float) -> Any:
            return dr.opaque(m.Float, float(v))

        def vec(v: Any) -> Any:
            return m.Vector3f(*(f(x) for x in v))

        fwd, right, up = camera.frame()
        tx, ty = camera.tan_half_fov
        c = self._consts()
        c.__dict__.update(
            origin=m.Point3f(*(f(x) for x in camera.origin_m)), fwd=vec(fwd), right=vec(right),
            up=vec(up), tan_x=f(tx), tan_y=f(ty), inv_w=f(1.0 / int(camera.width_px)),
            inv_h=f(1.0 / int(camera.height_px)), width=dr.opaque(m.UInt32, int(camera.width_px)),
            spp=dr.opaque(m.UInt32, int(spp)))
        return c

    def _camera_ray(self, c: SimpleNamespace, col: Any, row: Any, jx: Any, jy: Any) -> Any:
        dr, m = self.dr, self.m
        x = (2.0 * (m.Float(col) + jx) * c.inv_w - 1.0) * c.tan_x
        y = (1.0 - 2.0 * (m.Float(row) + jy) * c.inv_h) * c.tan_y
        return m.Ray3f(c.origin, dr.normalize(c.fwd + c.right * x + c.up * y))

    # ---- the three kernels of a chunk -------------------------------------------------------
    def _first_hit(self, tab: Mapping[str, Any], c: SimpleNamespace, n: int, pix0: int,
                   spp: int, seed_state: int) -> SimpleNamespace:
        """The camera rays of pixels pix0… (spp each) to their first hit: emission, the NEE
        and BSDF sample's λ-independent BRDF terms there (`_brdf_terms`; the bands are the
        third kernel's), and the continuation ray.  Everything evaluated (one kernel)."""
        dr, m = self.dr, self.m
        idx = dr.arange(m.UInt32, n)
        gidx = m.UInt64(idx) + dr.opaque(m.UInt64, int(pix0) * int(spp))
        # seeded by the global path index (so a chunk's paths do not depend on the chunking)
        rng = lane_rng(m, dr, seed_state, gidx)
        pix = dr.opaque(m.UInt32, int(pix0)) + idx // c.spp
        if self.qmc:
            # the spp samples of a pixel are the first spp points of an Owen-scrambled Sobol'
            # net, XORed with the pixel's own random digital shift (randomised QMC: every
            # sample uniform, pixels independent; the per-sample variance then bounds the
            # pixel's error from above)
            from normbox_lab.predict.patchset import sobol_net

            points = 1 << max(int(spp) - 1, 0).bit_length()
            net = jit_table(m.UInt32, sobol_net(points, QMC_DIMS), np.uint32)
            shifter = lane_rng(m, dr, int(seed_state) ^ 0x51A7E5D, pix)
            base = (idx - (idx // c.spp) * c.spp) * QMC_DIMS
            draws = _Draws([m.Float((dr.gather(m.UInt32, net, base + d)
                                     ^ shifter.next_uint32()) >> 8) * (1.0 / 16777216.0)
                            for d in range(QMC_DIMS)])
        else:
            draws = _Draws([rng.next_float32() for _ in range(QMC_DIMS)])
        later = draws.values[FIRST_HIT_DRAWS:]
        draws.values = draws.values[:FIRST_HIT_DRAWS]
        delta, k, frac = self._wavelength_offset(draws)
        row = pix // c.width
        col = pix - row * c.width
        jx = draws.next_float32()
        jy = draws.next_float32()
        ray = self._camera_ray(c, col, row, jx, jy)
        lookup = self._lookup(tab, k, frac)
        hit = self._intersect(c, ray, m.Bool(True))
        e0 = self._emission(c, hit, ray, m.Float(0.0))
        active = hit.surf
        frame, wi, o = self._frame(hit, ray)
        vx = self._vertex(tab, lookup, delta, hit.slot, wi, active, spectra=False)
        wl, wt, ok = self._nee(c, vx, frame, o, draws, active)
        nee = self._brdf_terms(vx, wl, wt, ok)
        wo, bpdf, act = self._sample(vx, draws, active)
        if draws.values:
            raise AssertionError("FIRST_HIT_DRAWS does not match the first hit's draws")
        smp = self._brdf_terms(vx, wo, wo.z / dr.fmax(bpdf, 1e-30), act)
        out = SimpleNamespace(e0=e0, delta=delta, k=k, frac=frac, slot=hit.slot, surf=active,
                              nee=nee, smp=smp, ray=m.Ray3f(o, frame.to_world(wo)), pdf=bpdf,
                              active=act & (1 < c.max_depth), rng=rng,
                              probe=self._probe(tab, lookup, vx, smp, delta), later=later)
        dr.eval(out.e0, out.delta, out.k, out.frac, out.slot, out.surf, vars(nee), vars(smp),
                out.ray.o, out.ray.d, out.pdf, out.active, out.rng, out.probe, out.later)
        return out

    def _probe(self, tab: Mapping[str, Any], lookup: Any, vx: SimpleNamespace,
               smp: SimpleNamespace, delta: Any) -> Any:
        """The roulette probe of the full path after the first hit, as `BandPathTracer`'s:
        max |f_b| over bands 0, 8, 16, … of the BSDF sample's factor (a band loop)."""
        dr, m = self.dr, self.m

        def body(b: Any, probe: Any) -> tuple[Any, Any]:
            kd, ks, kb = self._band_spectra(tab, lookup, vx, b)
            g = self._band_factor(vx, smp, kd, ks, kb, self._band_lam(b, delta))
            return b + 8, dr.fmax(probe, dr.abs(g))

        n_bands = dr.opaque(m.UInt32, self.grid.n_bands)
        return dr.while_loop((m.UInt32(0), m.Float(0.0)), lambda b, _: b < n_bands, body,
                             label="probe")[1]

    def _continue(self, tab: Mapping[str, Any], c: SimpleNamespace,
                  fh: SimpleNamespace, n: int) -> tuple[Any, Any]:
        """`BandPathTracer._path_loop` from the continuation rays with throughput 1: (acc as
        n_bands rows of n lanes, e1), where e1 is the emitter seen at the first vertex (MIS vs
        NEE) and acc_b everything after it."""
        dr, m = self.dr, self.m
        res = self._path_loop(tab, c, self._lookup(tab, fh.k, fh.frac), fh.delta, fh.ray,
                              fh.active, m.UInt32(1), fh.pdf, fh.rng, probe_scale=fh.probe,
                              split_first=True, first_draws=fh.later)
        acc = self._band_rows(n, [res.acc])[0]
        dr.eval(acc, res.e1)
        return acc, res.e1

    def _combine(self, tab: Mapping[str, Any], fh: SimpleNamespace, acc: Any, e1: Any, n: int,
                 spp: int, layers: bool = True) -> np.ndarray:
        """Per-path layers, CWNI, NWCI, radiance² and luminance (and its square), summed over
        each pixel's spp paths: (8·B + 2, n_pixels) float32 (the radiance summed as its own
        per-path value, so a render with and without layers gives the same radiance bits);
        without `layers`, radiance, radiance² and the luminance terms only: (2·B + 2, n_pixels).
        One kernel of band loops (the band mean of the incoming light, then the images) writing
        rows of one flat array."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        n_img = 8 if layers else 2
        lane = dr.arange(m.UInt32, int(n))
        n_lanes = dr.opaque(m.UInt32, int(n))
        n_bands = dr.opaque(m.UInt32, n_b)
        lookup = self._lookup(tab, fh.k, fh.frac)
        vx = self._vertex(tab, lookup, fh.delta, fh.slot, None, fh.surf, spectra=False)
        ybar = jit_table(m.Float, self._luminance_weights())

        def band(b: Any) -> SimpleNamespace:
            """Band b of one path: the lamp, the continuation and the first hit's factors."""
            kd, ks, kb = self._band_spectra(tab, lookup, vx, b)
            lam = self._band_lam(b, fh.delta)
            nd, gd = self._diffuse_factor(fh.nee, kd), self._diffuse_factor(fh.smp, kd)
            ns = self._angular_factor(vx, fh.nee, ks, kb, lam)
            gs = self._angular_factor(vx, fh.smp, ks, kb, lam)
            le = lookup.band(tab["le"], m.UInt32(0), m.Bool(True), 2, b)[0]
            acc_b = dr.gather(m.Float, acc, b * n_lanes + lane)
            return SimpleNamespace(le=le, acc=acc_b, nd=nd, ns=ns, gd=gd, gs=gs, nee=nd + ns,
                                   g=gd + gs, inc=(e1 + acc_b) * le)

        names = ("le", "acc", "nd", "ns", "gd", "gs")
        avg = None
        if layers:
            # pass 1: the band means of the incoming light, the NEE and the BSDF sample; each
            # band's values wait in per-lane local arrays for pass 2
            kept = [dr.alloc_local(m.Float, n_b) for _ in names]

            def sums(b: Any, s_le: Any, s_inc: Any, s_nee: Any, s_g: Any,
                     *kept: Any) -> tuple[Any, ...]:
                x = band(b)
                for name, local in zip(names, kept, strict=True):
                    local.write(getattr(x, name), b)
                return (b + 1, s_le + x.le, s_inc + x.inc, s_nee + x.nee, s_g + x.g, *kept)

            zero = m.Float(0.0)
            totals = dr.while_loop((m.UInt32(0), zero, zero, zero, zero, *kept),
                                   lambda b, *_: b < n_bands, sums, label="band means")
            avg = [t * (1.0 / n_b) for t in totals[1:5]]
            kept = totals[5:]
        out = dr.empty(m.Float, (n_img * n_b + 2) * int(n))

        def images(b: Any, y: Any, *kept: Any) -> tuple[Any, ...]:
            if layers:
                x = SimpleNamespace(**{k: v.read(b) for k, v in zip(names, kept, strict=True)})
                x.nee, x.g, x.inc = x.nd + x.ns, x.gd + x.gs, (e1 + x.acc) * x.le
            else:
                x = band(b)
            # the radiance in one form for both modes (identical materials, identical bits)
            rad = (x.nee + dr.fma(x.g, e1 + x.acc, fh.e0)) * x.le
            rows = []
            if layers:
                avg_le, avg_inc, avg_nee, avg_g = avg
                rows = [fh.e0 * x.le, dr.fma(x.gd, e1, x.nd) * x.le,
                        dr.fma(x.gs, e1, x.ns) * x.le, x.g * x.acc * x.le,
                        dr.fma(avg_le, x.nee, x.g * avg_inc), dr.fma(avg_nee, x.le, avg_g * x.inc)]
            for r, value in enumerate(rows + [rad, rad * rad]):
                dr.scatter(out, value, (b + r * n_b) * n_lanes + lane)
            return (b + 1, dr.fma(dr.gather(m.Float, ybar, b), rad, y), *kept)

        y = dr.while_loop((m.UInt32(0), m.Float(0.0), *(kept if layers else ())),
                          lambda b, *_: b < n_bands, images, label="images")[1]
        dr.scatter(out, y, n_img * n_b * n_lanes + lane)
        dr.scatter(out, y * y, (n_img * n_b + 1) * n_lanes + lane)
        dr.eval(out)                  # one kernel
        sums = dr.block_sum(out, int(spp), mode="evaluated")
        return require_finite(np.asarray(sums, dtype=np.float32).reshape(n_img * n_b + 2, -1),
                              f"camera tracer ({self.variant})")

    def _luminance_weights(self) -> np.ndarray:
        """w_b with Y = Σ w_b·L_b in cd/m² (`images.color.spectral_to_XYZ` is linear)."""
        if self._ybar is None:
            from normbox_lab.images.color import spectral_to_XYZ

            n_b = self.grid.n_bands
            self._ybar = spectral_to_XYZ(self.grid.centres_nm, np.eye(n_b))[:, 1]
        return self._ybar

    def _geometry(self, c: SimpleNamespace, camera: PinholeCamera
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel-centre rays: depth (m, +inf on a miss), normal towards the camera, slot id."""
        dr, m = self.dr, self.m
        w, h = int(camera.width_px), int(camera.height_px)
        idx = dr.arange(m.UInt32, w * h)
        row = idx // c.width
        col = idx - row * c.width
        ray = self._camera_ray(c, col, row, m.Float(0.5), m.Float(0.5))
        hit = self._intersect(c, ray, m.Bool(True))
        n_cam = dr.select(dr.dot(ray.d, hit.ng) > 0, -hit.ng, hit.ng)
        depth = dr.select(hit.valid, hit.t, dr.inf)
        normal = [dr.select(hit.valid, n_cam[i], 0.0) for i in range(3)]
        slot = dr.select(hit.valid, m.Int32(hit.slot), -1)
        dr.eval(depth, normal, slot)
        depth_np = np.asarray(depth, dtype=np.float32).reshape(h, w)
        normal_np = np.stack([np.asarray(v, dtype=np.float32) for v in normal],
                             axis=-1).reshape(h, w, 3)
        return depth_np, normal_np, np.asarray(slot, dtype=np.int32).reshape(h, w)

    # ---- public ------------------------------------------------------------------------
    def render(self, materials: Mapping[str, Any], emitter_wavelength_nm: Any,
               emitter_radiance: Any, *, spp: int, seed: int = 0,
               camera: PinholeCamera | None = None, layers: bool = True) -> SpectralImage:
        """The spectral image of the scene with `materials` (slot name → `Material`) and the
        emitter's spectral radiance (W·sr⁻¹·m⁻²·nm⁻¹ on `emitter_wavelength_nm`), `spp` jittered
        paths per pixel.  `camera` overrides the tracer's camera for this render.  Without
        `layers` only the radiance (and its errors) is summed: the layers and CWNI/NWCI are
        None, and the per-pixel sums cost about a third."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be ≥ 1, got {spp}")
        cam = camera if camera is not None else self.camera
        t0 = time.perf_counter()
        tab = self._tables(materials, emitter_wavelength_nm, emitter_radiance)
        c = self._camera_consts(cam, spp)
        w, h = int(cam.width_px), int(cam.height_px)
        n_pix = w * h
        n_b = self.grid.n_bands
        # per-pixel sums over the spp paths (float32 as Dr.Jit reduced them), then the means
        # one (H, W, B) image at a time, to keep the peak memory low
        n_img = 8 if layers else 2        # B-wide images: [layers, aux,] radiance, radiance²
        sums = np.zeros((n_img * n_b + 2, n_pix), dtype=np.float32)
        seed_state = _seed_state(seed)
        chunk_pix = max(1, self.chunk_paths // spp)
        for p0 in range(0, n_pix, chunk_pix):
            npx = min(chunk_pix, n_pix - p0)
            fh = self._first_hit(tab, c, npx * spp, p0, spp, seed_state)
            acc, e1 = self._continue(tab, c, fh, npx * spp)
            sums[:, p0:p0 + npx] = self._combine(tab, fh, acc, e1, npx * spp, spp, layers)
            del fh, acc, e1
        depth, normal, slot = self._geometry(c, cam)

        def mean_image(k: int) -> np.ndarray:
            return (sums[k * n_b:(k + 1) * n_b].T.astype(np.float64) / spp).reshape(h, w, n_b)

        f32: dict[str, np.ndarray | None] = {}
        for k, name in enumerate(LAYERS + AUX_IMAGES):
            f32[name] = mean_image(k).astype(np.float32) if layers else None
        radiance = mean_image(n_img - 2)
        std_error = luminance_se = None
        if spp > 1:
            rad_var = np.maximum(mean_image(n_img - 1) - radiance ** 2, 0.0) * spp / (spp - 1)
            std_error = np.sqrt(rad_var / spp).astype(np.float32)
            del rad_var
            y_mean = sums[n_img * n_b].astype(np.float64) / spp
            y2_mean = sums[n_img * n_b + 1].astype(np.float64) / spp
            y_se = np.sqrt(np.maximum(y2_mean - y_mean ** 2, 0.0) / (spp - 1)).reshape(h, w)
            luminance_se = y_se.astype(np.float32)
        image = SpectralImage(
            wavelength_nm=self.grid.centres_nm.copy(), radiance=radiance.astype(np.float32),
            std_error=std_error, luminance_se_cd_m2=luminance_se, depth_m=depth,
            normal=normal, slot_id=slot, slot_names=list(self.slot_names), camera=cam, spp=spp,
            time_s=time.perf_counter() - t0,
            info={"variant": self.variant, "seed": int(seed), "max_depth": self.max_depth,
                  "rr_depth": self.rr_depth, "n_paths": n_pix * spp}, **f32)
        image.info["median_rel_se_luminance"] = _median_rel_se(image)
        return image


def _seed_state(seed: int) -> int:
    """The 64-bit seed of a render from a user seed (`predict.streams.lane_rng` hashes it with
    each path index)."""
    return (int(seed) * 0x9E3779B97F4A7C15 + 0x2545F4914F6CDD1D) & 0xFFFFFFFFFFFFFFFF


def _median_rel_se(image: SpectralImage) -> float:
    """Median over lit pixels (luminance > 1 % of the 99th percentile) of the luminance's
    relative standard error; NaN without an error estimate."""
    if image.luminance_se_cd_m2 is None:
        return float("nan")
    y = image.luminance_cd_m2()
    lit = y > 0.01 * max(float(np.percentile(y, 99.0)), 1e-300)
    if not np.any(lit):
        return float("nan")
    return float(np.median(image.luminance_se_cd_m2[lit] / y[lit]))
