"""Fast spectral prediction of the Normbox: the facade over the band path tracer.

`FastNormbox` builds the virtual Normbox (`normbox_lab.predict.scene.scene_dict`) once as a
geometry-only mono Mitsuba scene, moves the patch per sample angle, and renders radiometer
spectra with `normbox_lab.predict.patchset.PatchSetTracer` (a
`normbox_lab.predict.bandpath.BandPathTracer` that can also serve all patches per path).
`predict_spectra` runs every patch × angle configuration as jobs, in process or on an
executor (`normbox_lab.predict.executors`); any executor gives identical spectra.

How the tracer works, and why it is unbiased against stock Mitsuba: `normbox_lab.predict.bandpath`.

Public API:
    FastNormbox(geometry=None).render_view(patch=..., wall=..., angle_deg=..., lamp=...,
                                           target_rel_se=DEFAULT_TARGET_SE, seed=0)
                                           -> render.RenderResult
    FastNormbox.render_patches(...)  (all patches at one angle from one set of paths)
    FastNormbox.predict(configs, ...) / predict_spectra(...)  (all patch × angle configurations)
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.predict.bandpath import (
    BandGrid,
    BandPathTracer,
    Radiometer,
    RectEmitter,
    max_rel_se,
)
from normbox_lab.predict.kernel_safety import jit_table
from normbox_lab.predict.mitsuba_setup import in_variant, jit_variant
from normbox_lab.predict.patchset import PatchSetTracer
from normbox_lab.predict.precision import DEFAULT_TARGET_SE, PRESETS

# --------------------------------------------------------------------------------------------
# The Normbox: the project's scene, its materials and lamp
# --------------------------------------------------------------------------------------------

ROLES = ("patch", "wall", "holder")
#: geometry-only stand-in BSDFs of the mono scene → the material slot they stand for
STAND_INS = {"patch": "patch", "wall": "wall", "holder": "holder", "post": "holder",
             "panel": "panel"}


@dataclass(frozen=True)
class PredictConfig:
    """One radiometer reading to predict: a patch material at a sample angle."""

    patch: Any                   # normbox_lab.predict.materials.Material (fitted or truth)
    angle_deg: float
    key: str = ""                # e.g. "patch-19@30"; default: "<patch name>@<angle>"

    @property
    def name(self) -> str:
        return self.key or f"{self.patch.name}@{self.angle_deg:g}"


#: the modules whose source decides what `FastNormbox.render_view` returns
RENDERER_MODULES = ("bandpath", "patchset", "fastrender", "guide", "streams", "kernel_safety",
                    "scene", "materials", "render", "precision")


@functools.lru_cache(maxsize=1)
def renderer_source_digest() -> str:
    """A hash of the renderer modules' source files (`RENDERER_MODULES`) and of the Mitsuba and
    Dr.Jit versions, part of every cache key of a fast render: editing a kernel, or another
    Mitsuba, invalidates what was rendered before."""
    from importlib.metadata import version

    h = hashlib.sha256(f"mitsuba {version('mitsuba')} drjit {version('drjit')}".encode())
    here = Path(__file__).resolve().parent
    for name in RENDERER_MODULES:
        h.update(name.encode())
        h.update((here / f"{name}.py").read_bytes())
    return h.hexdigest()[:16]


class FastNormbox:
    """The virtual Normbox (`normbox_lab.predict.scene.scene_dict`) rendered by `BandPathTracer`.

    One geometry scene for all sample angles: the patch and the holder plate are moved in place
    (`mi.traverse`), so no kernel is ever recompiled for a new angle or material.  The
    materials and the lamp are data passed per render.  Results are
    `normbox_lab.predict.render.RenderResult`s on the stock renderer's bands (`render.BAND_CENTRES_NM`,
    triangular 5 nm hats), in W·sr⁻¹·m⁻²·nm⁻¹.
    """

    MOVING = ("patch", "holder_plate")

    def __init__(self, geometry: Any = None, *, variant: str | None = None,
                 max_depth: int = 12, rr_depth: int = 6, grid: BandGrid | None = None,
                 chunk_paths: int = 1 << 16) -> None:
        from normbox_lab.predict.scene import as_geometry

        self.geometry = as_geometry(geometry)
        self.variant = jit_variant("mono", variant)
        self.max_depth = int(max_depth)
        self.rr_depth = int(rr_depth)
        self.grid = grid or BandGrid()
        self.chunk_paths = int(chunk_paths)
        self._scene: Any = None
        self._angle_deg: float | None = None
        self._tracers: dict[int, BandPathTracer] = {}

    # ---- the geometry scene ------------------------------------------------------------
    def _scene_dict(self, mi: Any, angle_deg: float, stand_in: Mapping[str, Any]) -> dict:
        from normbox_lab.predict import scene as nbscene

        d = nbscene.scene_dict(self.geometry, angle_deg=angle_deg,
                               patch_bsdf=stand_in["patch"], wall_bsdf=stand_in["wall"],
                               holder_bsdf=stand_in["holder"], lamp_values=np.ones(2),
                               lamp_grid_nm=np.array([360.0, 830.0]),
                               film={"type": "hdrfilm", "width": 1, "height": 1})
        d.pop("sensor", None)
        d.pop("integrator", None)
        # the moving plate must stay its own shape: Mitsuba merges shapes sharing a BSDF
        if "holder_post" in d:
            d["holder_post"]["bsdf"] = stand_in["post"]
        for key, value in d.items():
            if key.startswith("panel_") and isinstance(value, dict):
                value.pop("emitter", None)          # emission is the tracer's (RectEmitter)
                value["bsdf"] = stand_in["panel"]
        return d

    #: the angle the scene is built at; every other angle is this scene moved, computed from
    #: it directly (never from the previous angle), so the geometry at an angle does not
    #: depend on which angles a process rendered before (bit-identical across executors)
    REFERENCE_ANGLE_DEG = 45.0

    def _ensure_scene(self, angle_deg: float) -> None:
        from normbox_lab.predict import scene as nbscene

        if self._scene is None:
            g = self.geometry
            ref = self.REFERENCE_ANGLE_DEG
            with in_variant(self.variant) as mi:
                self._stand_in = {r: mi.load_dict({"type": "diffuse",
                                                   "reflectance": 0.1 + 0.1 * i})
                                  for i, r in enumerate(STAND_INS)}
                d = self._scene_dict(mi, ref, self._stand_in)
                self._scene = mi.load_dict(d)
                self._ref_to_world = {k: np.array(d[k]["to_world"].matrix, dtype=np.float64)
                                      for k in self.MOVING}
                params = mi.traverse(self._scene)
                self._ref_params = {}
                for key in self.MOVING:
                    for name in (f"{key}.vertex_positions", f"{key}.vertex_normals"):
                        if name in params and dr_size(params[name]) > 0:
                            self._ref_params[name] = np.array(params[name], dtype=np.float64)
            self._angle_deg = ref
            cells = nbscene.panel_cells_m(g)
            z = float(cells[0][0][2])
            self._emitter = RectEmitter((0.0, 0.0, z), g.aperture_x_mm / 2000.0,
                                        g.aperture_y_mm / 2000.0,
                                        tuple(map(tuple, nbscene.panel_map(
                                            g.panel_homogeneity_percent))))
            self._radiometer = Radiometer(origin_m=tuple(nbscene.radiometer_position_m(g)),
                                          target_m=tuple(nbscene.sample_centre_m(g)),
                                          up=(0.0, 0.0, 1.0),
                                          fov_deg=float(g.radiometer_view_deg))
        self.set_angle(angle_deg)

    def set_angle(self, angle_deg: float) -> None:
        """Rotate the patch and its holder plate in place to `angle_deg` (from the reference
        scene's vertices, so the result depends on `angle_deg` alone)."""
        if self._scene is None:
            self._ensure_scene(angle_deg)
            return
        if self._angle_deg == float(angle_deg):
            return
        with in_variant(self.variant) as mi:
            d = self._scene_dict(mi, float(angle_deg), self._stand_in)
            params = mi.traverse(self._scene)
            for key in self.MOVING:
                new = np.array(d[key]["to_world"].matrix, dtype=np.float64)
                rel = new @ np.linalg.inv(self._ref_to_world[key])
                if f"{key}.to_world" in params:
                    params[f"{key}.to_world"] = mi.ScalarTransform4f(new)
                    continue
                v = self._ref_params[f"{key}.vertex_positions"].reshape(-1, 3)
                v = v @ rel[:3, :3].T + rel[:3, 3]
                params[f"{key}.vertex_positions"] = jit_table(mi.Float, v)
                nk = f"{key}.vertex_normals"
                if nk in self._ref_params:
                    nn = self._ref_params[nk].reshape(-1, 3) @ np.linalg.inv(rel[:3, :3])
                    nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-30)
                    params[nk] = jit_table(mi.Float, nn)
            params.update()
        self._angle_deg = float(angle_deg)
        for tr in self._tracers.values():
            tr.refresh_geometry()

    def tracer(self, angle_deg: float, *, direct_only: bool = False) -> Any:
        """The tracer (max_depth 12, or 2 for the direct light only) with the patch at angle:
        a `patchset.PatchSetTracer` (a `BandPathTracer` that can also serve all patches)."""
        from normbox_lab.predict import scene as nbscene
        from normbox_lab.predict.guide import GuideRects

        self._ensure_scene(angle_deg)
        depth = 2 if direct_only else self.max_depth
        tr = self._tracers.get(depth)
        if tr is None:
            tr = self._tracers[depth] = PatchSetTracer(
                self._scene, [(self._stand_in[r], STAND_INS[r]) for r in STAND_INS],
                self._radiometer, self._emitter, variant=self.variant, emitter_slot="panel",
                grid=self.grid, max_depth=depth, rr_depth=self.rr_depth,
                chunk_paths=self.chunk_paths)
            if depth > 2:        # light from the walls: only with more than one bounce
                tr.guide = GuideRects(nbscene.aperture_sides_m(self.geometry))
        return tr

    def render_view(self, *, patch: Any, wall: Any, angle_deg: float, holder: Any = None,
                    lamp: Any = None, target_rel_se: float | None = DEFAULT_TARGET_SE,
                    n_paths: int | None = None, seed: int = 0, direct_only: bool = False,
                    max_paths: int = 1 << 23, pilot_paths: int = 1 << 14,
                    cache_dir: str | Path | None = None) -> Any:
        """Like `render.render_view`: the radiance the radiometer sees, per band, with its MC
        standard error (`RenderResult`; `batches` holds the mean only, `info["n_paths"]`).
        A small `pilot_paths` makes the achieved error close to `target_rel_se` (the default
        pilot already beats a loose target at small angles).

        `cache_dir`: keep the result there (`render`'s .npz format) and return it from there
        when everything it depends on is the same (`view_key`: the inputs, the seed, the
        variant and the renderer's source code); None renders every time."""
        from normbox_lab.predict.materials import holder_material
        from normbox_lab.predict.render import Lamp, cached_render

        holder = holder if holder is not None else holder_material()
        lamp = lamp if lamp is not None else Lamp()
        args = {"patch": patch, "wall": wall, "holder": holder, "angle_deg": float(angle_deg),
                "lamp": lamp, "target_rel_se": target_rel_se, "n_paths": n_paths,
                "seed": int(seed), "direct_only": bool(direct_only), "max_paths": int(max_paths),
                "pilot_paths": int(pilot_paths)}
        if cache_dir is None:
            return self._render_view(**args)
        key = self.view_key(**args)

        def compute() -> Any:
            result = self._render_view(**args)
            result.key = key
            return result
        return cached_render(Path(cache_dir) / f"fast-{key}.npz", compute)

    def view_key(self, **args: Any) -> str:
        """The cache key of a `render_view`: a hash of its arguments (materials by their
        digest, the lamp by its parameters), the geometry, the band grid, the path depths, the
        Mitsuba variant and the source code of the renderer's modules (`renderer_source_digest`:
        a changed kernel never returns an old result)."""
        from normbox_lab.predict.render import RENDER_VERSION

        payload = {k: (v.digest() if k in ROLES else v.key() if k == "lamp" else
                       [m.digest() for m in v] if k == "patches" else v)
                   for k, v in args.items()}
        payload.update(renderer="fastrender", v=RENDER_VERSION, variant=self.variant,
                       geometry=repr(self.geometry), max_depth=self.max_depth,
                       rr_depth=self.rr_depth, chunk_paths=self.chunk_paths,
                       grid=[self.grid.start_nm, self.grid.stop_nm, self.grid.step_nm],
                       source=renderer_source_digest())
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]

    def _render_view(self, *, patch: Any, wall: Any, holder: Any, angle_deg: float, lamp: Any,
                     target_rel_se: float | None, n_paths: int | None, seed: int,
                     direct_only: bool, max_paths: int, pilot_paths: int) -> Any:
        from normbox_lab.predict.render import LAMP_GRID_NM, RenderResult

        tr = self.tracer(angle_deg, direct_only=direct_only)
        target = None if n_paths is not None else target_rel_se
        if tr.separable(patch):
            # randomised QMC at the patch vertex, wavelength strata (`patchset`): 1.6–3× fewer
            # paths than plain Monte Carlo to the same standard error
            est = tr.render_patches([patch], {"wall": wall, "holder": holder}, LAMP_GRID_NM,
                                    lamp.radiance(LAMP_GRID_NM), n_paths=n_paths,
                                    target_rel_se=target, seed=seed, max_paths=max_paths,
                                    pilot_paths=pilot_paths)[0]
            renderer = "fastrender-qmc"
        else:
            est = tr.render({"patch": patch, "wall": wall, "holder": holder}, LAMP_GRID_NM,
                            lamp.radiance(LAMP_GRID_NM), n_paths=n_paths, target_rel_se=target,
                            seed=seed, max_paths=max_paths, pilot_paths=pilot_paths)
            renderer = "fastrender"
        info = {"angle_deg": float(angle_deg), "patch": patch.name, "wall": wall.name,
                "renderer": renderer, "n_paths": est.n_paths, "seed": int(seed),
                "max_depth": tr.max_depth, "target_rel_se": target_rel_se,
                "max_rel_se": max_rel_se(est.radiance, est.std_error)}
        return RenderResult(est.wavelength_nm, est.radiance, est.std_error,
                            est.radiance[None, :].copy(), est.time_s, self.variant,
                            key="", cached=False, info=info)

    def render_patches(self, *, patches: Sequence[Any], wall: Any, angle_deg: float,
                       holder: Any = None, lamp: Any = None,
                       target_rel_se: float | None = DEFAULT_TARGET_SE, n_paths: int | None = None,
                       seed: int = 0, max_paths: int = 1 << 23,
                       cache_dir: str | Path | None = None) -> list[Any]:
        """`render_view` for every patch at one angle from one set of paths
        (`patchset.PatchSetTracer.render_patches`): a `RenderResult` per patch, in order.
        The estimates are correlated across patches; each one's standard error is its own.
        `cache_dir`: kept there and read back as `render_view`'s."""
        from normbox_lab.predict.materials import holder_material
        from normbox_lab.predict.render import Lamp, cached_render

        holder = holder if holder is not None else holder_material()
        lamp = lamp if lamp is not None else Lamp()
        args = {"patches": list(patches), "wall": wall, "holder": holder,
                "angle_deg": float(angle_deg), "lamp": lamp, "target_rel_se": target_rel_se,
                "n_paths": n_paths, "seed": int(seed), "max_paths": int(max_paths)}
        if cache_dir is None:
            return self._render_patches(**args)
        key = self.view_key(**args)
        return cached_render(Path(cache_dir) / f"fast-patches-{key}.npz",
                             lambda: self._render_patches(**args), _load_results,
                             _save_results)

    def _render_patches(self, *, patches: list[Any], wall: Any, holder: Any, angle_deg: float,
                        lamp: Any, target_rel_se: float | None, n_paths: int | None, seed: int,
                        max_paths: int) -> list[Any]:
        from normbox_lab.predict.render import LAMP_GRID_NM, RenderResult

        tr = self.tracer(angle_deg)
        ests = tr.render_patches(list(patches), {"wall": wall, "holder": holder}, LAMP_GRID_NM,
                                 lamp.radiance(LAMP_GRID_NM), n_paths=n_paths,
                                 target_rel_se=None if n_paths is not None else target_rel_se,
                                 seed=seed, max_paths=max_paths)
        out = []
        for patch, est in zip(patches, ests, strict=True):
            info = {"angle_deg": float(angle_deg), "patch": patch.name, "wall": wall.name,
                    "renderer": "fastrender-patchset", "n_paths": est.n_paths,
                    "seed": int(seed), "max_depth": tr.max_depth, "patches": len(ests),
                    "target_rel_se": target_rel_se,
                    "max_rel_se": max_rel_se(est.radiance, est.std_error)}
            out.append(RenderResult(est.wavelength_nm, est.radiance, est.std_error,
                                    est.radiance[None, :].copy(), est.time_s, self.variant,
                                    key="", cached=False, info=info))
        return out

    def predict(self, configs: Sequence[PredictConfig], *, wall: Any, holder: Any = None,
                lamp: Any = None, target_rel_se: float | None = DEFAULT_TARGET_SE,
                n_paths: int | None = None, seed: int = 0) -> list[Any]:
        """Every configuration in process, angle-major (one scene per angle); the seed of each
        configuration is derived from `seed` and its name, so results do not depend on order."""
        order = sorted(range(len(configs)), key=lambda i: float(configs[i].angle_deg))
        out: list[Any] = [None] * len(configs)
        for i in order:
            c = configs[i]
            out[i] = self.render_view(patch=c.patch, wall=wall, angle_deg=c.angle_deg,
                                      holder=holder, lamp=lamp, target_rel_se=target_rel_se,
                                      n_paths=n_paths, seed=config_seed(seed, c.name))
        return out


def _save_results(path: Path, results: list[Any]) -> None:
    """A list of `RenderResult`s of one band grid as one .npz (whole or not at all; a cache
    that cannot be written only costs rendering again)."""
    from normbox_lab.core.npzfile import keep_npz

    keep_npz(path, wavelength_nm=results[0].wavelength_nm,
             radiance=np.stack([r.radiance for r in results]),
             std_error=np.stack([r.std_error for r in results]),
             time_s=np.array([r.render_time_s for r in results]),
             variant=results[0].variant, key=results[0].key,
             info=json.dumps([r.info for r in results]))


def _load_results(path: Path) -> list[Any] | None:
    """What `_save_results` wrote, or None."""
    from normbox_lab.predict.render import RenderResult

    try:
        with np.load(path, allow_pickle=False) as z:
            infos = json.loads(str(z["info"]))
            return [RenderResult(z["wavelength_nm"], z["radiance"][i], z["std_error"][i],
                                 z["radiance"][i][None, :].copy(), float(z["time_s"][i]),
                                 str(z["variant"]), str(z["key"]), cached=True, info=info)
                    for i, info in enumerate(infos)]
    except (OSError, KeyError, ValueError, IndexError):
        return None


def dr_size(x: Any) -> int:
    import drjit as dr

    return int(dr.width(x))


def config_seed(seed: int, name: str) -> int:
    """A per-configuration seed from the run seed and the configuration's name."""
    return (int(seed) << 20) ^ zlib.crc32(name.encode())


# --------------------------------------------------------------------------------------------
# All patch × angle spectra, in process or on a cluster
# --------------------------------------------------------------------------------------------

#: the quality presets of the target (worst band's relative standard error): defined once in
#: `normbox_lab.predict.precision`; this name is kept for the callers that used it
FAST_TARGET_REL_SE = PRESETS


@dataclass
class PredictionSet:
    """Predicted radiance for every patch × angle: arrays (n_patch, n_angle, n_band)."""

    wavelength_nm: np.ndarray
    patch_names: list[str]
    angles_deg: np.ndarray
    radiance: np.ndarray            # W·sr⁻¹·m⁻²·nm⁻¹ (5 nm triangular bands)
    std_error: np.ndarray           # Monte-Carlo standard error, same unit
    n_paths: np.ndarray             # (n_patch, n_angle)
    render_time_s: np.ndarray       # (n_patch, n_angle)
    wall_time_s: float = 0.0
    executor: str = "inprocess"

    @property
    def relative_std_error(self) -> np.ndarray:
        return self.std_error / np.maximum(np.abs(self.radiance), 1e-300)

    def spectrum(self, patch: str, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """(radiance, std_error) of one configuration."""
        i = self.patch_names.index(patch)
        j = int(np.argmin(np.abs(self.angles_deg - float(angle_deg))))
        return self.radiance[i, j], self.std_error[i, j]


_WORKER_BOXES: dict[tuple, FastNormbox] = {}


def render_task(task: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One job (module-level, so executors can ship it): render `task["configs"]` — a list of
    (name, patch material, angle) — in this process's cached `FastNormbox`."""
    key = (repr(task["geometry"]), task.get("variant"), int(task["max_depth"]))
    box = _WORKER_BOXES.get(key)
    if box is None:
        threads = task.get("threads")
        if threads:
            import drjit as dr

            dr.set_thread_count(int(threads))
        box = _WORKER_BOXES[key] = FastNormbox(task["geometry"], variant=task.get("variant"),
                                               max_depth=int(task["max_depth"]))
    out = []
    if task.get("all_patches"):
        configs = task["configs"]
        angle = float(configs[0][2])
        results = box.render_patches(patches=[p for _, p, _ in configs], wall=task["wall"],
                                     angle_deg=angle, holder=task["holder"], lamp=task["lamp"],
                                     target_rel_se=task["target_rel_se"],
                                     n_paths=task["n_paths"],
                                     seed=config_seed(task["seed"], f"patches@{angle:g}"))
        for (name, _, _), r in zip(configs, results, strict=True):
            out.append({"name": name, "radiance": r.radiance, "std_error": r.std_error,
                        "n_paths": r.info["n_paths"], "time_s": r.render_time_s})
        return out
    for name, patch, angle in task["configs"]:
        r = box.render_view(patch=patch, wall=task["wall"], angle_deg=angle,
                            holder=task["holder"], lamp=task["lamp"],
                            target_rel_se=task["target_rel_se"], n_paths=task["n_paths"],
                            seed=config_seed(task["seed"], name))
        out.append({"name": name, "radiance": r.radiance, "std_error": r.std_error,
                    "n_paths": r.info["n_paths"], "time_s": r.render_time_s})
    return out


def predict_spectra(patches: Sequence[Any] | Mapping[str, Any], angles_deg: Sequence[float], *,
                    wall: Any, holder: Any = None, lamp: Any = None, geometry: Any = None,
                    target_rel_se: float | None = DEFAULT_TARGET_SE, n_paths: int | None = None,
                    seed: int = 0, executor: Any = None, variant: str | None = None,
                    max_depth: int = 12, patches_per_job: int = 6,
                    threads_per_job: int | None = None,
                    all_patches: bool | None = None) -> PredictionSet:
    """Predict every patch × angle radiometer spectrum with the given (e.g. fitted) materials.

    `patches`: `materials.Material`s (use `Material.from_fit(MaterialFit)`) or a name → material
    mapping; `wall`, `holder` likewise; `lamp`: `render.Lamp`.  Noise: `target_rel_se` (largest
    relative standard error over the bands, per configuration) or a fixed `n_paths`.
    `executor`: an `executors.make_executor(...)` object (None: in process).

    `all_patches` (default: whenever no patch has a λ-dependent η): one job per angle traces
    each path once for all patches (`patchset`; the patches' estimates are then correlated,
    each with its own correct SE), seeded from `seed` and "patches@<angle>".  Otherwise jobs of
    `patches_per_job` configurations, each seeded from `seed` and its name "<patch
    name>@<angle>".  Either way any executor gives identical spectra.
    """
    from normbox_lab.predict.executors import InProcessExecutor
    from normbox_lab.predict.materials import holder_material
    from normbox_lab.predict.render import Lamp
    from normbox_lab.predict.scene import as_geometry

    items = list(patches.items()) if isinstance(patches, Mapping) else \
        [(p.name, p) for p in patches]
    names = [n for n, _ in items]
    if len(set(names)) != len(names):
        raise ValueError("patch names must be unique")
    angles = np.asarray([float(a) for a in angles_deg])
    g = as_geometry(geometry)
    base = {"geometry": g, "variant": variant, "max_depth": int(max_depth), "wall": wall,
            "holder": holder if holder is not None else holder_material(),
            "lamp": lamp if lamp is not None else Lamp(), "target_rel_se": target_rel_se,
            "n_paths": n_paths, "seed": int(seed), "threads": threads_per_job}
    if all_patches is None:
        all_patches = not any(float(getattr(p, "deta_per_100nm", 0.0)) for _, p in items)
    tasks = []
    for a in angles:                                  # angle-major: few patch moves per job
        if all_patches:
            tasks.append({**base, "all_patches": True,
                          "configs": [(f"{n}@{a:g}", p, float(a)) for n, p in items]})
            continue
        for s in range(0, len(items), max(1, int(patches_per_job))):
            chunk = items[s:s + max(1, int(patches_per_job))]
            tasks.append({**base, "configs": [(f"{n}@{a:g}", p, float(a)) for n, p in chunk]})
    ex = executor if executor is not None else InProcessExecutor()
    t0 = time.perf_counter()
    results = {r["name"]: r for batch in ex.map(render_task, tasks) for r in batch}
    wall_s = time.perf_counter() - t0
    grid = BandGrid()
    shape = (len(items), len(angles))
    rad = np.zeros(shape + (grid.n_bands,))
    se = np.zeros_like(rad)
    npaths = np.zeros(shape, dtype=np.int64)
    times = np.zeros(shape)
    for i, n in enumerate(names):
        for j, a in enumerate(angles):
            r = results[f"{n}@{a:g}"]
            rad[i, j], se[i, j] = r["radiance"], r["std_error"]
            npaths[i, j], times[i, j] = r["n_paths"], r["time_s"]
    return PredictionSet(grid.centres_nm, names, angles, rad, se, npaths, times, wall_s,
                         getattr(ex, "name", type(ex).__name__))
