"""The pipeline on stored runs: fit → predict → compare → error model → report.

It reads only the store and writes its results back as artifacts (DESIGN §3), so the report
and the TUI read one place:

- ``fit`` artifacts, one per material (`p01`…`p24`, `wall`), from a gonio run (`fit.py`);
- ``prediction`` artifact ``ref-run-<id>``: radiance [patch, angle, λ] rendered with the fitted
  materials through the shared scene builder, its Monte-Carlo standard error, and the
  direct-only render of the white patch per angle (for the light shares);
- ``comparison`` artifact ``ref-run-<id>`` (`compare.py`), ``error-model`` artifact likewise;
- the HTML report (`report.py`).

The light the predictions use: the lamp model of the virtual Normbox (`render.Lamp`), with its
luminance taken from the light-map run when there is one (the mean measured panel luminance),
else the nominal value.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.acquire.queries import fit_key, latest_fits, reference_data, white_index
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import DataError, StoreError

ProgressFn = Callable[[str, int, int], None]


def _noop(stage: str, done: int, total: int) -> None:
    """Default progress callback: silent."""


# --- fit -----------------------------------------------------------------------------------------

def fit_run(store: Store, brdf_run: int | str, w: float = 2.0,
            progress: ProgressFn = _noop,
            materials: Iterable[str] | None = None, *,
            accept_flagged: bool = False) -> dict[str, Any]:
    """Fit every material of a gonio run (or only `materials`); each fit is stored as a ``fit``
    artifact and checked by the fit gates (`qa.check_fits`, against all the run's latest
    fits).  A run with error flags is refused unless `accept_flagged` (then recorded in each
    fit's provenance)."""
    from normbox_lab.analyze import qa
    from normbox_lab.analyze.fit import data_from_store_run, fit_materials

    accepted = qa.require_clean(store, run=brdf_run, accept_flagged=accept_flagged, step="fit")
    data = data_from_store_run(store, brdf_run)
    if not data:
        raise DataError(str(store.path), f"run {brdf_run}", "no BRDF readings to fit")
    if materials is not None:
        missing = [m for m in materials if m not in data]
        if missing:
            raise DataError(str(store.path), f"run {brdf_run}",
                            f"no BRDF readings for {', '.join(missing)}")
        data = {m: data[m] for m in materials}
    progress("fit", 0, len(data))
    done: list[str] = []

    def stored(name: str, fit: Any) -> None:        # in name order, as each is ready
        fit.metadata.update(qa.provenance(accepted))
        fit.store(store, run_ref=brdf_run)
        done.append(name)
        if len(done) < len(data):
            progress("fit", len(done), len(data))

    # the materials on as many processes as this machine gives (the same fits, bit for bit)
    fits = fit_materials(data, w, on_fit=stored)
    from normbox_lab.predict.brdf_model import MaterialFit

    latest = {a.name: a for a in store.artifacts("fit", run_ref=brdf_run)}
    qa.check_fits(store, brdf_run,
                  {n: (a.id, MaterialFit.from_artifact(a)) for n, a in latest.items()})
    progress("fit", len(data), len(data))
    return fits


# --- predict -------------------------------------------------------------------------------------

def predict_run(store: Store, ref_run: int | str, *, fits: dict[str, Any] | None = None,
                geometry: Any = None, quality: str = "default",
                target_se: float | None = None, renderer: str = "fast", lamp: Any = None,
                render: Callable[..., Any] | None = None,
                progress: ProgressFn = _noop, accept_flagged: bool = False,
                executor: Any = None, render_angle: Callable[..., Any] | None = None) -> int:
    """Render every patch × angle of the reference run with the fitted materials.  Error
    flags on the reference run or on the (stored) fits used are refused unless
    `accept_flagged`.

    Precision: `target_se`, the target of the worst band's relative standard error
    (`normbox_lab.predict.precision`), else the preset of `quality`; both renderers stop on
    that statistic.  `renderer`: "fast" (the band-vector renderer, `fastrender.predict_spectra`,
    all configurations as independent jobs on `executor`: in process by default, or a dask
    cluster; the results do not depend on the executor) or "mitsuba" (the stock renderer,
    one configuration after the other, in process).  `render`: a render function used for
    every configuration instead (a simulated lab's, a test's), called with `quality`; with
    `render_angle` (every patch of one angle in one call: `patches=[...]`, a result per patch
    in order; the demo's all patches per path), the sweep goes through that and `render`
    renders the light shares."""
    from normbox_lab.analyze import qa
    from normbox_lab.predict.materials import Material, holder_material
    from normbox_lab.predict.precision import RENDERERS
    from normbox_lab.predict.precision import target_se as resolve_target

    if renderer not in RENDERERS:
        raise ValueError(f"unknown renderer {renderer!r}; known: {', '.join(RENDERERS)}")
    if executor is not None and (renderer != "fast" or render is not None):
        raise ValueError("an executor runs the fast renderer's jobs: use it with "
                         "renderer='fast' (the stock Mitsuba renderer runs in process)")
    target = resolve_target(quality, target_se)
    ref = reference_data(store, ref_run)
    stored_fits = fits is None
    fits = fits if fits is not None else latest_fits(store)
    need = [fit_key(p) for p in ref.patches] + ["wall"]
    missing = [n for n in need if n not in fits]
    if missing:
        raise StoreError(f"no fits for {', '.join(missing)}: run `normbox-lab fit` on a gonio "
                         f"run with those materials first")
    fit_ids = [a.id for a in {a.name: a for a in store.artifacts("fit")}.values()
               if a.name in need] if stored_fits else []
    accepted = qa.require_clean(store, run=ref_run, artifacts=fit_ids,
                                accept_flagged=accept_flagged, step="predict")
    wall = Material.from_fit(fits["wall"])
    holder = holder_material()
    materials = {fit_key(p): Material.from_fit(fits[fit_key(p)]) for p in ref.patches}
    t0 = time.perf_counter()
    if render_angle is not None and render is None:
        raise ValueError("render_angle renders the sweep; give `render` for the light shares")
    if render_angle is not None:
        out, err, used = _predict_by_angle(render_angle, ref, materials, wall, holder, geometry,
                                           lamp, quality, progress)
        direct_render = render
    elif render is not None:
        out, err, used = _predict_with(render, ref, materials, wall, holder, geometry, lamp,
                                       quality, progress)
        direct_render = render
    elif renderer == "fast":
        out, err, used, direct_render = _predict_fast(ref, materials, wall, holder, geometry,
                                                      lamp, target, executor, progress)
    else:
        direct_render = _mitsuba_render(target)
        out, err, used = _predict_with(direct_render, ref, materials, wall, holder, geometry,
                                       lamp, quality, progress)
    direct, wp = _direct_white(direct_render, ref, materials, wall, holder, geometry, lamp,
                               quality, progress)
    aid = store.add_artifact(
        "prediction", f"ref-run-{store.get_run(ref_run).id}",
        {"wavelength_nm": ref.wavelength_nm, "angle_deg": ref.angle_deg,
         "patches": np.array(ref.patches, dtype=float), "radiance": out, "std_error": err,
         "direct_white": direct, "full_white": out[ref.patches.index(wp)]},
        metadata={"quality": quality, "target_rel_se": target,
                  "rel_se_statistic": _statistic(), "white_patch": wp, "renderer": used,
                  "executor": getattr(executor, "name", None) or
                  ("inprocess" if used == "fastrender" and render is None else "none"),
                  "render_s": time.perf_counter() - t0,
                  "fits": {n: fits[n].name for n in need}, **qa.provenance(accepted)},
        run_ref=ref_run)
    qa.check_prediction(store, ref_run, aid, ref.patches, ref.angle_deg, out, err)
    return aid


def _statistic() -> str:
    from normbox_lab.predict.precision import STATISTIC

    return STATISTIC


def _predict_with(render: Callable[..., Any], ref: Any, materials: dict[str, Any], wall: Any,
                  holder: Any, geometry: Any, lamp: Any, quality: str, progress: ProgressFn
                  ) -> tuple[np.ndarray, np.ndarray, str]:
    """Every configuration through `render`, one after the other; (radiance, SE, renderer)."""
    n_p, n_a = len(ref.patches), ref.angle_deg.size
    out = np.zeros((n_p, n_a, ref.wavelength_nm.size))
    err = np.zeros_like(out)
    used, done, total = "mitsuba", 0, n_p * n_a + n_a
    for pi, p in enumerate(ref.patches):
        for ai, a in enumerate(ref.angle_deg):
            progress("predict", done, total)
            r = render(geometry, patch=materials[fit_key(p)], wall=wall, holder=holder,
                       angle_deg=float(a), lamp=lamp, quality=quality)
            out[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.radiance)
            err[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.std_error)
            used = str(r.info.get("renderer", "mitsuba"))
            done += 1
    return out, err, used


def _predict_by_angle(render_angle: Callable[..., Any], ref: Any, materials: dict[str, Any],
                      wall: Any, holder: Any, geometry: Any, lamp: Any, quality: str,
                      progress: ProgressFn) -> tuple[np.ndarray, np.ndarray, str]:
    """Every angle's patches through one `render_angle` call each; (radiance, SE, renderer)."""
    n_p, n_a = len(ref.patches), ref.angle_deg.size
    out = np.zeros((n_p, n_a, ref.wavelength_nm.size))
    err = np.zeros_like(out)
    used, total = "mitsuba", n_p * n_a + n_a
    for ai, a in enumerate(ref.angle_deg):
        progress("predict", ai * n_p, total)
        results = render_angle(geometry, patches=[materials[fit_key(p)] for p in ref.patches],
                               wall=wall, holder=holder, angle_deg=float(a), lamp=lamp,
                               quality=quality)
        for pi, r in enumerate(results):
            out[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.radiance)
            err[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.std_error)
            used = str(r.info.get("renderer", "mitsuba"))
    return out, err, used


def _predict_fast(ref: Any, materials: dict[str, Any], wall: Any, holder: Any, geometry: Any,
                  lamp: Any, target: float, executor: Any, progress: ProgressFn
                  ) -> tuple[np.ndarray, np.ndarray, str, Callable[..., Any]]:
    """All configurations with the fast renderer on `executor` (in process when None); and
    the same renderer for the light shares."""
    from normbox_lab.predict.executors import make_executor
    from normbox_lab.predict.fastrender import FastNormbox, predict_spectra

    n_p, n_a = len(ref.patches), ref.angle_deg.size
    progress("predict", 0, n_p * n_a + n_a)
    own = executor is None
    executor = make_executor("inprocess") if own else executor
    try:
        pred = predict_spectra(materials, ref.angle_deg, wall=wall, holder=holder, lamp=lamp,
                               geometry=geometry, target_rel_se=target, seed=1,
                               executor=executor)
    finally:
        if own:
            executor.close()
    out = np.zeros((n_p, n_a, ref.wavelength_nm.size))
    err = np.zeros_like(out)
    for pi, p in enumerate(ref.patches):
        for ai, a in enumerate(ref.angle_deg):
            rad, se = pred.spectrum(fit_key(p), float(a))
            out[pi, ai] = np.interp(ref.wavelength_nm, pred.wavelength_nm, rad)
            err[pi, ai] = np.interp(ref.wavelength_nm, pred.wavelength_nm, se)
    fast = FastNormbox(geometry)

    def render(geometry: Any, *, patch: Any, wall: Any, holder: Any, angle_deg: float,
               lamp: Any = None, quality: str | None = None, direct_only: bool = False) -> Any:
        return fast.render_view(patch=patch, wall=wall, holder=holder, angle_deg=angle_deg,
                                lamp=lamp, seed=1, target_rel_se=target,
                                direct_only=direct_only)
    return out, err, "fastrender", render


def _mitsuba_render(target: float) -> Callable[..., Any]:
    """The stock Mitsuba renderer at the target precision (the quality's batch plan)."""
    from normbox_lab.predict.render import render_view

    def render(geometry: Any, *, patch: Any, wall: Any, holder: Any, angle_deg: float,
               lamp: Any = None, quality: str | None = None, direct_only: bool = False) -> Any:
        return render_view(geometry, patch=patch, wall=wall, holder=holder,
                           angle_deg=angle_deg, lamp=lamp, quality=quality or "default",
                           direct_only=direct_only, target_rel_se=target)
    return render


def _direct_white(render: Callable[..., Any], ref: Any, materials: dict[str, Any], wall: Any,
                  holder: Any, geometry: Any, lamp: Any, quality: str, progress: ProgressFn
                  ) -> tuple[np.ndarray, int]:
    """Direct-only renders of the white patch (or the first) per angle, for the light shares;
    (radiance [angle, λ], that patch)."""
    n_p, n_a = len(ref.patches), ref.angle_deg.size
    wp = ref.patches[white_index(ref.patches)]
    direct = np.zeros((n_a, ref.wavelength_nm.size))
    for ai, a in enumerate(ref.angle_deg):
        progress("predict", n_p * n_a + ai, n_p * n_a + n_a)
        r = render(geometry, patch=materials[fit_key(wp)], wall=wall, holder=holder,
                   angle_deg=float(a), lamp=lamp, quality=quality, direct_only=True)
        direct[ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.radiance)
    progress("predict", n_p * n_a + n_a, n_p * n_a + n_a)
    return direct, wp


# --- compare and error model ---------------------------------------------------------------

def compare_run(store: Store, ref_run: int | str, brdf_run: int | str | None = None, *,
                accept_flagged: bool = False, renderer: str | None = None) -> Any:
    """ΔE00, NRMSE… of the latest prediction against the reference; stores the comparison and
    (when the gonio data are at hand) the error model.  Error flags on the reference run or
    the prediction are refused unless `accept_flagged` (then recorded in the comparison).
    `renderer`: another renderer's imported prediction (`predict.renderers`) instead of ours;
    its comparison and error model are stored under ``ref-run-<id>@<renderer>``."""
    from normbox_lab.analyze import qa
    from normbox_lab.analyze.compare import compare, direct_light_geometry, error_model
    from normbox_lab.predict.renderers import artifact_name

    run_id = store.get_run(ref_run).id
    ref = reference_data(store, run_id)
    name = artifact_name(run_id, renderer)
    pred_artifact = store.latest_artifact("prediction", name)
    accepted = qa.require_clean(store, run=run_id, artifacts=[pred_artifact.id],
                                accept_flagged=accept_flagged, step="compare")
    pred = pred_artifact.arrays
    if not np.array_equal(pred["patches"].astype(int), ref.patches) or \
            not np.array_equal(pred["angle_deg"], ref.angle_deg):
        raise StoreError(f"the prediction of run {run_id} does not match its readings; "
                         "run `normbox-lab predict` again")
    white = white_index(ref.patches)
    names = [f"{p} {n}" for p, n in zip(ref.patches, ref.patch_names)]
    result = compare(ref.radiance, pred["radiance"], ref.wavelength_nm, ref.angle_deg, names,
                     white_patch=white, white_angle_deg=float(ref.angle_deg.min()))
    # what one Monte-Carlo standard error of the prediction does to ΔE00 (the report's methods)
    shifted = compare(ref.radiance, pred["radiance"] + pred["std_error"], ref.wavelength_nm,
                      ref.angle_deg, names, white_patch=white,
                      white_angle_deg=float(ref.angle_deg.min()))
    dde = np.abs(shifted.delta_e00 - result.delta_e00)
    one_se = {"median": float(np.nanmedian(dde)), "max": float(np.nanmax(dde))}
    store.add_artifact("comparison", name, result.to_arrays(),
                       metadata={**result.to_metadata(), "delta_e00_one_se_shift": one_se,
                                 "renderer": renderer or "normbox-lab",
                                 **qa.provenance(accepted)},
                       run_ref=run_id)
    if brdf_run is not None and "direct_white" in pred:
        from normbox_lab.analyze.fit import data_from_store_run, fit_error_at

        fits = latest_fits(store)
        data = data_from_store_run(store, brdf_run)
        share = np.clip(np.mean(pred["direct_white"], axis=-1)
                        / np.mean(pred["full_white"], axis=-1), 0.0, 1.0)
        ti, to = direct_light_geometry(ref.angle_deg)
        err_d = np.zeros_like(ref.radiance)
        for pi, p in enumerate(ref.patches):
            k = fit_key(p)
            for ai in range(ref.angle_deg.size):
                e = fit_error_at(fits[k], data[k], float(ti[ai]), float(to[ai]))
                err_d[pi, ai] = np.interp(ref.wavelength_nm, data[k].wavelength_nm, e)
        e_wall = fit_error_at(fits["wall"], data["wall"], -70.0, 80.0)
        err_i = np.interp(ref.wavelength_nm, data["wall"].wavelength_nm, e_wall)
        em = error_model(share, np.nan_to_num(err_d), np.nan_to_num(err_i)[None, None, :],
                         ref.angle_deg, reference=ref.radiance, observed_nrmse=result.nrmse)
        em.store(store, name, run_ref=run_id)
    return result


# --- report --------------------------------------------------------------------------------------

def report_run(store: Store, ref_run: int | str, path: str | Path | None = None,
               brdf_run: int | str | None = None, notes: Iterable[str] = (),
               renderer: str | None = None) -> Path:
    """The HTML report of a reference run (`analyze.report_store` gathers its data);
    `renderer`: built on an imported renderer's comparison instead of ours."""
    from normbox_lab.analyze.report import write_report
    from normbox_lab.analyze.report_store import report_data_from_store

    rd = report_data_from_store(store, ref_run, brdf_run, notes, renderer=renderer)
    out = Path(path) if path else Path(f"report-run-{store.get_run(ref_run).id}.html")
    return write_report(out, rd)


# --- virtual camera (the paper's Fig. 1) ---------------------------------------------------------

@dataclass
class CameraFigures:
    """What `camera_figures_run` made: ΔE00 statistics, the W&W estimate, files, artifacts."""

    patch: int
    angle_deg: float
    delta_e00: dict[str, float]
    ww_xy: tuple[float, float]
    gray_world_xy: tuple[float, float]
    files: dict[str, Path]
    artifact_ids: list[int]
    render_s: float


def _share_above(de_map: np.ndarray, nf_map: np.ndarray, mask: np.ndarray,
                 factor: float = 3.0) -> float:
    """Share of the box's pixels whose block ΔE00 exceeds `factor` × the block's own noise
    floor (the statement the Fig. 1 caption makes)."""
    m = mask & np.isfinite(de_map) & np.isfinite(nf_map)
    return float(np.mean(de_map[m] > factor * nf_map[m])) if m.any() else float("nan")


def camera_figures_run(store: Store, ref_run: int | str, *, patch: int = 7,
                       angle_deg: float = 45.0, truth: str = "default", lamp: Any = None,
                       geometry: Any = None, width: int = 320, height: int = 240,
                       spp: int | None = None, seed: int = 1, w: float = 2.0,
                       out_dir: str | Path = "images", exr: bool = True,
                       cache_dir: str | Path | None = None) -> CameraFigures:
    """The box seen from its open side with the truth materials and with the fitted ones (the
    paper's Fig. 1), the per-pixel ΔE00 map, and the Wilkie–Weidlich white balance of both
    previews; stored as ``image-figure`` artifacts of the reference run (``fig-camera``,
    ``fig-whitebalance``: the report and the TUI show them) and written to `out_dir` as PNGs
    and (with `exr`) the truth image as a multilayer spectral OpenEXR.

    Both images use one lamp (`lamp`, e.g. from the light map) and the same seed (common
    random numbers), so the map shows the materials' fit, not the lamp or the noise.  Both
    previews get the Bradford adaptation of the *truth* image's W&W estimate, so they stay
    comparable.  `cache_dir`: keep the renders there and read them back when nothing they
    depend on changed (`figure1.rendered_view`; the demo's render cache)."""
    from normbox_lab.images import figure1, normbox_view, whitebalance
    from normbox_lab.images.color import XYZ_to_srgb

    run_id = store.get_run(ref_run).id
    truth_mats, fitted_mats = _camera_materials(store, patch, truth)
    t0 = time.perf_counter()
    fig = figure1.figure1(truth_mats, fitted_mats, float(angle_deg), lamp=lamp, geometry=geometry,
                         width=width, height=height,
                         spp=spp if spp is not None else normbox_view.NORMBOX_DEFAULT_SPP, seed=seed,
                         cache_dir=cache_dir)
    render_s = time.perf_counter() - t0
    wl = fig.truth.wavelength_nm
    est = whitebalance.estimate_illuminant(fig.truth.cwni, fig.truth.nwci, w, wavelength_nm=wl)
    gw = whitebalance.gray_world_xy(fig.truth_XYZ)
    white_Y = float(fig.white_XYZ[1])
    balanced = [XYZ_to_srgb(whitebalance.adapt_to_display(x, est.illuminant_XYZ), white_Y)
                for x in (fig.truth_XYZ, fig.fitted_XYZ)]
    stats = _camera_stats(fig)
    where = f"patch {patch} at {float(angle_deg):g}°, {width}×{height} px, {fig.truth.spp} spp"
    figures = _camera_image_figures(fig, stats, est, gw, balanced, where, w)
    ids = [f.store(store, run_ref=run_id) for f in figures]
    stem = f"figure1-p{int(patch):02d}-{float(angle_deg):g}deg"
    files = _write_camera_files(Path(out_dir), stem, fig, balanced, est, white_Y, where, truth,
                                exr)
    return CameraFigures(int(patch), float(angle_deg), stats,
                         (float(est.illuminant_xy[0]), float(est.illuminant_xy[1])),
                         (float(gw[0]), float(gw[1])), files, ids, render_s)


def _camera_materials(store: Store, patch: int, truth: str
                      ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The truth materials and the fitted ones (latest fits) of the patch and the wall."""
    from normbox_lab.predict.materials import Material, holder_material, truth_patch, truth_wall

    fits = latest_fits(store)
    missing = [k for k in (fit_key(patch), "wall") if k not in fits]
    if missing:
        raise StoreError(f"no fits for {', '.join(missing)}: run `normbox-lab fit` first")
    holder = holder_material()
    truth_mats = {"patch": truth_patch(int(patch), truth), "wall": truth_wall(truth),
                  "holder": holder}
    fitted_mats = {"patch": Material.from_fit(fits[fit_key(patch)]),
                   "wall": Material.from_fit(fits["wall"]), "holder": holder}
    return truth_mats, fitted_mats


def _camera_stats(fig: Any) -> dict[str, float]:
    """The figure's ΔE00 summary, the region means (ΔE00 of the mean XYZ per material: free
    of most Monte-Carlo noise) and the convergence figures (``converged_*``)."""
    from normbox_lab.images.color import delta_e00_map

    stats = fig.summary()
    for region in ("patch", "wall"):
        m = fig.truth.mask(region)
        if np.any(m):
            stats[f"{region}_region"] = float(delta_e00_map(
                fig.truth_XYZ[m].mean(axis=0), fig.fitted_XYZ[m].mean(axis=0), fig.white_XYZ))
    stats.update({f"converged_{k}": v for k, v in fig.noise_summary().items()})
    return stats


def _camera_image_figures(fig: Any, stats: dict[str, float], est: Any, gw: Any,
                          balanced: list[Any], where: str, w: float) -> list[Any]:
    """``fig-camera`` (truth, prediction, ΔE00 and noise-floor maps) and ``fig-whitebalance``."""
    from normbox_lab.analyze.report_data import ImageFigure, ImagePanel

    conv = {k.removeprefix("converged_"): v for k, v in stats.items()
            if k.startswith("converged_")}
    de_map = fig.delta_e00_blocks if fig.delta_e00_blocks is not None else fig.delta_e00
    nf_map = (fig.noise_floor_blocks if fig.noise_floor_blocks is not None
              else np.full(de_map.shape, np.nan))
    finite = de_map[np.isfinite(de_map)]
    vmax = max(1.0, float(np.percentile(finite, 99.0))) if finite.size else 5.0
    return [
        ImageFigure("fig-camera", "Virtual camera: truth vs prediction (paper Fig. 1)",
                    f"The Normbox seen from its open side, {where}: truth materials, fitted "
                    "materials (same lamp, same random numbers), the ΔE00 between them and, "
                    "beside it, the Monte-Carlo noise floor on the same scale. Both maps are "
                    f"unbiased region means ({conv['block_px']:.0f}×{conv['block_px']:.0f} px "
                    "blocks, averaged within one material only; XYZ normalised by the white "
                    "patch at 30° as in the tables, Lab D65). The noise floor is measured: "
                    "ΔE00 between the truth and an independent second truth render, median "
                    f"{conv['noise_median']:.2f}, 95th percentile {conv['noise_p95']:.2f}. "
                    "Differences well above it are real: over the box surfaces ΔE00 mean "
                    f"{conv['mean']:.2f}, 95th percentile {conv['p95']:.2f}, max "
                    f"{conv['max']:.2f}; {100 * _share_above(de_map, nf_map, fig.scene_mask):.0f}"
                    " % of the surface exceeds 3× its own noise floor (block by block), "
                    f"{100 * conv['share_above_noise']:.0f} % exceeds 3× the noise floor's "
                    f"95th percentile (ΔE00 > {3 * conv['noise_p95']:.2f}). Region means: patch "
                    f"{stats.get('patch_region', np.nan):.2f}, wall "
                    f"{stats.get('wall_region', np.nan):.2f}. Previews white-balanced by "
                    f"Wilkie & Weidlich (w = {w:g}) from the truth image.",
                    [ImagePanel("truth", balanced[0]),
                     ImagePanel("prediction (fits)", balanced[1]),
                     ImagePanel("ΔE00, region means", de_map, vmax=vmax, unit="ΔE00"),
                     ImagePanel("noise floor", nf_map, vmax=vmax, unit="ΔE00")], where),
        ImageFigure("fig-whitebalance", "Wilkie & Weidlich white balance of the truth image",
                    f"Left: the raw rendering (scaled to the white patch, no adaptation: the "
                    f"lamp's colour shows); middle: the 1−Chroma weights from the CWNI image "
                    f"(w = {w:g}); right: Bradford-adapted from the W&W estimate xy = "
                    f"({est.illuminant_xy[0]:.4f}, {est.illuminant_xy[1]:.4f}) to D65 "
                    f"(plain gray world on the raw image: ({gw[0]:.4f}, {gw[1]:.4f})).",
                    [ImagePanel("raw", fig.truth_srgb),
                     ImagePanel("1 − Chroma", est.one_minus_chroma, vmax=1.0),
                     ImagePanel("W&W balanced", balanced[0])], where),
    ]


def _write_camera_files(out: Path, stem: str, fig: Any, balanced: list[Any], est: Any,
                        white_Y: float, where: str, truth: str, exr: bool) -> dict[str, Path]:
    """The PNGs (truth, fitted, ΔE00, raw truth) and, with `exr`, the truth as a multilayer
    spectral OpenEXR with its white-balanced preview."""
    from normbox_lab.images import whitebalance
    from normbox_lab.images.color import write_png

    files = {"truth_png": write_png(out / f"{stem}-truth.png", balanced[0]),
             "fitted_png": write_png(out / f"{stem}-fitted.png", balanced[1]),
             "delta_e00_png": write_png(out / f"{stem}-delta-e00.png", fig.delta_e_rgb()),
             "raw_png": write_png(out / f"{stem}-truth-raw.png", fig.truth_srgb)}
    if exr:
        import colour

        from normbox_lab.core.exr import write_spectral_exr

        linear = np.clip(whitebalance.adapt_to_display(fig.truth_XYZ, est.illuminant_XYZ)
                         / white_Y, 0.0, None)
        preview = colour.XYZ_to_RGB(linear, colour.RGB_COLOURSPACES["sRGB"],
                                    apply_cctf_encoding=False)
        files["truth_exr"] = write_spectral_exr(
            out / f"{stem}-truth.exr", fig.truth, preview_rgb=preview,
            extra_spectral={"emission": fig.truth.emission},     # the layers sum to radiance
            attributes={"normbox.scene": where, "normbox.materials": f"truth ({truth})"})
    return files
