"""The virtual camera: full spectral images (all 81 bands per path) with light-path layers,
depth, normals and the Wilkie & Weidlich (2009) auxiliary images CWNI and NWCI.

It is `normbox_lab.predict.fastrender.BandPathTracer`'s machinery (Mitsuba mono variant for ray casting,
band tables, λ-independent sampling, NEE + MIS, GGX/cosine mixture, Russian roulette) with a
pinhole camera in place of the 1° radiometer.  Every path carries all bands, so every layer and
both auxiliary images are exact per-path estimators from the same paths.

Image formation (`PinholeCamera`): perspective, `fov_deg` on the horizontal (x) axis as Mitsuba's
`perspective` with fov_axis="x", square pixels, row 0 at the top.  A pixel is a box filter:
its rays are uniform (jittered) over the pixel's area on the image plane, so a pixel value is the
mean radiance over the pixel, in W·sr⁻¹·m⁻²·nm⁻¹ on the bands of `fastrender.BandGrid`
(380…780 nm every 5 nm, triangular hats).  With a square image and `fov_deg` equal to the
radiometer's view, the mean of all pixels estimates exactly what `FastNormbox.render_view` does.

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

Public API:
    PinholeCamera, SpectralImage, CameraTracer(scene, bsdf_slots, emitter, camera, ...)
    NormboxCamera(geometry).render(...), render_normbox_camera(patch, wall, angle_deg, ...),
    normbox_camera(geometry, width, height)
    cornell_scene(...), cornell_materials(), render_cornell(materials, lamp_wavelength_nm, ...)
    figure1(truth, fitted, angle_deg, ...) -> Figure1 (truth / fitted images, ΔE00 map)
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from normbox_lab.predict.fastrender import (
    STAND_INS,
    BandGrid,
    BandPathTracer,
    FastNormbox,
    RectEmitter,
    mono_variant,
)

#: the light-path layers; they sum to `SpectralImage.radiance`
LAYERS = ("emission", "diffuse", "specular", "indirect")
#: the Wilkie & Weidlich auxiliary images
AUX_IMAGES = ("cwni", "nwci")
#: default samples per pixel of `render_normbox_camera`: 320×240 in ≈ 30–35 s on 2 shared cores
NORMBOX_DEFAULT_SPP = 128


# --------------------------------------------------------------------------------------------
# Camera and image
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera looking from `origin_m` at `target_m`; `fov_deg` is the horizontal field
    of view (Mitsuba's fov_axis="x"), pixels are square, row 0 is the top of the image."""

    origin_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 40.0
    width_px: int = 320
    height_px: int = 240

    def __post_init__(self) -> None:
        if int(self.width_px) < 1 or int(self.height_px) < 1:
            raise ValueError(f"image size must be ≥ 1×1, got {self.width_px}×{self.height_px}")
        if not 0.0 < float(self.fov_deg) < 180.0:
            raise ValueError(f"fov_deg must be in (0, 180), got {self.fov_deg}")

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(forward, right, up) unit vectors of the image plane, world space."""
        o = np.asarray(self.origin_m, dtype=np.float64)
        f = np.asarray(self.target_m, dtype=np.float64) - o
        f /= np.linalg.norm(f)
        right = np.cross(f, np.asarray(self.up, dtype=np.float64))
        norm = np.linalg.norm(right)
        if norm < 1e-12:
            raise ValueError("camera `up` is parallel to the viewing direction")
        right /= norm
        return f, right, np.cross(right, f)

    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """tan of the half field of view on x and on y."""
        tx = math.tan(math.radians(float(self.fov_deg)) / 2.0)
        return tx, tx * int(self.height_px) / int(self.width_px)

    def ray_direction(self, col: Any, row: Any) -> np.ndarray:
        """Unit world direction through image-plane position (col, row) in pixels (the pixel
        (i, j) covers cols j…j+1, rows i…i+1); numpy, for checks and overlays."""
        f, right, up = self.frame()
        tx, ty = self.tan_half_fov
        x = (2.0 * np.asarray(col, dtype=np.float64) / int(self.width_px) - 1.0) * tx
        y = (1.0 - 2.0 * np.asarray(row, dtype=np.float64) / int(self.height_px)) * ty
        d = f * np.ones_like(x)[..., None] + right * x[..., None] + up * y[..., None]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, point_m: Any) -> np.ndarray:
        """Image-plane (col, row) in pixels of world points [..., 3] (in front of the camera)."""
        f, right, up = self.frame()
        tx, ty = self.tan_half_fov
        v = np.asarray(point_m, dtype=np.float64) - np.asarray(self.origin_m, dtype=np.float64)
        z = v @ f
        col = ((v @ right) / z / tx + 1.0) / 2.0 * int(self.width_px)
        row = (1.0 - (v @ up) / z / ty) / 2.0 * int(self.height_px)
        return np.stack([col, row], axis=-1)


@dataclass
class SpectralImage:
    """A spectral image: (H, W, B) float32 arrays on `wavelength_nm` (B,), in W·sr⁻¹·m⁻²·nm⁻¹.

    `radiance` = emission + diffuse + specular + indirect (see the module docstring for the
    layers and CWNI/NWCI).  `std_error`: per-pixel, per-band Monte-Carlo standard error of
    `radiance` (None for spp < 2); `luminance_se_cd_m2` likewise for the luminance.
    `depth_m` (H, W): +inf where the pixel-centre ray misses; `normal` (H, W, 3): face normal
    towards the camera, zeros where it misses; `slot_id` (H, W): index into `slot_names`, −1 miss.
    """

    wavelength_nm: np.ndarray
    radiance: np.ndarray
    emission: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    indirect: np.ndarray
    cwni: np.ndarray
    nwci: np.ndarray
    std_error: np.ndarray | None
    luminance_se_cd_m2: np.ndarray | None
    depth_m: np.ndarray
    normal: np.ndarray
    slot_id: np.ndarray
    slot_names: list[str]
    camera: PinholeCamera
    spp: int
    time_s: float
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.radiance.shape[0]), int(self.radiance.shape[1]))

    @property
    def layers(self) -> dict[str, np.ndarray]:
        """The light-path layers (they sum to `radiance`)."""
        return {name: getattr(self, name) for name in LAYERS}

    def mask(self, slot: str) -> np.ndarray:
        """(H, W) bool: pixels whose centre ray first hits the material slot `slot`."""
        if slot not in self.slot_names:
            raise KeyError(f"no slot {slot!r}; slots: {self.slot_names}")
        return self.slot_id == self.slot_names.index(slot)

    def XYZ(self, image: str = "radiance") -> np.ndarray:
        """Absolute CIE 1931 XYZ (H, W, 3) of `radiance` or any layer / auxiliary image
        (Y in cd/m²), through `normbox_lab.images.color`."""
        from normbox_lab.images.color import spectral_to_XYZ

        return spectral_to_XYZ(self.wavelength_nm, np.asarray(getattr(self, image), np.float64))

    def luminance_cd_m2(self) -> np.ndarray:
        return self.XYZ()[..., 1]


# --------------------------------------------------------------------------------------------
# The tracer
# --------------------------------------------------------------------------------------------

class CameraTracer(BandPathTracer):
    """`BandPathTracer` with a pinhole camera: spectral image, layers, CWNI/NWCI, depth, normal.

    `scene`, `bsdf_slots`, `emitter` (a down-facing `RectEmitter`), `variant`, `emitter_slot` as
    for `BandPathTracer` (any mono Mitsuba scene of meshes).  The camera, the image size, spp and
    the seed are run-time data (opaque to the JIT), as are the emitter's placement and the path
    depths, so one set of compiled kernels serves every camera and every scene with the same
    material features (backscatter lobe, dispersion).  Deterministic for a given seed: each
    path's random stream depends only on (seed, pixel, sample), not on the chunking.
    """

    def __init__(self, scene: Any, bsdf_slots: Sequence[tuple[Any, str]], emitter: RectEmitter,
                 camera: PinholeCamera, *, variant: str | None = None,
                 emitter_slot: str = "panel", grid: BandGrid | None = None,
                 max_depth: int = 12, rr_depth: int = 6, chunk_paths: int = 1 << 16) -> None:
        if int(max_depth) < 2:
            raise ValueError("the camera needs max_depth ≥ 2 (a first hit and its light)")
        if int(rr_depth) < 1:
            raise ValueError("rr_depth must be ≥ 1 (no roulette at the first hit)")
        super().__init__(scene, bsdf_slots, None, emitter, variant=mono_variant(variant),
                         emitter_slot=emitter_slot, grid=grid, max_depth=max_depth,
                         rr_depth=rr_depth, chunk_paths=chunk_paths, symbolic=True)
        self.camera = camera
        self._ybar: np.ndarray | None = None

    # ---- run-time constants (opaque: changing them never recompiles) ----------------------
    def _consts(self, camera: PinholeCamera, spp: int) -> SimpleNamespace:
        dr, m = self.dr, self.m
        e = self.emitter
        ny, nx = self._map_shape

        def f(v: float) -> Any:
            return dr.opaque(m.Float, float(v))

        def u(v: int) -> Any:
            return dr.opaque(m.UInt32, int(v))

        def vec(v: Any) -> Any:
            return m.Vector3f(*(f(x) for x in v))

        fwd, right, up = camera.frame()
        tx, ty = camera.tan_half_fov
        return SimpleNamespace(
            origin=m.Point3f(*(f(x) for x in camera.origin_m)), fwd=vec(fwd), right=vec(right),
            up=vec(up), tan_x=f(tx), tan_y=f(ty), inv_w=f(1.0 / int(camera.width_px)),
            inv_h=f(1.0 / int(camera.height_px)), width=u(int(camera.width_px)),
            spp=u(int(spp)), em_slot=u(self.emitter_slot), max_depth=u(self.max_depth),
            rr_depth=u(self.rr_depth),
            em_x0=f(e.centre_m[0] - e.half_x_m), em_y0=f(e.centre_m[1] - e.half_y_m),
            em_sx=f(2.0 * e.half_x_m), em_sy=f(2.0 * e.half_y_m), em_z=f(e.centre_m[2]),
            em_area=f(e.area_m2), map_nx=u(nx), map_nxf=f(nx), map_nyf=f(ny))

    def _em_factor(self, c: SimpleNamespace, x: Any, y: Any) -> Any:
        """The emitter's spatial factor at a point of its plane (as `_emitter_factor`)."""
        dr, m = self.dr, self.m
        i = m.UInt32(dr.clip(dr.floor((x - c.em_x0) / c.em_sx * c.map_nxf), 0.0, c.map_nxf - 1.0))
        j = m.UInt32(dr.clip(dr.floor((y - c.em_y0) / c.em_sy * c.map_nyf), 0.0, c.map_nyf - 1.0))
        return dr.gather(m.Float, self._factor_map, j * c.map_nx + i)

    def _lookup(self, tab: Mapping[str, Any], delta: Any) -> Any:
        """Band spectra at λ_b + δ (as `BandPathTracer._trace`'s lookup)."""
        dr, m = self.dr, self.m
        step = self.grid.step_nm
        pos = delta + step
        k = m.UInt32(dr.floor(pos))
        frac = pos - dr.floor(pos)
        offsets = [b * step for b in range(self.grid.n_bands)]
        n_fine = tab["n_fine"]

        def lookup(table: Any, slot: Any, active: Any, width: int) -> list[list[Any]]:
            base = slot * n_fine + k
            arr = m.Array4f if width == 4 else m.Array2f
            out: list[list[Any]] = [[] for _ in range(width // 2)]
            for off in offsets:
                v = dr.gather(arr, table, base + off, active)
                for t in range(width // 2):
                    out[t].append(dr.fma(frac, v[2 * t + 1], v[2 * t]))
            return out

        return lookup

    def _camera_ray(self, c: SimpleNamespace, col: Any, row: Any, jx: Any, jy: Any) -> Any:
        dr, m = self.dr, self.m
        x = (2.0 * (m.Float(col) + jx) * c.inv_w - 1.0) * c.tan_x
        y = (1.0 - 2.0 * (m.Float(row) + jy) * c.inv_h) * c.tan_y
        return m.Ray3f(c.origin, dr.normalize(c.fwd + c.right * x + c.up * y))

    # ---- one path vertex, in pieces --------------------------------------------------------
    def _intersect(self, c: SimpleNamespace, ray: Any, active: Any) -> SimpleNamespace:
        dr, m = self.dr, self.m
        pi = self.scene.ray_intersect_preliminary(ray, active=active)
        valid = active & pi.is_valid()
        reg = dr.reinterpret_array(m.UInt32, pi.shape)
        slot = dr.gather(m.UInt32, self._shape_slot, reg, valid)
        fidx = dr.gather(m.UInt32, self._shape_base, reg, valid) + pi.prim_index
        ng = m.Vector3f(*(dr.gather(m.Float, comp, fidx, valid) for comp in self._normals))
        p = ray.o + ray.d * pi.t
        surf = valid & (slot > 0) & (slot != c.em_slot)
        return SimpleNamespace(valid=valid, t=pi.t, slot=slot, ng=ng, p=p, surf=surf)

    def _emission(self, c: SimpleNamespace, hit: SimpleNamespace, ray: Any,
                  prev_pdf: Any) -> Any:
        """The emitter's factor where the ray hits its front, MIS-weighted against NEE when the
        ray was BSDF-sampled (prev_pdf > 0); weight 1 for camera rays."""
        dr = self.dr
        cos_l = ray.d.z                                   # the light faces −z
        hit_em = hit.valid & (hit.slot == c.em_slot) & (cos_l > 0)
        pdf_em = dr.square(hit.t) / (c.em_area * dr.fmax(cos_l, 1e-12))
        w = dr.select(prev_pdf > 0, dr.square(prev_pdf)
                      / dr.fmax(dr.square(prev_pdf) + dr.square(pdf_em), 1e-30), 1.0)
        return dr.select(hit_em, self._em_factor(c, hit.p.x, hit.p.y) * w, 0.0)

    def _vertex(self, tab: Mapping[str, Any], lookup: Any, delta: Any, hit: SimpleNamespace,
                ray: Any, active: Any) -> tuple[SimpleNamespace, Any, Any]:
        """Material and local frame at a surface hit: (vx for `_band_factors`, frame, origin
        of rays leaving it)."""
        dr, m = self.dr, self.m
        wi_w = -ray.d
        nf = dr.select(dr.dot(wi_w, hit.ng) < 0, -hit.ng, hit.ng)
        frame = m.Frame3f(nf)
        slot = hit.slot
        kd, ks = lookup(tab["kdks"], slot, active, 4)
        has_kb, dispersive = tab["has_kb"], tab["dispersive"]
        vx = SimpleNamespace(
            wi=frame.to_local(wi_w), alpha=dr.gather(m.Float, tab["alpha"], slot, active),
            eta=dr.gather(m.Float, tab["eta"], slot, active),
            c=dr.gather(m.Float, tab["c"], slot, active),
            p_spec=dr.gather(m.Float, tab["p_spec"], slot, active), kd=kd, ks=ks,
            kb=lookup(tab["kb"], slot, active, 2)[0] if has_kb else None,
            inv_s2=dr.gather(m.Float, tab["inv_sigma2"], slot, active) if has_kb else None,
            deta=dr.gather(m.Float, tab["deta"], slot, active) if dispersive else None,
            delta=delta)
        return vx, frame, self._offset(hit.p, nf)

    def _nee(self, c: SimpleNamespace, vx: SimpleNamespace, frame: Any, o: Any, rng: Any,
             active: Any) -> tuple[Any, Any, Any]:
        """A uniform point of the emitter with a shadow ray: (local wo, weight without the
        BRDF — factor·MIS·cos/pdf —, mask)."""
        dr, m = self.dr, self.m
        lx = c.em_x0 + rng.next_float32() * c.em_sx
        ly = c.em_y0 + rng.next_float32() * c.em_sy
        to_l = m.Vector3f(lx, ly, c.em_z) - o
        dist2 = dr.squared_norm(to_l)
        dist = dr.sqrt(dist2)
        dl = to_l / dist
        cos_e = dl.z
        shadow = m.Ray3f(o, dl)
        shadow.maxt = dist * (1.0 - 1e-4)
        ok = active & (cos_e > 0)
        ok = ok & ~self.scene.ray_test(shadow, ok)
        pdf_l = dist2 / (c.em_area * dr.fmax(cos_e, 1e-12))
        wo = frame.to_local(dl)
        bpdf = self._pdf(vx.wi, wo, vx.alpha, vx.p_spec)
        mis = dr.square(pdf_l) / dr.fmax(dr.square(pdf_l) + dr.square(bpdf), 1e-30)
        return wo, self._em_factor(c, lx, ly) / dr.fmax(pdf_l, 1e-30) * mis * wo.z, ok

    def _lobes(self, vx: SimpleNamespace, wo: Any, weight: Any,
               mask: Any) -> tuple[list[Any], list[Any]]:
        """weight·f_b split into the diffuse part (kd_b/π − c) and the angular lobes (GGX and
        backscatter), both through `_band_factors` (one BRDF definition)."""
        m = self.m
        zeros = [m.Float(0.0)] * self.grid.n_bands
        diffuse = SimpleNamespace(**{**vars(vx), "ks": zeros, "kb": None, "inv_s2": None,
                                     "deta": None})
        angular = SimpleNamespace(**{**vars(vx), "kd": zeros, "c": m.Float(0.0)})
        return (self._band_factors(diffuse, wo, weight, mask),
                self._band_factors(angular, wo, weight, mask))

    # ---- the three kernels of a chunk -------------------------------------------------------
    def _first_hit(self, tab: Mapping[str, Any], c: SimpleNamespace, n: int, pix0: int,
                   spp: int, seed_state: int) -> SimpleNamespace:
        """The camera rays of pixels pix0… (spp each) to their first hit: emission, NEE and the
        BSDF sample there, and the continuation ray.  Everything evaluated (one kernel)."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        step = self.grid.step_nm
        idx = dr.arange(m.UInt32, n)
        gidx = m.UInt64(idx) + dr.opaque(m.UInt64, int(pix0) * int(spp))
        # seeded by the global path index (the constructor would add the chunk-local index)
        rng = m.PCG32(size=n)
        rng.seed(initstate=dr.opaque(m.UInt64, int(seed_state)) + gidx, initseq=gidx)
        delta = step * (rng.next_float32() - rng.next_float32())
        pix = dr.opaque(m.UInt32, int(pix0)) + idx // c.spp
        row = pix // c.width
        col = pix - row * c.width
        jx = rng.next_float32()
        jy = rng.next_float32()
        ray = self._camera_ray(c, col, row, jx, jy)
        lookup = self._lookup(tab, delta)
        hit = self._intersect(c, ray, m.Bool(True))
        e0 = self._emission(c, hit, ray, m.Float(0.0))
        active = hit.surf
        vx, frame, o = self._vertex(tab, lookup, delta, hit, ray, active)
        wl, wt, ok = self._nee(c, vx, frame, o, rng, active)
        nd, ns = self._lobes(vx, wl, wt, ok)
        wo, bpdf, act = self._sample(vx, rng, active)
        gd, gs = self._lobes(vx, wo, wo.z / dr.fmax(bpdf, 1e-30), act)
        # the roulette probe of the full path (as BandPathTracer: bands 0, 8, 16, …)
        probe = dr.abs(gd[0] + gs[0])
        for b in range(8, n_b, 8):
            probe = dr.fmax(probe, dr.abs(gd[b] + gs[b]))
        out = SimpleNamespace(nd=nd, ns=ns, gd=gd, gs=gs, e0=e0, delta=delta,
                              ray=m.Ray3f(o, frame.to_world(wo)), pdf=bpdf,
                              active=act & (1 < c.max_depth), rng=rng, probe=probe)
        dr.eval(out.nd, out.ns, out.gd, out.gs, out.e0, out.delta, out.ray.o, out.ray.d,
                out.pdf, out.active, out.rng, out.probe)
        return out

    def _continue(self, tab: Mapping[str, Any], c: SimpleNamespace,
                  fh: SimpleNamespace) -> tuple[list[Any], Any]:
        """The path loop from the continuation rays with throughput 1: (acc_b, e1), where e1 is
        the emitter seen at the first vertex (MIS vs NEE) and acc_b everything after it."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        delta, probe_scale = fh.delta, fh.probe
        lookup = self._lookup(tab, delta)

        def bounce(depth: Any, active: Any, ray: Any, prev_pdf: Any, rng: Any, thr: Any,
                   acc: Any, e1: Any) -> tuple[Any, ...]:
            thr, acc = list(thr), list(acc)
            hit = self._intersect(c, ray, active)
            e = self._emission(c, hit, ray, prev_pdf)
            first = depth == 1
            e1 = e1 + dr.select(first, e, 0.0)
            e_later = dr.select(first, 0.0, e)
            for b in range(n_b):
                acc[b] = dr.fma(thr[b], e_later, acc[b])
            active = hit.surf & (depth + 1 < c.max_depth)
            vx, frame, o = self._vertex(tab, lookup, delta, hit, ray, active)
            wl, wt, ok = self._nee(c, vx, frame, o, rng, active)
            fac = self._band_factors(vx, wl, wt, ok)
            for b in range(n_b):
                acc[b] = dr.fma(thr[b], fac[b], acc[b])
            wo, bpdf, active = self._sample(vx, rng, active)
            fac = self._band_factors(vx, wo, wo.z / dr.fmax(bpdf, 1e-30), active)
            for b in range(n_b):
                thr[b] = thr[b] * fac[b]
            probe = dr.abs(thr[0])
            for b in range(8, n_b, 8):
                probe = dr.fmax(probe, dr.abs(thr[b]))
            q = dr.select(depth + 1 >= c.rr_depth, dr.minimum(probe * probe_scale, 0.95), 1.0)
            active = active & (rng.next_float32() < q)
            inv_q = dr.select(active, 1.0 / dr.fmax(q, 1e-12), 0.0)
            for b in range(n_b):
                thr[b] = thr[b] * inv_q
            return depth + 1, active, m.Ray3f(o, frame.to_world(wo)), bpdf, rng, thr, acc, e1

        state = (m.UInt32(1), fh.active, fh.ray, fh.pdf, fh.rng,
                 [m.Float(1.0) for _ in range(n_b)], [m.Float(0.0) for _ in range(n_b)],
                 m.Float(0.0))
        state = dr.while_loop(state, lambda depth, active, *_: active & (depth < c.max_depth),
                              bounce, label="camerapath")
        acc, e1 = state[6], state[7]
        dr.eval(acc, e1)
        return acc, e1

    def _combine(self, tab: Mapping[str, Any], fh: SimpleNamespace, acc: list[Any], e1: Any,
                 spp: int) -> np.ndarray:
        """Per-path layers, CWNI, NWCI, radiance² and luminance (and its square), summed over
        each pixel's spp paths: (7·B + 2, n_pixels) float32."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        lookup = self._lookup(tab, fh.delta)
        le = lookup(tab["le"], m.UInt32(0), m.Bool(True), 2)[0]
        inv_b = 1.0 / n_b
        g = [fh.gd[b] + fh.gs[b] for b in range(n_b)]
        nee = [fh.nd[b] + fh.ns[b] for b in range(n_b)]
        inc = [(e1 + acc[b]) * le[b] for b in range(n_b)]
        avg_le = _sum(le) * inv_b
        avg_inc = _sum(inc) * inv_b
        avg_nee = _sum(nee) * inv_b
        avg_g = _sum(g) * inv_b
        ybar = self._luminance_weights()
        emission, diffuse, specular, indirect, cwni, nwci, rad2 = ([] for _ in range(7))
        y = m.Float(0.0)
        for b in range(n_b):
            em_b = fh.e0 * le[b]
            di_b = dr.fma(fh.gd[b], e1, fh.nd[b]) * le[b]
            sp_b = dr.fma(fh.gs[b], e1, fh.ns[b]) * le[b]
            in_b = g[b] * acc[b] * le[b]
            rad_b = em_b + di_b + sp_b + in_b
            emission.append(em_b)
            diffuse.append(di_b)
            specular.append(sp_b)
            indirect.append(in_b)
            cwni.append(dr.fma(avg_le, nee[b], g[b] * avg_inc))
            nwci.append(dr.fma(avg_nee, le[b], avg_g * inc[b]))
            rad2.append(rad_b * rad_b)
            y = dr.fma(float(ybar[b]), rad_b, y)
        outputs = emission + diffuse + specular + indirect + cwni + nwci + rad2 + [y, y * y]
        dr.eval(outputs)                  # one kernel (block_sum would launch one per output)
        sums = dr.block_sum(outputs, int(spp), mode="evaluated")
        return np.stack([np.asarray(s, dtype=np.float32) for s in sums])

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
               camera: PinholeCamera | None = None) -> SpectralImage:
        """The spectral image of the scene with `materials` (slot name → `Material`) and the
        emitter's spectral radiance (W·sr⁻¹·m⁻²·nm⁻¹ on `emitter_wavelength_nm`), `spp` jittered
        paths per pixel.  `camera` overrides the tracer's camera for this render."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be ≥ 1, got {spp}")
        cam = camera if camera is not None else self.camera
        t0 = time.perf_counter()
        tab = self._tables(materials, emitter_wavelength_nm, emitter_radiance)
        c = self._consts(cam, spp)
        w, h = int(cam.width_px), int(cam.height_px)
        n_pix = w * h
        n_b = self.grid.n_bands
        # per-pixel sums over the spp paths (float32 as Dr.Jit reduced them), then the means
        # one (H, W, B) image at a time, to keep the peak memory low
        sums = np.zeros((7 * n_b + 2, n_pix), dtype=np.float32)
        seed_state = _seed_state(seed)
        chunk_pix = max(1, self.chunk_paths // spp)
        for p0 in range(0, n_pix, chunk_pix):
            npx = min(chunk_pix, n_pix - p0)
            fh = self._first_hit(tab, c, npx * spp, p0, spp, seed_state)
            acc, e1 = self._continue(tab, c, fh)
            sums[:, p0:p0 + npx] = self._combine(tab, fh, acc, e1, spp)
            del fh, acc, e1
        depth, normal, slot = self._geometry(c, cam)

        def mean_image(k: int) -> np.ndarray:
            return (sums[k * n_b:(k + 1) * n_b].T.astype(np.float64) / spp).reshape(h, w, n_b)

        f32: dict[str, np.ndarray] = {}
        radiance = np.zeros((h, w, n_b))
        for k, name in enumerate(LAYERS + AUX_IMAGES):
            f32[name] = mean_image(k).astype(np.float32)
            if name in LAYERS:
                radiance += f32[name]
        std_error = luminance_se = None
        if spp > 1:
            rad_var = np.maximum(mean_image(6) - radiance ** 2, 0.0) * spp / (spp - 1)
            std_error = np.sqrt(rad_var / spp).astype(np.float32)
            del rad_var
            y_mean = sums[7 * n_b].astype(np.float64) / spp
            y2_mean = sums[7 * n_b + 1].astype(np.float64) / spp
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


def _sum(values: Sequence[Any]) -> Any:
    total = values[0]
    for v in values[1:]:
        total = total + v
    return total


def _seed_state(seed: int) -> int:
    """PCG32 initial state from a user seed (one stream per path via initseq)."""
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


# --------------------------------------------------------------------------------------------
# The Normbox seen from its open side (the paper's Fig. 1)
# --------------------------------------------------------------------------------------------

def normbox_camera(geometry: Any = None, width: int = 320, height: int = 240, *,
                   distance_m: float | None = None, margin: float = 1.06) -> PinholeCamera:
    """A camera outside the box on the open (−y) side, on the axis of the opening, looking +y:
    the whole opening fills the image height with `margin`, so the walls, the floor, the lit
    aperture (seen from below, its back half and the panel through it), the sample holder and
    the patch are in view.  `distance_m` from the opening plane (default 10/6 of the box size,
    1.0 m for the 600 mm box)."""
    from normbox_lab.predict.scene import as_geometry

    g = as_geometry(geometry)
    size_m = g.box_inner_mm / 1000.0
    dist = float(distance_m) if distance_m is not None else size_m / 0.6
    tan_y = margin * size_m / 2.0 / dist
    fov_deg = math.degrees(2.0 * math.atan(tan_y * int(width) / int(height)))
    y0 = -size_m / 2.0 - dist
    return PinholeCamera(origin_m=(0.0, y0, size_m / 2.0), target_m=(0.0, 0.0, size_m / 2.0),
                         up=(0.0, 0.0, 1.0), fov_deg=fov_deg, width_px=int(width),
                         height_px=int(height))


class NormboxCamera:
    """The virtual Normbox (`fastrender.FastNormbox`'s one loaded mono scene, patch and holder
    plate moved in place per angle) seen by a `CameraTracer`; the same object also gives
    radiometer readings (`box.render_view`) on the same scene."""

    def __init__(self, geometry: Any = None, *, variant: str | None = None,
                 max_depth: int = 12, rr_depth: int = 6, chunk_paths: int = 1 << 16) -> None:
        self.box = FastNormbox(geometry, variant=variant, max_depth=max_depth,
                               rr_depth=rr_depth)
        self.geometry = self.box.geometry
        self.chunk_paths = int(chunk_paths)
        self._tracer: CameraTracer | None = None
        self._tracer_angle_deg: float | None = None

    def tracer(self, angle_deg: float) -> CameraTracer:
        """The camera tracer with the patch at `angle_deg` (builds the scene once)."""
        bt = self.box.tracer(angle_deg)            # loads the scene / moves the patch in place
        # the stand-in BSDFs are FastNormbox internals: the camera shares its loaded scene
        if self._tracer is None:
            slots = [(self.box._stand_in[r], STAND_INS[r]) for r in STAND_INS]
            self._tracer = CameraTracer(bt.scene, slots, bt.emitter, normbox_camera(self.geometry),
                                        variant=self.box.variant, emitter_slot="panel",
                                        grid=self.box.grid, max_depth=self.box.max_depth,
                                        rr_depth=self.box.rr_depth,
                                        chunk_paths=self.chunk_paths)
        elif self._tracer_angle_deg != float(angle_deg):
            self._tracer.refresh_geometry()
        self._tracer_angle_deg = float(angle_deg)
        return self._tracer

    def render(self, *, patch: Any, wall: Any, angle_deg: float, holder: Any = None,
               lamp: Any = None, width: int = 320, height: int = 240,
               spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0,
               camera: PinholeCamera | None = None) -> SpectralImage:
        """The box interior with `patch` at `angle_deg` (default camera: `normbox_camera`)."""
        from normbox_lab.predict.materials import holder_material
        from normbox_lab.predict.render import LAMP_GRID_NM, Lamp

        holder = holder if holder is not None else holder_material()
        lamp = lamp if lamp is not None else Lamp()
        cam = camera if camera is not None else normbox_camera(self.geometry, width, height)
        tr = self.tracer(angle_deg)
        image = tr.render({"patch": patch, "wall": wall, "holder": holder}, LAMP_GRID_NM,
                          lamp.radiance(LAMP_GRID_NM), spp=spp, seed=seed, camera=cam)
        image.info.update({"scene": "normbox", "angle_deg": float(angle_deg),
                           "patch": patch.name, "wall": wall.name, "holder": holder.name})
        return image


_NORMBOX_CAMERAS: dict[tuple[str, str], NormboxCamera] = {}


def normbox_camera_renderer(geometry: Any = None, variant: str | None = None) -> NormboxCamera:
    """This process's `NormboxCamera` for a geometry (one loaded scene, reused)."""
    from normbox_lab.predict.scene import as_geometry

    key = (repr(as_geometry(geometry)), mono_variant(variant))
    nc = _NORMBOX_CAMERAS.get(key)
    if nc is None:
        nc = _NORMBOX_CAMERAS[key] = NormboxCamera(geometry, variant=variant)
    return nc


def render_normbox_camera(patch: Any, wall: Any, angle_deg: float, *, holder: Any = None,
                          lamp: Any = None, width: int = 320, height: int = 240,
                          spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0,
                          geometry: Any = None) -> SpectralImage:
    """The box interior seen from the open side (`normbox_camera`): the virtual equivalent of
    the Normbox paper's Fig. 1.  `patch`, `wall`, `holder` are `materials.Material`s (truth or
    fitted), `lamp` a `render.Lamp`."""
    return normbox_camera_renderer(geometry).render(
        patch=patch, wall=wall, angle_deg=angle_deg, holder=holder, lamp=lamp, width=width,
        height=height, spp=spp, seed=seed)


# --------------------------------------------------------------------------------------------
# A small Cornell-box-like scene (white balance tests)
# --------------------------------------------------------------------------------------------

#: material slots of `cornell_scene` (the light's slot is "light")
CORNELL_SLOTS = ("floor", "ceiling", "back", "left", "right", "box")


@dataclass
class CornellScene:
    """`cornell_scene`'s product: the tracer (scene, slots, light, camera) and its layout."""

    tracer: CameraTracer
    camera: PinholeCamera
    emitter: RectEmitter
    bsdf_slots: list[tuple[Any, str]]
    box_centre_m: tuple[float, float, float]
    box_half_m: float


def cornell_scene(width: int = 64, height: int = 48, *, variant: str | None = None,
                  max_depth: int = 12) -> CornellScene:
    """A 1 m Cornell-like box, open at y = −0.5: floor z = 0, ceiling z = 1, back y = +0.5,
    left x = −0.5, right x = +0.5; a 0.3 × 0.3 m light facing down 5 mm below the ceiling's
    centre (slot "light"); one cube of 0.36 m turned 20° about z standing on the floor (slot
    "box"); the camera outside on −y, looking +y.  Material slots: `CORNELL_SLOTS`."""
    from normbox_lab.predict.fastrender import in_variant

    variant = mono_variant(variant)
    light_z = 0.995
    half_light = 0.15
    centre = (0.12, 0.08, 0.18)
    half = 0.18
    with in_variant(variant) as mi:
        T = mi.ScalarTransform4f
        bsdfs = {name: mi.load_dict({"type": "diffuse", "reflectance": 0.05 + 0.1 * i})
                 for i, name in enumerate(CORNELL_SLOTS + ("light",))}

        def rect(t: Any, name: str) -> dict[str, Any]:
            return {"type": "rectangle", "to_world": t @ T().scale([0.5, 0.5, 1.0]),
                    "bsdf": bsdfs[name]}

        d = {"type": "scene",
             "floor": rect(T(), "floor"),
             "ceiling": rect(T().translate([0, 0, 1]).rotate([1, 0, 0], 180), "ceiling"),
             "back": rect(T().translate([0, 0.5, 0.5]).rotate([1, 0, 0], 90), "back"),
             "left": rect(T().translate([-0.5, 0, 0.5]).rotate([0, 1, 0], 90), "left"),
             "right": rect(T().translate([0.5, 0, 0.5]).rotate([0, 1, 0], -90), "right"),
             "box": {"type": "cube", "bsdf": bsdfs["box"],
                     "to_world": T().translate(list(centre)).rotate([0, 0, 1], 20)
                     .scale([half, half, half])},
             "light": {"type": "rectangle", "bsdf": bsdfs["light"],
                       "to_world": T().translate([0, 0, light_z]).rotate([1, 0, 0], 180)
                       .scale([half_light, half_light, 1.0])}}
        scene = mi.load_dict(d)
    emitter = RectEmitter((0.0, 0.0, light_z), half_light, half_light)
    # the opening (1 m) fills the image height with a 5 % margin, 1.4 m in front of it
    tan_y = 1.05 * 0.5 / 1.4
    camera = PinholeCamera(origin_m=(0.0, -1.9, 0.5), target_m=(0.0, 0.0, 0.5),
                           fov_deg=math.degrees(2.0 * math.atan(tan_y * width / height)),
                           width_px=int(width), height_px=int(height))
    slots = [(bsdfs[n], n) for n in CORNELL_SLOTS + ("light",)]
    tracer = CameraTracer(scene, slots, emitter, camera, variant=variant, emitter_slot="light",
                          max_depth=max_depth)
    return CornellScene(tracer, camera, emitter, slots, centre, half)


def cornell_materials() -> dict[str, Any]:
    """Default materials per slot: red left wall, green right wall, grey floor / ceiling /
    back (reflectance 0.5), white box (0.85); all Lambertian, smooth spectra."""
    from normbox_lab.predict.materials import MATERIAL_WAVELENGTHS_NM, Material

    wl = MATERIAL_WAVELENGTHS_NM
    red = 0.05 + 0.65 / (1.0 + np.exp(-(wl - 600.0) / 12.0))
    green = 0.06 + 0.45 * np.exp(-0.5 * ((wl - 530.0) / 35.0) ** 2)
    grey = np.full(wl.shape, 0.5)
    return {"left": Material.diffuse("red", red, wl), "right": Material.diffuse("green", green, wl),
            "floor": Material.diffuse("grey", grey, wl),
            "ceiling": Material.diffuse("grey", grey, wl),
            "back": Material.diffuse("grey", grey, wl),
            "box": Material.diffuse("white", np.full(wl.shape, 0.85), wl)}


_CORNELL: dict[tuple[int, int, str], CornellScene] = {}


def render_cornell(materials: Mapping[str, Any] | None, lamp_wavelength_nm: Any,
                   lamp_radiance: Any, width: int = 64, height: int = 48, spp: int = 64,
                   seed: int = 0) -> SpectralImage:
    """The Cornell-like scene (`cornell_scene`) under a light of spectral radiance
    `lamp_radiance` (W·sr⁻¹·m⁻²·nm⁻¹ on `lamp_wavelength_nm`); `materials` (slot → Material)
    override `cornell_materials()` per slot.  The white cube's pixels: `image.mask("box")`."""
    key = (int(width), int(height), mono_variant(None))
    cs = _CORNELL.get(key)
    if cs is None:
        cs = _CORNELL[key] = cornell_scene(int(width), int(height))
    mats = {**cornell_materials(), **dict(materials or {})}
    image = cs.tracer.render(mats, lamp_wavelength_nm, lamp_radiance, spp=spp, seed=seed)
    image.info["scene"] = "cornell"
    return image


# --------------------------------------------------------------------------------------------
# Figure 1: truth and fitted images side by side, per-pixel ΔE00
# --------------------------------------------------------------------------------------------

@dataclass
class Figure1:
    """Truth and fitted images of the same view (same seed: common random numbers), their
    XYZ, display sRGB (scaled so the white reference → 1, no white balance) and ΔE00 map."""

    angle_deg: float
    truth: SpectralImage
    fitted: SpectralImage
    truth_XYZ: np.ndarray
    fitted_XYZ: np.ndarray
    truth_srgb: np.ndarray
    fitted_srgb: np.ndarray
    delta_e00: np.ndarray          # (H, W)
    white_XYZ: np.ndarray          # absolute XYZ (cd/m²) of the white reference
    white_source: str
    scene_mask: np.ndarray         # (H, W) pixels on a box surface (not the light, not a miss)

    def summary(self) -> dict[str, float]:
        """ΔE00 statistics over the box surfaces (mean, median, 95th percentile, max)."""
        de = self.delta_e00[self.scene_mask]
        if de.size == 0:
            return {"mean": float("nan"), "median": float("nan"), "p95": float("nan"),
                    "max": float("nan")}
        return {"mean": float(np.mean(de)), "median": float(np.median(de)),
                "p95": float(np.percentile(de, 95.0)), "max": float(np.max(de))}

    def delta_e_rgb(self, max_delta_e: float = 5.0) -> np.ndarray:
        """The ΔE00 map as an RGB image in [0, 1] (matplotlib 'magma', 0 … max_delta_e)."""
        from matplotlib import colormaps

        x = np.clip(np.nan_to_num(self.delta_e00) / float(max_delta_e), 0.0, 1.0)
        return np.asarray(colormaps["magma"](x))[..., :3]

    def write_pngs(self, directory: Any, stem: str = "figure1") -> dict[str, Any]:
        """truth / fitted / ΔE00 PNGs in `directory`; returns their paths."""
        from pathlib import Path

        from normbox_lab.images.color import write_png

        d = Path(directory)
        return {"truth": write_png(d / f"{stem}-truth.png", self.truth_srgb),
                "fitted": write_png(d / f"{stem}-fitted.png", self.fitted_srgb),
                "delta_e00": write_png(d / f"{stem}-delta-e00.png", self.delta_e_rgb())}


def white_reference_XYZ(wall: Any, *, white_patch: Any = None, holder: Any = None,
                        lamp: Any = None, geometry: Any = None, angle_deg: float = 30.0,
                        target_rel_se: float = 0.002, seed: int = 0) -> np.ndarray:
    """Absolute XYZ of the white reference of `normbox_lab.analyze.compare`: the white ColorChecker
    patch (default: `materials.truth_patch(19)`) at 30° seen by the radiometer in the world
    with `wall` (same scene as the camera: the radiometer of `FastNormbox`)."""
    from normbox_lab.images.color import spectral_to_XYZ
    from normbox_lab.predict.materials import truth_patch

    white = white_patch if white_patch is not None else truth_patch(19)
    box = normbox_camera_renderer(geometry).box
    r = box.render_view(patch=white, wall=wall, angle_deg=angle_deg, holder=holder, lamp=lamp,
                        target_rel_se=target_rel_se, seed=seed)
    return spectral_to_XYZ(r.wavelength_nm, r.radiance)


def _white_patch_like(patch: Any) -> Any:
    """The truth world's white patch (19) of the same truth kind as `patch` ("default" unless
    its metadata says "model")."""
    from normbox_lab.predict.materials import TRUTH_KINDS, truth_patch

    kind = getattr(patch, "metadata", {}).get("truth", "default")
    return truth_patch(19, kind if kind in TRUTH_KINDS else "default")


def figure1(truth: Mapping[str, Any], fitted: Mapping[str, Any], angle_deg: float, *,
            lamp: Any = None, geometry: Any = None, width: int = 320, height: int = 240,
            spp: int = NORMBOX_DEFAULT_SPP, seed: int = 0, white_XYZ: Any = None,
            white_patch: Any = None) -> Figure1:
    """The Normbox paper's Fig. 1, virtually: the box with the truth materials and with the
    fitted ones (`{"patch": Material, "wall": Material, "holder": Material (optional)}` each),
    rendered with the same seed, and the per-pixel ΔE00 between them.

    ΔE00 follows `normbox_lab.analyze.compare`: both images' XYZ divided by the Y of one white
    reference, Lab with D65, kL = kC = kH = 1.  The white (`white_XYZ`, absolute, cd/m²) is by
    default the radiometer reading of the white patch at 30° in the truth world
    (`white_reference_XYZ`; the white patch is `white_patch`, else `truth["white"]`, else
    ColorChecker 19 of the truth patch's kind), i.e. the normalisation of the comparison
    tables, so image and tables speak the same ΔE.  The sRGB previews use the same white for scale (no white
    balance: the 3100 K lamp shows warm)."""
    from normbox_lab.images.color import XYZ_to_srgb, delta_e00_map

    nc = normbox_camera_renderer(geometry)
    kw = {"angle_deg": angle_deg, "lamp": lamp, "width": width, "height": height, "spp": spp,
          "seed": seed}
    img_t = nc.render(patch=truth["patch"], wall=truth["wall"], holder=truth.get("holder"), **kw)
    img_f = nc.render(patch=fitted["patch"], wall=fitted["wall"], holder=fitted.get("holder"),
                      **kw)
    if white_XYZ is None:
        if white_patch is None:
            white_patch = truth.get("white") or _white_patch_like(truth["patch"])
        white = white_reference_XYZ(truth["wall"], white_patch=white_patch,
                                    holder=truth.get("holder"), lamp=lamp, geometry=geometry,
                                    seed=seed)
        source = "radiometer: white patch at 30° in the truth world"
    else:
        white = np.asarray(white_XYZ, dtype=np.float64)
        source = "given"
    xyz_t, xyz_f = img_t.XYZ(), img_f.XYZ()
    white_Y = float(white[1])
    scene_mask = np.isfinite(img_t.depth_m) & (img_t.slot_id > 0) & \
        (img_t.slot_id != img_t.slot_names.index("panel"))
    return Figure1(float(angle_deg), img_t, img_f, xyz_t, xyz_f,
                   XYZ_to_srgb(xyz_t, white_Y), XYZ_to_srgb(xyz_f, white_Y),
                   delta_e00_map(xyz_t, xyz_f, white), white, source, scene_mask)
