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

from normbox_lab.acquire.store_api import Store
from normbox_lab.analyze.queries import fit_key, latest_fits, reference_data, white_index
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
    from normbox_lab.analyze.fit import data_from_store_run, fit_material

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
    fits = {}
    for k, name in enumerate(sorted(data)):
        progress("fit", k, len(data))
        fit = fit_material(data[name], w)
        fit.metadata.update(qa.provenance(accepted))
        fit.store(store, run_ref=brdf_run)
        fits[name] = fit
    from normbox_lab.predict.brdf_model import MaterialFit

    latest = {a.name: a for a in store.artifacts("fit", run_ref=brdf_run)}
    qa.check_fits(store, brdf_run,
                  {n: (a.id, MaterialFit.from_artifact(a)) for n, a in latest.items()})
    progress("fit", len(data), len(data))
    return fits


# --- predict -------------------------------------------------------------------------------------

def predict_run(store: Store, ref_run: int | str, *, fits: dict[str, Any] | None = None,
                geometry: Any = None, quality: str = "default", lamp: Any = None,
                render: Callable[..., Any] | None = None,
                progress: ProgressFn = _noop, accept_flagged: bool = False,
                executor: Any = None) -> int:
    """Render every patch × angle of the reference run with the fitted materials.  Error
    flags on the reference run or on the (stored) fits used are refused unless
    `accept_flagged`.

    `executor` (an `executors.make_executor(...)`: in process, or a dask cluster): predict all
    patch × angle configurations with the fast band-vector renderer
    (`fastrender.predict_spectra`) as independent jobs on it, at the relative standard error
    of `quality` (`FAST_TARGET_REL_SE`); the results do not depend on the executor.  Without
    one, each configuration goes through `render` (default: the stock Mitsuba renderer)."""
    from normbox_lab.analyze import qa
    from normbox_lab.predict.materials import Material, holder_material
    from normbox_lab.predict.render import render_view

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
    render = render or render_view
    wall = Material.from_fit(fits["wall"])
    holder = holder_material()
    n_p, n_a = len(ref.patches), ref.angle_deg.size
    out = np.zeros((n_p, n_a, ref.wavelength_nm.size))
    err = np.zeros_like(out)
    total, done, t0 = n_p * n_a + n_a, 0, time.perf_counter()
    renderer = "fastrender"             # the band-vector renderer, unless a render says other
    if executor is not None:
        from normbox_lab.predict.fastrender import FAST_TARGET_REL_SE, predict_spectra

        progress("predict", done, total)
        mats = {fit_key(p): Material.from_fit(fits[fit_key(p)]) for p in ref.patches}
        pred = predict_spectra(mats, ref.angle_deg, wall=wall, holder=holder, lamp=lamp,
                               geometry=geometry, target_rel_se=FAST_TARGET_REL_SE[quality],
                               seed=1, executor=executor)
        for pi, p in enumerate(ref.patches):
            for ai, a in enumerate(ref.angle_deg):
                rad, se = pred.spectrum(fit_key(p), float(a))
                out[pi, ai] = np.interp(ref.wavelength_nm, pred.wavelength_nm, rad)
                err[pi, ai] = np.interp(ref.wavelength_nm, pred.wavelength_nm, se)
        done = n_p * n_a
        if render is render_view:              # the light shares with the same renderer
            from normbox_lab.predict.fastrender import FastNormbox

            fast = FastNormbox(geometry)

            def render(geometry, *, patch, wall, holder, angle_deg, lamp=None, quality=None,
                       direct_only=False):
                return fast.render_view(patch=patch, wall=wall, holder=holder,
                                        angle_deg=angle_deg, lamp=lamp, seed=1,
                                        target_rel_se=FAST_TARGET_REL_SE[quality or "default"],
                                        direct_only=direct_only)
    else:
        for pi, p in enumerate(ref.patches):
            mat = Material.from_fit(fits[fit_key(p)])
            for ai, a in enumerate(ref.angle_deg):
                progress("predict", done, total)
                r = render(geometry, patch=mat, wall=wall, holder=holder, angle_deg=float(a),
                           lamp=lamp, quality=quality)
                out[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.radiance)
                err[pi, ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.std_error)
                renderer = str(r.info.get("renderer", "mitsuba"))
                done += 1
    # direct-only renders of the white patch (or the first) for the light shares per angle
    wp = ref.patches[white_index(ref.patches)]
    wmat = Material.from_fit(fits[fit_key(wp)])
    direct = np.zeros((n_a, ref.wavelength_nm.size))
    for ai, a in enumerate(ref.angle_deg):
        progress("predict", done, total)
        r = render(geometry, patch=wmat, wall=wall, holder=holder, angle_deg=float(a),
                   lamp=lamp, quality=quality, direct_only=True)
        direct[ai] = np.interp(ref.wavelength_nm, r.wavelength_nm, r.radiance)
        done += 1
    progress("predict", total, total)
    aid = store.add_artifact(
        "prediction", f"ref-run-{store.get_run(ref_run).id}",
        {"wavelength_nm": ref.wavelength_nm, "angle_deg": ref.angle_deg,
         "patches": np.array(ref.patches, dtype=float), "radiance": out, "std_error": err,
         "direct_white": direct, "full_white": out[ref.patches.index(wp)]},
        metadata={"quality": quality, "white_patch": wp, "renderer": renderer,
                  "executor": getattr(executor, "name", None) or "none",
                  "render_s": time.perf_counter() - t0,
                  "fits": {n: fits[n].name for n in need}, **qa.provenance(accepted)},
        run_ref=ref_run)
    qa.check_prediction(store, ref_run, aid, ref.patches, ref.angle_deg, out, err)
    return aid


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
                       out_dir: str | Path = "images", exr: bool = True) -> CameraFigures:
    """The box seen from its open side with the truth materials and with the fitted ones (the
    paper's Fig. 1), the per-pixel ΔE00 map, and the Wilkie–Weidlich white balance of both
    previews; stored as ``image-figure`` artifacts of the reference run (``fig-camera``,
    ``fig-whitebalance``: the report and the TUI show them) and written to `out_dir` as PNGs
    and (with `exr`) the truth image as a multilayer spectral OpenEXR.

    Both images use one lamp (`lamp`, e.g. from the light map) and the same seed (common
    random numbers), so the map shows the materials' fit, not the lamp or the noise.  Both
    previews get the Bradford adaptation of the *truth* image's W&W estimate, so they stay
    comparable."""
    from normbox_lab.analyze.report_data import ImageFigure, ImagePanel
    from normbox_lab.images import figure1, normbox_view, whitebalance
    from normbox_lab.images.color import XYZ_to_srgb, delta_e00_map, write_png
    from normbox_lab.predict.materials import Material, holder_material, truth_patch, truth_wall

    run_id = store.get_run(ref_run).id
    fits = latest_fits(store)
    missing = [k for k in (fit_key(patch), "wall") if k not in fits]
    if missing:
        raise StoreError(f"no fits for {', '.join(missing)}: run `normbox-lab fit` first")
    holder = holder_material()
    truth_mats = {"patch": truth_patch(int(patch), truth), "wall": truth_wall(truth),
                  "holder": holder}
    fitted_mats = {"patch": Material.from_fit(fits[fit_key(patch)]),
                   "wall": Material.from_fit(fits["wall"]), "holder": holder}
    t0 = time.perf_counter()
    fig = figure1.figure1(truth_mats, fitted_mats, float(angle_deg), lamp=lamp, geometry=geometry,
                         width=width, height=height,
                         spp=spp if spp is not None else normbox_view.NORMBOX_DEFAULT_SPP, seed=seed)
    render_s = time.perf_counter() - t0
    wl = fig.truth.wavelength_nm
    est = whitebalance.estimate_illuminant(fig.truth.cwni, fig.truth.nwci, w, wavelength_nm=wl)
    gw = whitebalance.gray_world_xy(fig.truth_XYZ)
    white_Y = float(fig.white_XYZ[1])
    balanced = [XYZ_to_srgb(whitebalance.adapt_to_display(x, est.illuminant_XYZ), white_Y)
                for x in (fig.truth_XYZ, fig.fitted_XYZ)]
    stats = fig.summary()
    # region means are free of most Monte-Carlo noise: ΔE00 of the mean XYZ per material
    for region in ("patch", "wall"):
        m = fig.truth.mask(region)
        if np.any(m):
            stats[f"{region}_region"] = float(delta_e00_map(
                fig.truth_XYZ[m].mean(axis=0), fig.fitted_XYZ[m].mean(axis=0), fig.white_XYZ))
    where = f"patch {patch} at {float(angle_deg):g}°, {width}×{height} px, {fig.truth.spp} spp"
    conv = fig.noise_summary()
    stats.update({f"converged_{k}": v for k, v in conv.items()})
    de_map = fig.delta_e00_blocks if fig.delta_e00_blocks is not None else fig.delta_e00
    nf_map = (fig.noise_floor_blocks if fig.noise_floor_blocks is not None
              else np.full(de_map.shape, np.nan))
    finite = de_map[np.isfinite(de_map)]
    vmax = max(1.0, float(np.percentile(finite, 99.0))) if finite.size else 5.0
    figures = [
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
    ids = [f.store(store, run_ref=run_id) for f in figures]
    out = Path(out_dir)
    stem = f"figure1-p{int(patch):02d}-{float(angle_deg):g}deg"
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
    return CameraFigures(int(patch), float(angle_deg), stats,
                         (float(est.illuminant_xy[0]), float(est.illuminant_xy[1])),
                         (float(gw[0]), float(gw[1])), files, ids, render_s)
