"""The band path tracer: every traced path serves all wavelength bands (the fast renderer's kernel).

In the Normbox nothing geometric depends on wavelength (no dispersion in the fit model, one
global η per material), so a path's vertices and directions can be shared by all bands and only
its *throughput* evaluated per band.  Stock Mitsuba spectral rendering carries 4 hero wavelengths
per path, so a 5 nm band sees a path only ~4/81 of the time; here every path feeds all 81 bands.

How it works (a path tracer written with Dr.Jit, `BandPathTracer`; one symbolic-loop
megakernel per chunk of paths, its bands a loop over per-lane local arrays):
- Mitsuba does ray intersection, emitter sampling (position, pdf, visibility) and the
  shape/BSDF bookkeeping, in a *mono* JIT variant (`llvm_ad_mono` on a CPU, `cuda_ad_mono` on a
  GPU: nothing here is LLVM-specific).  The mono scene is `normbox_lab.predict.scene.scene_dict` — the
  same builder as the stock renderer — with geometry-only stand-in BSDFs (one per role, so a hit
  tells its material) and every panel cell's radiance replaced by its homogeneity-map factor.
  The spectral radiance of the lamp is applied per band.
- Directions are sampled independently of λ: a mixture of cosine-hemisphere and GGX (D·cos θh)
  sampling, emitter sampling with MIS (power heuristic) as in Mitsuba's `path` integrator,
  Russian roulette after `rr_depth` on a λ-independent survival probability, `max_depth` as in
  Mitsuba (12 segments by default, as `normbox_lab.predict.render`).
- The material family (`normbox_lab.predict.materials.Material`, which contains the fit model) separates:
      f_b(ωi, ωo) = kd_b/π + ks_b · F(ωi·h; η_b) · D·G1·G1/(4 cos cos) + kb_b · B(ωi·ωo) − c
  so one bounce multiplies band b's throughput by  kd_b·A + ks_b·F_b·S + kb_b·K − C  where
  A, S, K, C are per-path numbers; F is per path when η does not depend on λ (the fit model)
  and per band only for a dispersive truth material.
- Band definition, the same as the stock renderer (`specfilm` triangular SRFs, `render.py`):
  band b is the average of the radiance under a unit-height triangular hat of half-width 5 nm
  centred on λ_b.  Each path draws one triangular offset δ shared by all bands and evaluates all
  spectra at λ_b + δ (linear interpolation in 1 nm tables), so the estimate is unbiased for that
  band average and all bands of one path use common random numbers (as MIST packs wavelengths
  into the channels of one RGB render with the same random numbers).
- Standard error per band from the per-path sample variance (paths are i.i.d.).

Public API:
    BandPathTracer(scene, bsdf_slots, radiometer, emitter, variant=...).render(...) -> BandEstimate
    BandGrid, Radiometer, RectEmitter, BandEstimate, max_rel_se, and the BRDF pieces (ggx_d,
    smith_g1, fresnel, specular_probability).  The Normbox facade is
    `normbox_lab.predict.fastrender`; the all-patches tracer `normbox_lab.predict.patchset`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from normbox_lab.predict.guide import GUIDE_SHARE, GuideKernel
from normbox_lab.predict.kernel_safety import cell_index, jit_table, lane_index, require_finite
from normbox_lab.predict.streams import FirstBounceDraws, chunk_seed, lane_rng

INV_PI = 1.0 / np.pi


# --------------------------------------------------------------------------------------------
# Bands
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BandGrid:
    """Bands centred on start…stop every step nm, each a triangular hat of half-width step."""

    start_nm: int = 380
    stop_nm: int = 780
    step_nm: int = 5

    @property
    def centres_nm(self) -> np.ndarray:
        return np.arange(self.start_nm, self.stop_nm + 1, self.step_nm, dtype=np.float64)

    @property
    def n_bands(self) -> int:
        return int((self.stop_nm - self.start_nm) // self.step_nm + 1)

    @property
    def fine_nm(self) -> np.ndarray:
        """The 1 nm table grid covering every hat: start − step … stop + step (+1 for lerp)."""
        return np.arange(self.start_nm - self.step_nm, self.stop_nm + self.step_nm + 2, 1.0)

    def table(self, wavelength_nm: Any, values: Any) -> np.ndarray:
        """A spectrum on the 1 nm table grid (linear interpolation, constant beyond its ends)."""
        wl = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))
        v = np.broadcast_to(np.asarray(values, dtype=np.float64), wl.shape)
        return np.interp(self.fine_nm, wl, v)

    def band_average(self, wavelength_nm: Any, values: Any) -> np.ndarray:
        """The exact hat-weighted band averages of a (piecewise-linear) spectrum."""
        t = self.table(wavelength_nm, values)
        fine = self.fine_nm
        out = np.empty(self.n_bands)
        for b, c in enumerate(self.centres_nm):
            w = np.clip(1.0 - np.abs(fine - c) / self.step_nm, 0.0, None)
            out[b] = np.sum(w * t) / np.sum(w)
        return out


@dataclass(frozen=True)
class Radiometer:
    """A square view of `fov_deg` (Mitsuba `perspective`, fov on x, square film, box filter),
    averaged over its area: rays uniform on the film plane."""

    origin_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 1.0

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        o = np.asarray(self.origin_m, dtype=np.float64)
        f = np.asarray(self.target_m, dtype=np.float64) - o
        f /= np.linalg.norm(f)
        left = np.cross(np.asarray(self.up, dtype=np.float64), f)
        left /= np.linalg.norm(left)
        return f, left, np.cross(f, left)


# --------------------------------------------------------------------------------------------
# The engine
# --------------------------------------------------------------------------------------------

@dataclass
class BandEstimate:
    """Per-band radiance (the emitter table's unit) and its Monte-Carlo standard error."""

    wavelength_nm: np.ndarray
    radiance: np.ndarray
    std_error: np.ndarray
    n_paths: int
    time_s: float

    @property
    def relative_std_error(self) -> np.ndarray:
        return self.std_error / np.maximum(np.abs(self.radiance), 1e-300)


def max_rel_se(mean: np.ndarray, se: np.ndarray) -> float:
    """The largest relative standard error over bands with signal (> 1e-6 of the peak)."""
    sig = np.abs(mean) > 1e-6 * max(float(np.max(np.abs(mean))), 1e-300)
    return float(np.max(se[sig] / np.abs(mean[sig]))) if np.any(sig) else 0.0


@dataclass(frozen=True)
class RectEmitter:
    """An axis-aligned rectangular area light in a plane z = z_m, emitting downwards (−z),
    Lambertian, with a piecewise-constant spatial factor map (rows along y, columns along x,
    mean ≈ 1); the spectral radiance is given per render."""

    centre_m: tuple[float, float, float]
    half_x_m: float
    half_y_m: float
    factor_map: tuple[tuple[float, ...], ...] = ((1.0,),)

    @property
    def area_m2(self) -> float:
        return 4.0 * self.half_x_m * self.half_y_m


class BandLookup:
    """Spectra at λ_b + δ for a path's offset δ (δ + step = k + frac, k the 1 nm cell) from
    interleaved (value, slope) tables of `width`/2 spectra per slot (one packet gather per band).

    - `lookup(table, slot, active, width)`: every band, as Python lists (straight-line code:
      for values needed once per path, e.g. the lamp spectrum at the end);
    - `lookup.band(table, slot, active, width, b)`: band b (a UInt32, the counter of a band
      loop), so that a kernel holds one band's code however many bands there are.
    Every index lies in the table: slot < slots, k < 2·step, b < n_bands."""

    def __init__(self, dr: Any, m: Any, k: Any, frac: Any, n_fine: int, grid: BandGrid) -> None:
        self.dr, self.m, self.k, self.frac = dr, m, k, frac
        self.n_fine = int(n_fine)
        self.step = int(grid.step_nm)
        self.n_bands = grid.n_bands

    def band(self, table: Any, slot: Any, active: Any, width: int, b: Any) -> list[Any]:
        dr, m = self.dr, self.m
        arr = m.Array4f if width == 4 else m.Array2f
        v = dr.gather(arr, table, slot * self.n_fine + self.k + b * self.step, active)
        return [dr.fma(self.frac, v[2 * t + 1], v[2 * t]) for t in range(width // 2)]

    def __call__(self, table: Any, slot: Any, active: Any, width: int) -> list[list[Any]]:
        out: list[list[Any]] = [[] for _ in range(width // 2)]
        for b in range(self.n_bands):
            for t, value in enumerate(self.band(table, slot, active, width, b)):
                out[t].append(value)
        return out


class BandPathTracer:
    """Path tracer carrying all bands per path; Mitsuba (any JIT mono variant) does only the
    ray casting: `scene.ray_intersect_preliminary` and `scene.ray_test`.

    - `scene`: a Mitsuba scene loaded in `variant`, all shapes meshes (Mitsuba ≥ 3.6 makes
      rectangles and cubes meshes).  Normals are the meshes' face normals (flat geometry).
    - `bsdf_slots`: (BSDF object of that scene, material slot name) pairs: a surface whose BSDF
      is listed takes the material passed for that name at render time; any other is black.
    - `emitter_slot`: the slot name of the emitting surface (`emitter` gives its geometry for
      emitter sampling).  Surfaces are two-sided (as the project's `normbox` BSDF).
    No virtual function call is traced, and every material parameter is array data, so one
    compiled kernel serves all materials, all sample angles, and later processes (Dr.Jit's
    kernel cache on disk).

    The path loop (`_path_loop`: emission with MIS, next-event estimation, BSDF sampling,
    Russian roulette) is the one loop of the project: the radiometer estimate (`render`), the
    all-patches estimate (`normbox_lab.predict.patchset`) and the camera
    (`normbox_lab.images.tracer`) all run it, each with its own start of the path.
    """

    #: rectangles every vertex also samples by area (`guide.GuideRects`; `FastNormbox`: the
    #: aperture's side faces), or None
    guide: Any = None
    #: compile the backscatter lobe and the λ-dependent η in whatever the materials are (one
    #: kernel for every material family), instead of only where a material has them
    general_materials: bool = False

    def __init__(self, scene: Any, bsdf_slots: Sequence[tuple[Any, str]],
                 radiometer: Radiometer | None, emitter: RectEmitter, *, variant: str,
                 emitter_slot: str = "panel", grid: BandGrid | None = None, max_depth: int = 12,
                 rr_depth: int = 6, chunk_paths: int = 1 << 16) -> None:
        import drjit as dr
        import mitsuba as mi

        self.m = getattr(mi, variant)
        self.dr = dr
        self.variant = variant
        self.scene = scene
        self.grid = grid or BandGrid()
        self.max_depth = int(max_depth)
        self.rr_depth = int(rr_depth)
        self.chunk_paths = int(chunk_paths)
        self.radiometer = radiometer
        self.emitter = emitter
        m = self.m
        self.slot_names = ["<black>"]
        self._bsdf_slot: dict[int, int] = {}
        for bsdf, name in bsdf_slots:
            if name not in self.slot_names:
                self.slot_names.append(name)
            reg = int(dr.reinterpret_array(m.UInt32, m.BSDFPtr(bsdf))[0])
            self._bsdf_slot[reg] = self.slot_names.index(name)
        if emitter_slot not in self.slot_names:
            raise KeyError(f"emitter slot {emitter_slot!r} is not among the BSDF slots")
        self.emitter_slot = self.slot_names.index(emitter_slot)
        fm = np.asarray(emitter.factor_map, dtype=np.float64)
        self._factor_map = jit_table(m.Float, np.concatenate([fm.ravel(), [0.0]]))   # ≥ 2 entries
        self._map_shape = fm.shape
        self.refresh_geometry()

    def refresh_geometry(self) -> None:
        """Rebuild the per-shape tables (call after moving shapes with `mi.traverse`)."""
        dr, m = self.dr, self.m
        shapes = list(self.scene.shapes())
        regs = [int(dr.reinterpret_array(m.UInt32, m.ShapePtr(s))[0]) for s in shapes]
        size = max(regs) + 2
        base = np.zeros(size, dtype=np.uint32)
        slot = np.zeros(size, dtype=np.uint32)
        normals = []
        offset = 0
        for s, reg in zip(shapes, regs, strict=True):
            if not s.is_mesh():
                raise TypeError(f"shape {s.id()!r} is not a mesh (need Mitsuba ≥ 3.6)")
            p = np.asarray(s.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
            f = np.asarray(s.faces_buffer(), dtype=np.int64).reshape(-1, 3)
            n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
            normals.append(n)
            base[reg] = offset
            offset += len(n)
            b = s.bsdf()
            breg = int(dr.reinterpret_array(m.UInt32, m.BSDFPtr(b))[0]) if b is not None else -1
            slot[reg] = self._bsdf_slot.get(breg, 0)
        nrm = np.concatenate(normals + [np.zeros((1, 3))])
        self._shape_base = jit_table(m.UInt32, base, np.uint32)
        self._shape_slot = jit_table(m.UInt32, slot, np.uint32)
        self._normals = [jit_table(m.Float, nrm[:, i]) for i in range(3)]

    # ---- tables ------------------------------------------------------------------------
    def material_tables(self, material: Any) -> dict[str, Any]:
        """One material on the 1 nm grid: kd, ks, kb tables and its scalar parameters."""
        g = self.grid
        mkb = getattr(material, "kb", None)
        return {"kd": g.table(material.wavelength_nm, material.kd),
                "ks": g.table(material.wavelength_nm, material.ks),
                "kb": (g.table(material.wavelength_nm, mkb) if mkb is not None
                       else np.zeros(g.fine_nm.size)),
                "alpha": max(float(material.alpha), 1e-4), "eta": float(material.eta),
                "c": float(getattr(material, "c", 0.0)),
                "deta": float(getattr(material, "deta_per_100nm", 0.0)) / 100.0,
                "inv_sigma2": 1.0 / float(getattr(material, "backscatter_sigma", 1.0)) ** 2,
                "p_spec": specular_probability(material)}

    def _tables(self, materials: Mapping[str, Any], emitter_wavelength_nm: Any,
                emitter_radiance: Any, extra_slots: Sequence[Any] = ()) -> dict[str, Any]:
        """JIT tables of every slot's material (slot names → `materials`), then `extra_slots`
        (materials at slot indices len(slot_names)…, for `_path_loop`'s patch remapping)."""
        m = self.m
        g = self.grid
        fine = g.fine_nm
        names = list(self.slot_names)
        n_slots = len(names) + len(extra_slots)
        kd = np.zeros((n_slots, fine.size))
        ks = np.zeros((n_slots, fine.size))
        kb = np.zeros((n_slots, fine.size))
        width = max(n_slots, 2)                   # ≥ 2 entries: arrays, never JIT literals
        par = {"alpha": np.full(width, 0.5), "eta": np.full(width, 1.5),
               "c": np.zeros(width), "p_spec": np.zeros(width), "deta": np.zeros(width),
               "inv_sigma2": np.ones(width)}
        for s in range(n_slots):
            if s < len(names):
                if s == 0 or s == self.emitter_slot:
                    continue                      # black
                mat = materials.get(names[s])
                if mat is None:
                    raise KeyError(f"no material for {names[s]!r}")
            else:
                mat = extra_slots[s - len(names)]
            t = self.material_tables(mat)
            kd[s], ks[s], kb[s] = t["kd"], t["ks"], t["kb"]
            for key, column in par.items():
                column[s] = t[key]
        le = g.table(emitter_wavelength_nm, emitter_radiance)
        tab = {k: jit_table(m.Float, v) for k, v in par.items()}

        def pair(t: np.ndarray) -> np.ndarray:
            """(…, n) → (…, n, 2): value and slope to the next 1 nm sample."""
            return np.stack([t, np.diff(t, axis=-1, append=t[..., -1:])], axis=-1)

        tab.update(kdks=jit_table(m.Float, np.concatenate([pair(kd), pair(ks)], axis=-1)),
                   kb=jit_table(m.Float, pair(kb)), le=jit_table(m.Float, pair(le)),
                   n_fine=int(fine.size), has_kb=self.general_materials or bool(np.any(kb)),
                   dispersive=self.general_materials or bool(np.any(par["deta"])))
        return tab

    # ---- run-time constants (opaque: changing them never recompiles) ----------------------
    def _consts(self) -> SimpleNamespace:
        """The emitter's placement and the path depths as opaque JIT values."""
        dr, m = self.dr, self.m
        e = self.emitter
        ny, nx = self._map_shape

        def f(v: float) -> Any:
            return dr.opaque(m.Float, float(v))

        def u(v: int) -> Any:
            return dr.opaque(m.UInt32, int(v))

        return SimpleNamespace(
            em_slot=u(self.emitter_slot), max_depth=u(self.max_depth), rr_depth=u(self.rr_depth),
            em_x0=f(e.centre_m[0] - e.half_x_m), em_y0=f(e.centre_m[1] - e.half_y_m),
            em_sx=f(2.0 * e.half_x_m), em_sy=f(2.0 * e.half_y_m), em_z=f(e.centre_m[2]),
            em_area=f(e.area_m2), map_nx=u(nx), map_nxf=f(nx), map_nyf=f(ny))

    # ---- path pieces -------------------------------------------------------------------
    def _wavelength_offset(self, rng: Any) -> tuple[Any, Any, Any]:
        """A per-path offset δ ~ triangular(−step, step), shared by all bands: (δ, k, frac)
        with δ + step = k + frac, k the 1 nm table index and frac ∈ [0, 1]."""
        dr, m = self.dr, self.m
        step = self.grid.step_nm
        pos = step * (rng.next_float32() - rng.next_float32()) + step
        k = cell_index(dr, m, pos, 2.0 * step)
        return pos - step, k, pos - m.Float(k)

    def _lookup(self, tab: Mapping[str, Any], k: Any, frac: Any) -> BandLookup:
        """Spectra at λ_b + δ (δ + step = k + frac) from the interleaved (value, slope) tables:
        all bands at once (`BandLookup.__call__`) or band b alone (`BandLookup.band`)."""
        return BandLookup(self.dr, self.m, k, frac, tab["n_fine"], self.grid)

    def _radiometer_ray(self, rng: Any) -> Any:
        """A ray uniform over the radiometer's square field of view."""
        dr, m = self.dr, self.m
        f, left, up = self.radiometer.frame()

        def vec(v: Any) -> Any:       # opaque: another placement never recompiles
            return m.Vector3f(*(dr.opaque(m.Float, float(x)) for x in v))

        th = dr.opaque(m.Float, float(np.tan(np.deg2rad(self.radiometer.fov_deg) / 2.0)))
        u1 = (2.0 * rng.next_float32() - 1.0) * th
        u2 = (2.0 * rng.next_float32() - 1.0) * th
        d = dr.normalize(vec(f) + vec(left) * u1 + vec(up) * u2)
        return m.Ray3f(m.Point3f(vec(self.radiometer.origin_m)), d)

    def _em_factor(self, c: SimpleNamespace, x: Any, y: Any, active: Any) -> Any:
        """The emitter's spatial factor at a point of its plane (0 where not `active`; a
        non-finite point reads cell 0, never an arbitrary address)."""
        dr, m = self.dr, self.m
        i = cell_index(dr, m, (x - c.em_x0) / c.em_sx * c.map_nxf, c.map_nxf, active)
        j = cell_index(dr, m, (y - c.em_y0) / c.em_sy * c.map_nyf, c.map_nyf, active)
        return dr.gather(m.Float, self._factor_map, j * c.map_nx + i, active)

    def _offset(self, p: Any, n: Any) -> Any:
        """A ray origin just off the surface on the side of n."""
        dr = self.dr
        eps = 2e-5 * (1.0 + dr.max(dr.abs(p)))
        return p + n * eps

    def _intersect(self, c: SimpleNamespace, ray: Any, active: Any) -> SimpleNamespace:
        dr, m = self.dr, self.m
        pi = self.scene.ray_intersect_preliminary(ray, active=active)
        valid = active & pi.is_valid()
        reg = lane_index(dr, dr.reinterpret_array(m.UInt32, pi.shape), valid)
        slot = dr.gather(m.UInt32, self._shape_slot, reg, valid)
        fidx = lane_index(dr, dr.gather(m.UInt32, self._shape_base, reg, valid)
                          + pi.prim_index, valid)
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
        pdf_em = 1.0 / dr.fmax(self._rect_view(c, ray.o).solid_angle, 1e-30)
        w = dr.select(prev_pdf > 0, dr.square(prev_pdf)
                      / dr.fmax(dr.square(prev_pdf) + dr.square(pdf_em), 1e-30), 1.0)
        return dr.select(hit_em, self._em_factor(c, hit.p.x, hit.p.y, hit_em) * w, 0.0)

    def _frame(self, hit: SimpleNamespace, ray: Any) -> tuple[Any, Any, Any]:
        """Local frame at a hit with the normal towards the incoming side (two-sided
        surfaces): (frame, local wi, origin of rays leaving it)."""
        dr, m = self.dr, self.m
        wi_w = -ray.d
        nf = dr.select(dr.dot(wi_w, hit.ng) < 0, -hit.ng, hit.ng)
        frame = m.Frame3f(nf)
        return frame, frame.to_local(wi_w), self._offset(hit.p, nf)

    def _vertex(self, tab: Mapping[str, Any], lookup: BandLookup, delta: Any, slot: Any,
                wi: Any, active: Any, *, spectra: bool = True) -> SimpleNamespace:
        """The material of `slot` at a vertex with local incoming direction wi (the `vx` of
        `_band_factors` / `_sample`).  With `spectra`, kd, ks (and kb) of every band as lists;
        without, only what `_band_spectra` needs to gather band b inside a band loop."""
        dr, m = self.dr, self.m
        has_kb, dispersive = tab["has_kb"], tab["dispersive"]
        kd = ks = kb = None
        if spectra:
            kd, ks = lookup(tab["kdks"], slot, active, 4)
            kb = lookup(tab["kb"], slot, active, 2)[0] if has_kb else None
        return SimpleNamespace(
            wi=wi, alpha=dr.gather(m.Float, tab["alpha"], slot, active),
            eta=dr.gather(m.Float, tab["eta"], slot, active),
            c=dr.gather(m.Float, tab["c"], slot, active),
            p_spec=dr.gather(m.Float, tab["p_spec"], slot, active), kd=kd, ks=ks, kb=kb,
            inv_s2=dr.gather(m.Float, tab["inv_sigma2"], slot, active) if has_kb else None,
            deta=dr.gather(m.Float, tab["deta"], slot, active) if dispersive else None,
            delta=delta, slot=slot, mask=active, has_kb=has_kb, dispersive=dispersive)

    def _band_lam(self, b: Any, delta: Any) -> Any:
        """λ_b + δ − 550 nm (the dispersive η's argument) of band b, a UInt32 band-loop
        counter."""
        dr, m = self.dr, self.m
        lam0 = float(self.grid.centres_nm[0]) - 550.0
        return dr.fma(m.Float(b), float(self.grid.step_nm), lam0) + delta

    def _band_spectra(self, tab: Mapping[str, Any], lookup: BandLookup, vx: SimpleNamespace,
                      b: Any) -> tuple[Any, Any, Any]:
        """kd, ks and kb (None without a backscatter lobe) of band b (UInt32) at vertex `vx`."""
        kd, ks = lookup.band(tab["kdks"], vx.slot, vx.mask, 4, b)
        kb = lookup.band(tab["kb"], vx.slot, vx.mask, 2, b)[0] if vx.has_kb else None
        return kd, ks, kb

    def _rect_view(self, c: SimpleNamespace, o: Any) -> SimpleNamespace:
        """The emitter as a spherical rectangle seen from o (below its plane; Ureña, Fajardo
        and King, "An area-preserving parametrization for spherical rectangles", 2013, in the
        form of pbrt-v4's SampleSphericalRectangle): the rectangle in o's frame (x, y along
        the world's, z pointing away from the emitter's plane), its edge normals' z and inner
        angles, and its solid angle (0 where o is not below the plane)."""
        dr, m = self.dr, self.m
        x0 = c.em_x0 - o.x
        y0 = c.em_y0 - o.y
        z0 = dr.minimum(o.z - c.em_z, 0.0)             # ≤ 0: the flipped frame's z
        x1, y1 = x0 + c.em_sx, y0 + c.em_sy
        v00, v01 = m.Vector3f(x0, y0, z0), m.Vector3f(x0, y1, z0)
        v10, v11 = m.Vector3f(x1, y0, z0), m.Vector3f(x1, y1, z0)
        n0 = dr.normalize(dr.cross(v00, v10))
        n1 = dr.normalize(dr.cross(v10, v11))
        n2 = dr.normalize(dr.cross(v11, v01))
        n3 = dr.normalize(dr.cross(v01, v00))

        def angle(a: Any, b: Any) -> Any:               # the angle between unit vectors
            return dr.select(dr.dot(a, b) < 0, dr.pi - 2.0 * dr.safe_asin(dr.norm(a + b) / 2.0),
                             2.0 * dr.safe_asin(dr.norm(b - a) / 2.0))

        g0, g1, g2, g3 = angle(-n0, n1), angle(-n1, n2), angle(-n2, n3), angle(-n3, n0)
        sa = g0 + g1 + g2 + g3 - 2.0 * dr.pi
        sa = dr.select((z0 < 0) & dr.isfinite(sa), dr.fmax(sa, 0.0), 0.0)
        return SimpleNamespace(x0=x0, y0=y0, x1=x1, y1=y1, z0=z0, b0=n0.z, b1=n2.z, g0=g0,
                               g1=g1, g2=g2, g3=g3, solid_angle=sa)

    def _light_sample(self, c: SimpleNamespace, frame: Any, o: Any, rng: Any,
                      active: Any) -> tuple[Any, Any, Any, Any]:
        """A point of the emitter uniform in the solid angle it subtends at o (spherical
        rectangle sampling: no 1/r² weight near the panel, e.g. on the aperture's sides), with
        a shadow ray: (local wo, emitter factor / pdf (solid angle), pdf, mask of unoccluded
        front-facing samples)."""
        dr, m = self.dr, self.m
        u0, u1 = rng.next_float32(), rng.next_float32()
        q = self._rect_view(c, o)
        sa = q.solid_angle
        au = u0 * (q.g0 + q.g1 - 2.0 * dr.pi) + (u0 - 1.0) * (q.g2 + q.g3)
        fu = (dr.cos(au) * q.b0 - q.b1) / dr.sin(au)
        cu = dr.copysign(dr.rsqrt(fu * fu + q.b0 * q.b0), fu)
        cu = dr.clip(cu, -0.99999994, 0.99999994)
        xu = dr.clip(-(cu * q.z0) * dr.rsqrt(dr.fmax(1.0 - cu * cu, 1e-30)), q.x0, q.x1)
        dd = dr.sqrt(xu * xu + q.z0 * q.z0)
        h0 = q.y0 * dr.rsqrt(dd * dd + q.y0 * q.y0)
        h1 = q.y1 * dr.rsqrt(dd * dd + q.y1 * q.y1)
        hv = h0 + u1 * (h1 - h0)
        yv = dr.select(hv * hv < 1.0 - 1e-4, hv * dd * dr.rsqrt(dr.fmax(1.0 - hv * hv, 1e-30)),
                       q.y1)
        yv = dr.clip(yv, q.y0, q.y1)
        lx, ly = o.x + xu, o.y + yv
        to_l = m.Vector3f(lx, ly, c.em_z) - o
        dist = dr.norm(to_l)
        dl = to_l / dr.fmax(dist, 1e-30)
        shadow = m.Ray3f(o, dl)
        shadow.maxt = dist * (1.0 - 1e-4)
        ok = active & (dl.z > 0) & (sa > 1e-7) & dr.isfinite(lx) & dr.isfinite(ly)
        ok = ok & ~self.scene.ray_test(shadow, ok)
        pdf_l = 1.0 / dr.fmax(sa, 1e-30)
        em_w = dr.select(ok, self._em_factor(c, lx, ly, ok) * sa, 0.0)
        return frame.to_local(dl), em_w, pdf_l, ok

    def _guide_at(self, o: Any, frame: Any) -> Any:
        """The guide (`guide.GuideKernel`) at the vertex o, or None without one."""
        if self.guide is None:
            return None
        return GuideKernel(self.m, self.dr, self.guide, o, frame.n)

    def _direction_pdf(self, vx: Any, wo: Any, guide: Any, frame: Any) -> Any:
        """The pdf of the local direction wo under the vertex's sampling (BSDF mixture, and
        the guide with probability `GUIDE_SHARE` when there is one)."""
        bpdf = self._pdf(vx.wi, wo, vx.alpha, vx.p_spec)
        return bpdf if guide is None else guide.mixture_pdf(bpdf, frame.to_world(wo))

    def _nee(self, c: SimpleNamespace, vx: SimpleNamespace, frame: Any, o: Any, rng: Any,
             active: Any, guide: Any = None) -> tuple[Any, Any, Any]:
        """Next-event estimation at a vertex: (local wo, weight without the BRDF — emitter
        factor · MIS · cos / pdf —, mask)."""
        dr = self.dr
        wo, em_w, pdf_l, ok = self._light_sample(c, frame, o, rng, active)
        bpdf = self._direction_pdf(vx, wo, guide, frame)
        mis = dr.square(pdf_l) / dr.fmax(dr.square(pdf_l) + dr.square(bpdf), 1e-30)
        return wo, em_w * mis * wo.z, ok

    # ---- the path loop -----------------------------------------------------------------
    def _path_loop(self, tab: Mapping[str, Any], c: SimpleNamespace, lookup: BandLookup,
                   delta: Any, ray: Any, active: Any, depth: Any, prev_pdf: Any, rng: Any, *,
                   probe_scale: Any = None, split_first: bool = False,
                   patches: SimpleNamespace | None = None,
                   first_draws: Sequence[Any] | None = None) -> SimpleNamespace:
        """Trace from `ray` (path vertex number `depth`, previous BSDF pdf `prev_pdf`, 0 for a
        camera ray) with throughput 1 until every path has ended.  Returns `acc` (per band,
        Σ throughput · emitter factor; the lamp spectrum is the caller's), and:

        - `split_first`: `e1`, the emitter found at vertex 1 (kept out of `acc`; the camera's
          layers need it apart);
        - `patches` (slot: the patch slot, base: first extra slot of `_tables`, count: P): the
          patch stands for P materials.  A path that hits it picks one, p* uniformly at random,
          with weight P, and uses p*'s material there and at every later patch hit; everything
          it finds afterwards goes to `late` (per band) for patch p* alone.  Unbiased for every
          patch: E[P · 1{p* = p} · X_p] = E[X_p].
        `probe_scale` multiplies the Russian-roulette probe (the throughput before `ray`).
        `first_draws` (`FIRST_BOUNCE_DRAWS`: the patch pick when `patches`, the light sample, the
        direction): uniform numbers that replace the generator's in the first bounce (the
        caller's quasi-random ones); the generator advances the same either way.

        One symbolic loop over the bounces (a SIMD packet runs until its own longest path
        ends) holds one symbolic loop over the bands: the per-band throughput and sums live in
        per-lane local arrays (`dr.alloc_local`), so the kernel holds one band's code, not 81
        copies of it (a kernel's LLVM compile time grows with its size)."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        pp = patches
        none = 0xFFFFFFFF
        # opaque: with a literal trip count LLVM unrolls the band loop 81 times and compiles
        # as long as without the loop
        n_bands = dr.opaque(m.UInt32, n_b)

        def bands(thr: Any, acc: Any, late: Any, vx: SimpleNamespace, e_w: Any,
                  nee: SimpleNamespace, smp: SimpleNamespace, late_e: Any,
                  late_n: Any) -> Any:
            """For every band b: acc_b += thr_b·(e_w + f_b(NEE)), thr_b ·= f_b(sample); with
            `patches`, the emission's share late_e and the NEE's share late_n go to late_b
            instead.  Returns the roulette probe max |thr_b| over bands 0, 8, 16, …"""

            def body(b: Any, probe: Any, thr: Any, acc: Any, late: Any) -> tuple[Any, ...]:
                kd, ks, kb = self._band_spectra(tab, lookup, vx, b)
                lam = self._band_lam(b, delta)
                t = thr.read(b)
                fn = self._band_factor(vx, nee, kd, ks, kb, lam)
                if pp is not None:
                    ge, gn = t * e_w, t * fn
                    late.write(dr.fma(gn, late_n, dr.fma(ge, late_e, late.read(b))), b)
                    acc.write(dr.fma(gn, 1.0 - late_n, dr.fma(ge, 1.0 - late_e, acc.read(b))),
                              b)
                else:
                    acc.write(dr.fma(t, e_w + fn, acc.read(b)), b)
                t = t * self._band_factor(vx, smp, kd, ks, kb, lam)
                thr.write(t, b)
                probe = dr.select((b & 7) == 0, dr.fmax(probe, dr.abs(t)), probe)
                return b + 1, probe, thr, acc, late

            state = dr.while_loop((m.UInt32(0), m.Float(0.0), thr, acc, late),
                                  lambda b, *_: b < n_bands, body, label="bands")
            return state[1]

        def bounce(depth: Any, active: Any, ray: Any, prev_pdf: Any, rng: Any, w: Any,
                   thr: Any, acc: Any, e1: Any, late: Any, pstar: Any) -> tuple[Any, ...]:
            src = rng if first_draws is None else FirstBounceDraws(
                rng, depth == start_depth, first_draws[0 if pp is not None else 1:])
            hit = self._intersect(c, ray, active)
            e = self._emission(c, hit, ray, prev_pdf)
            if split_first:
                first = depth == 1
                e1 = e1 + dr.select(first, e, 0.0)
                e = dr.select(first, 0.0, e)
            slot = hit.slot
            late_e = late_n = None
            sel_w = 1.0
            if pp is not None:
                late_e = dr.select(pstar != none, 1.0, 0.0)   # the emission: the p* before
                on_patch = hit.surf & (slot == pp.slot)
                u = src.next_float32()
                pick = on_patch & (pstar == none)
                pstar = dr.select(pick, cell_index(dr, m, u * pp.count_f, pp.count_f), pstar)
                sel_w = dr.select(pick, pp.count_f, 1.0)
                slot = dr.select(on_patch, pp.base + pstar, slot)
                late_n = dr.select(pstar != none, 1.0, 0.0)   # the NEE: the p* after the pick
            active = hit.surf & (depth + 1 < c.max_depth)
            frame, wi, o = self._frame(hit, ray)
            vx = self._vertex(tab, lookup, delta, slot, wi, active, spectra=False)
            guide = self._guide_at(o, frame)
            wl, wt, ok = self._nee(c, vx, frame, o, src, active, guide)
            nee = self._brdf_terms(vx, wl, w * wt * sel_w, ok)
            wo, bpdf, active = self._sample(vx, src, active, guide, frame)
            if first_draws is not None and src.values:
                raise AssertionError("first_draws does not match the first bounce's draws")
            smp = self._brdf_terms(vx, wo, wo.z / dr.fmax(bpdf, 1e-30) * sel_w, active)
            probe = w * bands(thr, acc, late, vx, w * e, nee, smp, late_e, late_n)
            # Russian roulette on a λ-independent survival probability (bands 0, 8, 16, …)
            if probe_scale is not None:
                probe = probe * probe_scale
            q = dr.select(depth + 1 >= c.rr_depth, dr.minimum(probe, 0.95), 1.0)
            active = active & (rng.next_float32() < q)
            w = w * dr.select(active, 1.0 / dr.fmax(q, 1e-12), 0.0)
            return (depth + 1, active, m.Ray3f(o, frame.to_world(wo)), bpdf, rng, w, thr, acc,
                    e1, late, pstar)

        start_depth = m.UInt32(depth)
        state = (m.UInt32(depth), m.Bool(active), ray, m.Float(prev_pdf), rng,
                 m.Float(1.0),                             # λ-independent path weight w
                 dr.alloc_local(m.Float, n_b, m.Float(1.0)),   # thr_b / w
                 dr.alloc_local(m.Float, n_b, m.Float(0.0)),   # Σ throughput · emitter
                 m.Float(0.0),                             # e1 (split_first)
                 dr.alloc_local(m.Float, n_b if pp is not None else 1, m.Float(0.0)),
                 m.UInt32(none) if pp is not None else m.UInt32(0))
        state = dr.while_loop(state, lambda depth, active, *_: active & (depth < c.max_depth),
                              bounce, label="bandpath")
        return SimpleNamespace(acc=state[7], e1=state[8],
                               late=state[9] if pp is not None else None, pstar=state[10])

    def _band_rows(self, n: int, arrays: Sequence[Any],
                   lamp: tuple[Mapping[str, Any], BandLookup] | None = None) -> list[Any]:
        """Each per-lane local array of `_path_loop` (`acc`, `late`) as one flat Float of
        n_bands rows × n lanes (row b: band b, times the lamp spectrum L_b(λ_b + δ) with
        `lamp` = (tables, lookup)), written by a band loop: the kernel holds one band's code."""
        dr, m = self.dr, self.m
        n_bands = dr.opaque(m.UInt32, self.grid.n_bands)
        n_lanes = dr.opaque(m.UInt32, int(n))
        lane = dr.arange(m.UInt32, int(n))
        rows = [dr.empty(m.Float, self.grid.n_bands * int(n)) for _ in arrays]

        def body(b: Any, *arrays: Any) -> tuple[Any, ...]:
            scale = 1.0
            if lamp is not None:
                tab, lookup = lamp
                scale = lookup.band(tab["le"], m.UInt32(0), m.Bool(True), 2, b)[0]
            for local, row in zip(arrays, rows, strict=True):
                dr.scatter(row, local.read(b) * scale, b * n_lanes + lane)
            return (b + 1, *arrays)

        dr.while_loop((m.UInt32(0), *arrays), lambda b, *_: b < n_bands, body, label="rows")
        return rows

    # ---- one chunk of radiometer paths ---------------------------------------------------
    def _trace(self, tab: Mapping[str, Any], n: int, seed: int) -> np.ndarray:
        """Trace n radiometer paths; returns (n_bands, n) float64 per-path radiance estimates."""
        dr, m = self.dr, self.m
        n_b = self.grid.n_bands
        c = self._consts()
        rng = lane_rng(m, dr, seed, dr.arange(m.UInt32, n))
        delta, k, frac = self._wavelength_offset(rng)
        lookup = self._lookup(tab, k, frac)
        ray = self._radiometer_ray(rng)
        res = self._path_loop(tab, c, lookup, delta, ray, m.Bool(True), m.UInt32(0),
                              m.Float(0.0), rng)
        rows = self._band_rows(n, [res.acc], (tab, lookup))[0]
        dr.eval(rows)
        return require_finite(np.asarray(rows, dtype=np.float64).reshape(n_b, n),
                              f"band path tracer ({self.variant}), seed {seed}")

    def _brdf_terms(self, vx: Any, wo: Any, weight: Any, mask: Any) -> SimpleNamespace:
        """The per-path parts of weight · f_b(wi, wo) at vertex `vx` (weight includes the
        cosine): f_b·weight = kd_b·a + ks_b·F_b·s + kb_b·k − c (`_band_factor`); all 0 where not
        `mask` (selects, never multiplications by 0, so NaNs cannot leak)."""
        dr = self.dr
        wi, alpha = vx.wi, vx.alpha
        h = dr.normalize(wi + wo)
        a2 = alpha * alpha
        dist = ggx_d(a2, h.z)
        valid = mask & (wi.z > 0) & (wo.z > 0)
        geo = (dist * smith_g1(a2, wi.z) * smith_g1(a2, wo.z)
               / (4.0 * dr.select(valid, wi.z * wo.z, 1.0)))
        cb = dr.clip(dr.dot(wi, h), 0.0, 1.0)
        s_ = weight * geo
        if vx.deta is None:
            s_ = s_ * fresnel(vx.eta, cb)
        k_ = None
        if vx.inv_s2 is not None:
            k_ = dr.select(valid, weight * INV_PI * dr.exp((dr.dot(wi, wo) - 1.0) * vx.inv_s2),
                           0.0)
        return SimpleNamespace(valid=valid, cb=cb, a=dr.select(valid, weight * INV_PI, 0.0),
                               c=dr.select(valid, weight * vx.c, 0.0),
                               s=dr.select(valid, s_, 0.0), k=k_)

    def _band_factor(self, vx: Any, t: SimpleNamespace, kd: Any, ks: Any, kb: Any,
                     lam_nm: Any) -> Any:
        """weight · f_b for one band from the vertex's terms `t` (`_brdf_terms`), the band's
        kd, ks, kb and its wavelength λ_b + δ − 550 nm (used only by a dispersive η): the
        diffuse part plus the angular lobes."""
        return self._angular_factor(vx, t, ks, kb, lam_nm, self._diffuse_factor(t, kd))

    def _diffuse_factor(self, t: SimpleNamespace, kd: Any) -> Any:
        """The angle-independent part of weight · f_b: kd_b·a − c."""
        return self.dr.fma(kd, t.a, -t.c)

    def _angular_factor(self, vx: Any, t: SimpleNamespace, ks: Any, kb: Any, lam_nm: Any,
                        base: Any = 0.0) -> Any:
        """base + the angular lobes of weight · f_b: ks_b·F_b·s (+ kb_b·k with a backscatter
        lobe)."""
        dr = self.dr
        if vx.deta is not None:
            # select, not multiply: F is NaN where cb = 0 (g = 0), outside `valid`
            f_b = dr.select(t.valid, fresnel(dr.fma(vx.deta, lam_nm, vx.eta), t.cb), 0.0)
            fb = dr.fma(ks * f_b, t.s, base)
        else:
            fb = dr.fma(ks, t.s, base)
        if t.k is not None:
            fb = dr.fma(kb, t.k, fb)
        return fb

    def _band_factors(self, vx: Any, wo: Any, weight: Any, mask: Any) -> list[Any]:
        """weight · f_b(wi, wo) for every band at vertex `vx` (its spectra as lists)."""
        t = self._brdf_terms(vx, wo, weight, mask)
        out = []
        for b in range(self.grid.n_bands):
            lam = (float(self.grid.centres_nm[b]) - 550.0) + vx.delta
            out.append(self._band_factor(vx, t, vx.kd[b], vx.ks[b],
                                         vx.kb[b] if t.k is not None else None, lam))
        return out

    def _sample(self, vx: Any, rng: Any, active: Any, guide: Any = None,
                frame: Any = None) -> tuple[Any, Any, Any]:
        """Cosine or GGX (D·cos θh) direction by a λ-independent coin at vertex `vx` (wi, alpha,
        p_spec), or with probability `GUIDE_SHARE` a point of the `guide`: (local wo, its pdf,
        `active` where wo is usable).  Three random numbers either way: the coin's picks the
        technique and, rescaled, the lobe or the guide's rectangle."""
        dr = self.dr
        if guide is None:
            wo = self._sample_direction(vx.wi, vx.alpha, vx.p_spec, rng)
        else:
            uc, ux, uy = rng.next_float32(), rng.next_float32(), rng.next_float32()
            guided = uc < GUIDE_SHARE
            u_lobe = dr.clip((uc - GUIDE_SHARE) / (1.0 - GUIDE_SHARE), 0.0, 1.0)
            wo = dr.select(guided,
                           frame.to_local(guide.sample(uc / GUIDE_SHARE, ux, uy)),
                           self._direction(vx.wi, vx.alpha, vx.p_spec, u_lobe, ux, uy))
        bpdf = self._direction_pdf(vx, wo, guide, frame)
        return wo, bpdf, active & (wo.z > 0) & (bpdf > 0)

    def _sample_direction(self, wi: Any, alpha: Any, p_spec: Any, rng: Any) -> Any:
        """A local direction: GGX (D·cos θh, roughness alpha) with probability p_spec, else
        cosine-weighted; three random numbers, drawn whatever the branch."""
        uc = rng.next_float32()
        ux = rng.next_float32()
        return self._direction(wi, alpha, p_spec, uc, ux, rng.next_float32())

    def _direction(self, wi: Any, alpha: Any, p_spec: Any, uc: Any, ux: Any, uy: Any) -> Any:
        """`_sample_direction` from its three uniform numbers."""
        dr, m = self.dr, self.m
        us = m.Point2f(ux, uy)
        wo_cos = m.warp.square_to_cosine_hemisphere(us)
        t2 = alpha * alpha * us.x / dr.fmax(1.0 - us.x, 1e-7)
        cth = dr.rsqrt(1.0 + t2)
        sth = dr.safe_sqrt(1.0 - cth * cth)
        phi = 2.0 * dr.pi * us.y
        hh = m.Vector3f(sth * dr.cos(phi), sth * dr.sin(phi), cth)
        wo_spec = 2.0 * dr.dot(wi, hh) * hh - wi
        return dr.select(uc < p_spec, wo_spec, wo_cos)

    def _pdf(self, wi: Any, wo: Any, alpha: Any, p_spec: Any) -> Any:
        """Solid-angle pdf of the cosine + GGX(D·cos θh) mixture for the outgoing wo."""
        dr = self.dr
        h = dr.normalize(wi + wo)
        pdf_h = ggx_d(alpha * alpha, h.z) * h.z
        woh = dr.abs(dr.dot(wo, h))
        pdf_spec = dr.select(woh > 0, pdf_h / (4.0 * dr.fmax(woh, 1e-12)), 0.0)
        pdf_cos = dr.fmax(wo.z, 0.0) * INV_PI
        return dr.select(wo.z > 0, p_spec * pdf_spec + (1.0 - p_spec) * pdf_cos, 0.0)

    # ---- public ------------------------------------------------------------------------
    def render(self, materials: Mapping[str, Any], emitter_wavelength_nm: Any,
               emitter_radiance: Any, *, n_paths: int | None = None,
               target_rel_se: float | None = None, seed: int = 0,
               max_paths: int = 1 << 23, pilot_paths: int = 1 << 14) -> BandEstimate:
        """Radiance per band seen by the radiometer, with its standard error.

        Either a fixed `n_paths`, or `target_rel_se` (the largest relative standard error over
        the bands with signal, `max_rel_se`): a pilot estimates the per-path variance, then paths
        are added until the target is met (or `max_paths`).  Deterministic for a given seed.
        """
        if n_paths is None and target_rel_se is None:
            raise ValueError("give n_paths or target_rel_se")
        t0 = time.perf_counter()
        tab = self._tables(materials, emitter_wavelength_nm, emitter_radiance)
        n_b = self.grid.n_bands
        s1 = np.zeros(n_b)
        s2 = np.zeros(n_b)
        done = 0
        chunk_no = 0
        goal = int(n_paths) if n_paths is not None else min(int(pilot_paths), int(max_paths))
        while True:
            while done < goal:
                n = min(self.chunk_paths, goal - done)
                vals = self._trace(tab, n, seed=chunk_seed(seed, chunk_no))
                chunk_no += 1
                s1 += vals.sum(axis=1)
                s2 += np.einsum("ij,ij->i", vals, vals)
                done += n
            mean = s1 / done
            var = np.maximum(s2 / done - mean * mean, 0.0) * done / max(done - 1, 1)
            se = np.sqrt(var / done)
            if target_rel_se is None:
                break
            rel = max_rel_se(mean, se)
            if rel <= target_rel_se or done >= max_paths:
                break
            need = int(np.ceil(done * (rel / target_rel_se) ** 2 * 1.05))
            goal = min(int(max_paths), max(need, done + 1024))
        return BandEstimate(self.grid.centres_nm, mean, se, done, time.perf_counter() - t0)


def ggx_d(a2: Any, cos_h: Any) -> Any:
    """GGX normal distribution D(h) for α² = a2 at cos θh (0 for a back-facing h; Dr.Jit)."""
    import drjit as dr

    dd = cos_h * cos_h * (a2 - 1.0) + 1.0
    return dr.select(cos_h > 0, a2 / (dr.pi * dd * dd), 0.0)


def smith_g1(a2: Any, cos_theta: Any) -> Any:
    """Smith G1 of GGX for α² = a2 at cos θ (Dr.Jit)."""
    import drjit as dr

    c2 = dr.clip(cos_theta * cos_theta, 1e-12, 1.0)
    return 2.0 / (1.0 + dr.sqrt(1.0 + a2 * (1.0 - c2) / c2))


def fresnel(eta: Any, cos_beta: Any) -> Any:
    """Cook-Torrance unpolarised dielectric Fresnel (Dr.Jit; as `brdf_model`)."""
    import drjit as dr

    g = dr.sqrt(dr.fmax(eta * eta - 1.0 + cos_beta * cos_beta, 0.0))
    a = (g - cos_beta) / (g + cos_beta)
    b = (cos_beta * (g + cos_beta) - 1.0) / (cos_beta * (g - cos_beta) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def specular_probability(material: Any) -> float:
    """Share of GGX direction sampling for a material: 0 without ks, else 0.15…0.5 growing with
    ks/(ks+kd) and smoothness (only efficiency depends on it, never the expected value)."""
    ks = float(np.mean(np.abs(material.ks)))
    if ks <= 0.0:
        return 0.0
    kd = float(np.mean(np.abs(material.kd)))
    return float(min(0.5, max(0.15, 0.25 / max(float(material.alpha), 0.1) * ks / (ks + kd))))
