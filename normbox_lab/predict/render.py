"""Spectral rendering of the Normbox radiometer view with Mitsuba 3, with error bars and a cache.

    result = render_view(geometry, patch=truth_patch(19), wall=truth_wall(), angle_deg=30)
    result.wavelength_nm, result.radiance, result.std_error     # W·sr⁻¹·m⁻²·nm⁻¹ per band

- Spectral grid: triangular bands (5 nm apart, half-width 5 nm) centred at 380…780 nm; a
  band value is the radiance at its centre, smoothed by the 5 nm hat (the radiometer's own
  bandwidth is similar).  `to_1nm()` interpolates linearly to 380…780 step 1.
- Monte-Carlo standard error: the view is rendered in `batches` independent batches (different
  seeds); the result is their mean and the standard error of the mean, per band.
- Quality levels (`QUALITIES`): the batch plan (samples per pixel per batch, first and last
  batch count) of "quick" (tests, sub-second), "default" (the campaign) and "high"; the
  precision is one quantity (`normbox_lab.predict.precision`): batches are added until the
  worst band's relative standard error is at most the target (the quality's preset, or
  `render_view(target_rel_se=…)`), up to the batch cap; `info` states what was reached.
- `max_depth`: the full render uses paths of up to 12 segments (Russian roulette after 6);
  `direct_only=True` renders max_depth = 2 (emitter → surface → radiometer: the direct light).
- Cache: results are .npz files under `cache_dir` (default `.cache/normbox-render/` in the
  working directory, or $NORMBOX_RENDER_CACHE), keyed by a hash of the materials, the patch
  material, the angle, the lamp, the geometry, the quality and the code version.
- Variants: `llvm_ad_spectral` by default, `cuda_ad_spectral` when a GPU works,
  `scalar_spectral` when llvm cannot be loaded (see `normbox_lab.predict.mitsuba_setup`); force one with
  $NORMBOX_MITSUBA_VARIANT.  Mitsuba is imported on the first render, never at module import.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.core.spectral import BAND_WAVELENGTHS_NM, RADIOMETER_WAVELENGTHS_NM
from normbox_lab.predict.kernel_safety import require_finite
from normbox_lab.predict.materials import Material, holder_material
from normbox_lab.predict.precision import PRESETS, STATISTIC, rel_se
from normbox_lab.predict.scene import (
    MOVING_SHAPES,
    as_geometry,
    band_film,
    moving_transforms,
    panel_map,
    scene_dict,
)

#: bump when the scene code changes what a render returns (invalidates every cache entry)
RENDER_VERSION = 4
BAND_CENTRES_NM = BAND_WAVELENGTHS_NM
BAND_WIDTH_NM = 5.0
LAMP_GRID_NM = np.arange(360.0, 831.0, 5.0)
KM_LM_W = 683.002


@dataclass(frozen=True)
class Quality:
    name: str
    spp: int            # samples per pixel per batch (10 × 10 pixels); a square number
                        # (kept square: the counts of earlier stratified renders)
    batches: int
    pixels: int = 10
    # adaptive: after `batches`, keep adding batches (up to `max_batches`) until the worst
    # band's relative standard error (`precision.rel_se`) is ≤ `target_rel_se`
    # (0 = fixed batch count)
    max_batches: int = 0
    target_rel_se: float = 0.0


#: the most batches a render with a stated `target_rel_se` takes (the `independent` sampler's
#: band SE per batch is 1.2-1.75x the former stratified one's: 20 batches no longer reach 0.5 %)
TARGET_MAX_BATCHES = 64

QUALITIES = {
    "quick": Quality("quick", spp=16, batches=4),
    "default": Quality("default", spp=256, batches=8, max_batches=20,
                       target_rel_se=PRESETS["default"]),
    "high": Quality("high", spp=1024, batches=16),
}


# --- the light ----------------------------------------------------------------------------------
def planck_W_sr_m2_nm(wavelength_nm: Any, temperature_K: float) -> np.ndarray:
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    wl = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    return 2 * h * c * c / wl ** 5 / np.expm1(h * c / (wl * k * temperature_K)) * 1e-9


def photopic_v(wavelength_nm: Any) -> np.ndarray:
    """CIE 1924 photopic V(λ) from colour-science (cached on disk: colour imports slowly)."""
    from normbox_lab.predict.materials import _cache_dir

    path = _cache_dir() / "cie1924_photopic_360_830_1nm.npy"
    try:
        v = np.load(path)
    except (OSError, ValueError):
        import colour

        sd = colour.SDS_LEFS["CIE 1924 Photopic Standard Observer"]
        v = np.interp(np.arange(360.0, 831.0), sd.wavelengths, sd.values)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, v)
        except OSError:
            pass
    return np.interp(np.asarray(wavelength_nm, dtype=np.float64), np.arange(360.0, 831.0), v,
                     left=0.0, right=0.0)


def luminance_cd_m2(wavelength_nm: Any, radiance: Any) -> float:
    """683 · ∫ L(λ) V(λ) dλ (trapezoid on the given grid)."""
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    return KM_LM_W * float(np.trapezoid(np.asarray(radiance) * photopic_v(wl), wl))


@dataclass(frozen=True)
class Lamp:
    """The sphere's opal panel: a Planckian (tungsten-halogen) spectrum at `cct_K`, scaled so the
    panel's mean luminance is `luminance_cd_m2`; `relative_output` scales it (sphere dimming).
    The spatial 5×5 map (±homogeneity) comes from the geometry (`scene.panel_map`)."""

    cct_K: float = 3100.0
    luminance_cd_m2: float = 3000.0
    relative_output: float = 1.0

    def radiance(self, wavelength_nm: Any) -> np.ndarray:
        """Mean panel spectral radiance (W·sr⁻¹·m⁻²·nm⁻¹)."""
        grid = np.arange(360.0, 831.0)
        p = planck_W_sr_m2_nm(grid, self.cct_K)
        scale = self.luminance_cd_m2 / luminance_cd_m2(grid, p) * self.relative_output
        return planck_W_sr_m2_nm(wavelength_nm, self.cct_K) * scale

    def key(self) -> dict[str, float]:
        return asdict(self)


# --- results ------------------------------------------------------------------------------------
@dataclass
class RenderResult:
    wavelength_nm: np.ndarray       # band centres
    radiance: np.ndarray            # W·sr⁻¹·m⁻²·nm⁻¹, mean over batches
    std_error: np.ndarray           # standard error of the mean, same unit
    batches: np.ndarray             # (n_batches, n_bands)
    render_time_s: float
    variant: str
    key: str
    cached: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def relative_std_error(self) -> np.ndarray:
        return self.std_error / np.maximum(np.abs(self.radiance), 1e-300)

    def to_1nm(self, wavelength_nm: Any = None) -> tuple[np.ndarray, np.ndarray]:
        wl = RADIOMETER_WAVELENGTHS_NM.copy() if wavelength_nm is None else np.asarray(wavelength_nm)
        return wl, np.interp(wl, self.wavelength_nm, self.radiance)

    def scaled(self, factor: float) -> RenderResult:
        return RenderResult(self.wavelength_nm, self.radiance * factor, self.std_error * factor,
                            self.batches * factor, self.render_time_s, self.variant, self.key,
                            self.cached, dict(self.info))


# --- variant and cache --------------------------------------------------------------------------
_LOCK = threading.Lock()
_VARIANT: str | None = None


def ensure_variant(variant: str | None = None) -> str:
    """Import Mitsuba and make `variant` (None: this machine's best spectral variant, probed
    once per process) the active one; Mitsuba's variant is process-global, so this is called
    before every render."""
    global _VARIANT
    import mitsuba as mi

    if variant is None:
        if _VARIANT is None:
            from normbox_lab.predict.mitsuba_setup import choose_variant

            _VARIANT = choose_variant()
        variant = _VARIANT
    if mi.variant() != variant:
        mi.set_variant(variant)
    if variant.startswith("llvm"):
        from normbox_lab.predict.mitsuba_setup import apply_llvm_target

        apply_llvm_target()
    return variant


def default_cache_dir() -> Path:
    env = os.environ.get("NORMBOX_RENDER_CACHE")
    return Path(env) if env else Path.cwd() / ".cache" / "normbox-render"


def render_key(geometry: Any, patch: Material, wall: Material, holder: Material,
               angle_deg: float, lamp: Lamp, quality: Quality, max_depth: int,
               seed: int) -> str:
    g = as_geometry(geometry)
    lamp_key = lamp.key()
    lamp_key.pop("relative_output")      # radiance scales linearly with it: applied afterwards
    payload = {"v": RENDER_VERSION, "geometry": asdict(g), "patch": patch.digest(),
               "wall": wall.digest(), "holder": holder.digest(),
               "angle_deg": round(float(angle_deg), 6), "lamp": lamp_key,
               "panel_map": np.round(panel_map(g.panel_homogeneity_percent), 9).tolist(),
               "quality": asdict(quality), "max_depth": int(max_depth), "seed": int(seed),
               "bands": [float(BAND_CENTRES_NM[0]), float(BAND_CENTRES_NM[-1]), BAND_WIDTH_NM]}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def _load_cached(path: Path) -> RenderResult | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            info = json.loads(str(z["info"]))
            return RenderResult(z["wavelength_nm"], z["radiance"], z["std_error"], z["batches"],
                                float(z["render_time_s"]), str(z["variant"]), str(z["key"]),
                                cached=True, info=info)
    except (OSError, KeyError, ValueError):
        return None


def cached_render(path: Path, compute: Any, load: Any = None, save: Any = None) -> Any:
    """The render kept at `path`, or `compute()`'s result, saved there (`load(path)` → the
    result or None, `save(path, result)`: by default a `RenderResult` in `render`'s .npz
    format).  The look-up and the render hold an exclusive lock on ``<path>.lock``: two
    processes that want the same render (the demo and its ahead-rendering child,
    `demo_prewarm`) trace it once, and the second one reads what the first one saved.  The
    lock goes with its process (a killed renderer never blocks the other)."""
    import fcntl

    load = load if load is not None else _load_cached
    save = save if save is not None else _save_cached
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path.with_suffix(".lock"), "a+b")  # noqa: SIM115 - closed by the with below
    except OSError:                   # a read-only cache: read what it has, keep nothing
        hit = load(path)
        return hit if hit is not None else compute()
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        hit = load(path)
        if hit is not None:
            return hit
        result = compute()
        save(path, result)
        return result


def _save_cached(path: Path, r: RenderResult) -> None:
    from normbox_lab.core.npzfile import keep_npz

    keep_npz(path, wavelength_nm=r.wavelength_nm, radiance=r.radiance, std_error=r.std_error,
             batches=r.batches, render_time_s=r.render_time_s, variant=r.variant, key=r.key,
             info=json.dumps(r.info))


# --- rendering ----------------------------------------------------------------------------------
class _PersistentScene:
    """One loaded Mitsuba scene per (variant, geometry, lamp, pixels, max_depth), reused for
    every render: the materials change through the BSDF objects (`set_material`), the sample
    angle by moving the patch and holder plate in place (`mi.traverse`).  Reuse keeps the
    render kernel.  The panel is a single emitter (lamp × map texture): Mitsuba orders a
    freshly loaded scene's objects differently from one load to the next, and with several
    emitters that would change which one a random number picks, i.e. the noise realisation of
    the same seed.  With one emitter, renders repeat exactly, across reloads and processes."""

    def __init__(self, g: Any, lamp: Lamp, pixels: int, max_depth: int,
                 materials: dict[str, Material]) -> None:
        import mitsuba as mi

        from normbox_lab.predict.mitsuba_bsdf import make_bsdf, make_panel_texture

        self.bsdfs = {role: make_bsdf(m) for role, m in materials.items()}
        self.bsdfs["post"] = make_bsdf(materials["holder"])
        self.geometry = g
        film = band_film(BAND_CENTRES_NM, BAND_WIDTH_NM, pixels)
        # loaded at s = 0° and always moved from there, so that the geometry at an angle does
        # not depend on the order of earlier renders (repeatable to the last bit)
        d = scene_dict(g, angle_deg=0.0, patch_bsdf=self.bsdfs["patch"],
                       wall_bsdf=self.bsdfs["wall"], holder_bsdf=self.bsdfs["holder"],
                       lamp_values=lamp.radiance(LAMP_GRID_NM), lamp_grid_nm=LAMP_GRID_NM,
                       film=film, max_depth=max_depth, post_bsdf=self.bsdfs["post"],
                       panel_radiance=make_panel_texture(
                           LAMP_GRID_NM, lamp.radiance(LAMP_GRID_NM),
                           panel_map(g.panel_homogeneity_percent)))
        self.scene = mi.load_dict(d, parallel=False)
        # the moving shapes as loaded: every move starts from these (no accumulated rounding)
        self.to_world0 = {k: np.array(d[k]["to_world"].matrix, dtype=np.float64)
                          for k in MOVING_SHAPES}
        params = mi.traverse(self.scene)
        self.vertices0 = {k: (np.array(params[f"{k}.vertex_positions"], dtype=np.float64),
                              np.array(params[f"{k}.vertex_normals"], dtype=np.float64)
                              if f"{k}.vertex_normals" in params else np.zeros(0))
                          for k in MOVING_SHAPES if f"{k}.vertex_positions" in params}
        self.angle_deg: float | None = None

    def set_materials(self, materials: dict[str, Material]) -> None:
        for role, m in materials.items():
            self.bsdfs[role].set_material(m)
        self.bsdfs["post"].set_material(materials["holder"])

    def set_angle(self, angle_deg: float) -> None:
        import mitsuba as mi

        if float(angle_deg) == self.angle_deg:
            return
        params = mi.traverse(self.scene)
        for key, tr in moving_transforms(self.geometry, angle_deg).items():
            if key not in self.vertices0:             # an analytic shape: set its transform
                params[f"{key}.to_world"] = tr
                continue
            # a mesh: move the loaded vertices by new · loaded⁻¹
            rel = np.array(tr.matrix, dtype=np.float64) @ np.linalg.inv(self.to_world0[key])
            rot = rel[:3, :3]
            v0, n0 = self.vertices0[key]
            v = v0.reshape(-1, 3) @ rot.T + rel[:3, 3]
            buffer = type(params[f"{key}.vertex_positions"])   # mi.Float, or ArrayXf (scalar)
            params[f"{key}.vertex_positions"] = buffer(v.ravel().astype(np.float32))
            if n0.size:
                nn = n0.reshape(-1, 3) @ rot.T
                params[f"{key}.vertex_normals"] = buffer(nn.ravel().astype(np.float32))
        params.update()
        self.angle_deg = float(angle_deg)


_SCENES: dict[str, _PersistentScene] = {}


def render_view(geometry: Any = None, *, patch: Material, wall: Material,
                angle_deg: float, holder: Material | None = None, lamp: Lamp | None = None,
                quality: str | Quality = "default", direct_only: bool = False, seed: int = 0,
                cache: bool = True, cache_dir: str | Path | None = None,
                variant: str | None = None,
                target_rel_se: float | None = None) -> RenderResult:
    """Spectral radiance the radiometer sees (band means over the 10×10 px, 1° view).
    `target_rel_se`: the precision (`normbox_lab.predict.precision`) instead of the quality's
    preset; batches are added until it is met, up to the quality's `max_batches` or
    `TARGET_MAX_BATCHES`, whichever is larger."""
    g = as_geometry(geometry)
    holder = holder if holder is not None else holder_material()
    lamp = lamp if lamp is not None else Lamp()
    q = QUALITIES[quality] if isinstance(quality, str) else quality
    if target_rel_se is not None:
        q = replace(q, target_rel_se=float(target_rel_se),
                    max_batches=max(q.max_batches, q.batches, TARGET_MAX_BATCHES))
    max_depth = 2 if direct_only else 12
    key = render_key(g, patch, wall, holder, angle_deg, lamp, q, max_depth, seed)
    path = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = path / f"{key}.npz"
    def compute() -> RenderResult:
        with _LOCK:
            return _render(g, patch, wall, holder, angle_deg, lamp, q, max_depth, seed, key,
                           variant)
    result = cached_render(path, compute) if cache else compute()
    return result.scaled(lamp.relative_output) if lamp.relative_output != 1.0 else result


def _render(g: Any, patch: Material, wall: Material, holder: Material, angle_deg: float,
            lamp: Lamp, q: Quality, max_depth: int, seed: int, key: str,
            variant: str | None) -> RenderResult:
    import mitsuba as mi

    variant = ensure_variant(variant)
    t0 = time.perf_counter()
    materials = {"patch": patch, "wall": wall, "holder": holder}
    base_lamp = Lamp(lamp.cct_K, lamp.luminance_cd_m2, 1.0)
    scene_key = json.dumps([variant, asdict(g), base_lamp.key(), q.pixels, max_depth],
                           sort_keys=True)
    ps = _SCENES.get(scene_key)
    if ps is None:
        ps = _SCENES[scene_key] = _PersistentScene(g, base_lamp, q.pixels, max_depth,
                                                   materials)
    ps.set_materials(materials)
    ps.set_angle(angle_deg)
    scene = ps.scene
    batches: list[np.ndarray] = []

    def stats() -> tuple[np.ndarray, np.ndarray]:
        arr = np.array(batches)
        m = arr.mean(axis=0)
        if len(arr) < 2:
            return m, np.full_like(m, np.nan)
        return m, arr.std(axis=0, ddof=1) / np.sqrt(len(arr))

    while True:
        img = mi.render(scene, spp=q.spp, seed=seed * 1000 + len(batches))
        arr = require_finite(np.asarray(img, dtype=np.float64),    # (px, px, n_bands)
                             f"stock Mitsuba ({variant}) at {angle_deg:g}°")
        batches.append(arr.reshape(-1, arr.shape[-1]).mean(axis=0) / BAND_WIDTH_NM)
        if len(batches) < q.batches:
            continue
        if len(batches) >= max(q.max_batches, q.batches) or q.target_rel_se <= 0:
            break
        m, e = stats()
        if rel_se(m, e) <= q.target_rel_se:
            break
    batches_arr = np.array(batches)
    mean, se = stats()
    dt = time.perf_counter() - t0
    info = {"angle_deg": float(angle_deg), "patch": patch.name, "wall": wall.name,
            "quality": q.name, "spp": q.spp, "batches": len(batches), "max_depth": max_depth,
            "target_rel_se": q.target_rel_se, "rel_se": rel_se(mean, se),
            "rel_se_statistic": STATISTIC, "renderer": "mitsuba",
            "lamp_cct_K": lamp.cct_K, "lamp_luminance_cd_m2": lamp.luminance_cd_m2}
    return RenderResult(BAND_CENTRES_NM.copy(), mean, se, batches_arr, dt, variant, key,
                        cached=False, info=info)


# --- a closed-form check: the direct light -------------------------------------------------------
def band_average(wavelength_nm: Any, values: Any, centres_nm: Any = BAND_CENTRES_NM,
                 width_nm: float = BAND_WIDTH_NM) -> np.ndarray:
    """Average of a finely sampled spectrum (…, n_λ) under the render's triangular band hats."""
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    c = np.asarray(centres_nm, dtype=np.float64)
    hats = np.clip(1.0 - np.abs(wl[None, :] - c[:, None]) / width_nm, 0.0, None)
    hats /= hats.sum(axis=1, keepdims=True)
    return np.asarray(values, dtype=np.float64) @ hats.T


def direct_estimate(geometry: Any = None, *, material: Material, angle_deg: float,
                    lamp: Lamp | None = None, wavelength_nm: Any = None,
                    subdivisions: int = 8) -> np.ndarray:
    """Direct radiance (W·sr⁻¹·m⁻²·nm⁻¹) at the sample centre towards the radiometer, by
    quadrature over the 25 panel cells (each split `subdivisions`² times):

        L(λ) = Σ f(ωi, ωo, λ) · m_k · L_panel(λ) · cosθ_sample · cosθ_panel / r² · ΔA

    with the truth BRDF in the sample's frame; nothing occludes the panel from the sample.
    `wavelength_nm` None: the render's bands (hat averages, comparable band by band with
    `render_view`); otherwise the value at each wavelength."""
    if wavelength_nm is None:
        fine = np.arange(BAND_CENTRES_NM[0] - BAND_WIDTH_NM,
                         BAND_CENTRES_NM[-1] + BAND_WIDTH_NM + 0.25, 0.5)
        return band_average(fine, direct_estimate(geometry, material=material,
                                                  angle_deg=angle_deg, lamp=lamp,
                                                  wavelength_nm=fine,
                                                  subdivisions=subdivisions))
    from normbox_lab.predict.materials import truth_brdf
    from normbox_lab.predict.scene import (
        panel_cells_m,
        radiometer_position_m,
        sample_centre_m,
        sample_normal,
    )

    g = as_geometry(geometry)
    lamp = lamp if lamp is not None else Lamp()
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    p = sample_centre_m(g)
    n = sample_normal(angle_deg)
    t1 = np.array([1.0, 0.0, 0.0])
    t2 = np.cross(n, t1)
    frame = np.stack([t1, t2, n])                       # rows: local x, y, z
    to_eye = radiometer_position_m(g) - p
    wo = frame @ (to_eye / np.linalg.norm(to_eye))
    pts, weights = [], []
    k = int(subdivisions)
    u = (np.arange(k) + 0.5) / k * 2.0 - 1.0
    for centre, ex, ey, factor in panel_cells_m(g):
        xs, ys = np.meshgrid(centre[0] + u * ex, centre[1] + u * ey, indexing="ij")
        q = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, centre[2])], axis=-1)
        pts.append(q)
        weights.append(np.full(xs.size, factor * (2 * ex) * (2 * ey) / xs.size))
    q = np.concatenate(pts)
    dA = np.concatenate(weights)
    v = q - p
    r = np.linalg.norm(v, axis=-1)
    w_world = v / r[:, None]
    cos_panel = w_world[:, 2]                           # the panel faces −z
    wi = w_world @ frame.T
    cos_s = wi[:, 2]
    ok = (cos_s > 0) & (cos_panel > 0)
    f = truth_brdf(material, wi[ok], np.broadcast_to(wo, wi[ok].shape), wl)
    geom = (cos_s * cos_panel / r ** 2 * dA)[ok]
    return lamp.radiance(wl) * np.sum(f * geom[:, None], axis=0)


# --- a benchmark: `python -m normbox_lab.predict.render [--quality default] [--patches 19,13,24] ...` ------
def main(argv: list[str] | None = None) -> int:
    import argparse

    from normbox_lab.predict.materials import truth_patch, truth_wall

    ap = argparse.ArgumentParser(prog="python -m normbox_lab.predict.render",
                                 description="Render time and standard error per configuration")
    ap.add_argument("--quality", default="default", choices=sorted(QUALITIES))
    ap.add_argument("--patches", default="19,13,24")
    ap.add_argument("--angles", default="30,60,90")
    ap.add_argument("--truth", default="default", choices=("default", "model"))
    ap.add_argument("--direct-only", action="store_true")
    ap.add_argument("--variant", default=None)
    args = ap.parse_args(argv)
    wall = truth_wall(args.truth)
    t_first = time.perf_counter()
    variant = ensure_variant(args.variant)
    print(f"variant {variant}; quality {args.quality} {QUALITIES[args.quality]}; "
          f"{BAND_CENTRES_NM.size} bands of {BAND_WIDTH_NM:g} nm; no cache")
    times, ses = [], []
    for n in [int(p) for p in args.patches.split(",")]:
        for a in [float(x) for x in args.angles.split(",")]:
            r = render_view(patch=truth_patch(n, args.truth), wall=wall, angle_deg=a,
                            quality=args.quality, direct_only=args.direct_only, cache=False,
                            variant=variant)
            rel = r.relative_std_error
            times.append(r.render_time_s)
            ses.append(rel)
            print(f"patch {n:2d} s={a:4.0f}°  {r.render_time_s:6.2f} s  "
                  f"Lv={luminance_cd_m2(r.wavelength_nm, r.radiance):8.2f} cd/m²  "
                  f"{r.info['batches']:2d} batches  "
                  f"rel. SE per 5 nm band: median {100 * np.median(rel):.2f} %  "
                  f"90th pct {100 * np.percentile(rel, 90):.2f} %  max {100 * rel.max():.2f} %")
    all_se = np.concatenate(ses)
    t = np.array(times)
    print(f"first render (includes kernel compile or load) {t[0]:.2f} s; "
          f"median per configuration {np.median(t[1:] if t.size > 1 else t):.2f} s; "
          f"rel. SE per band over all: median {100 * np.median(all_se):.2f} %, "
          f"90th pct {100 * np.percentile(all_se, 90):.2f} %; total "
          f"{time.perf_counter() - t_first:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
