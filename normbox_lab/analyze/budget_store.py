"""The error budget of a stored campaign: its inputs read from the store (reference,
prediction, error model, the renderer's derivatives), the budget stored back as an
``error-budget`` artifact, and the paper-scenario observations of docs/error-budget.md."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.analyze.budget import (
    BUDGET_SOURCES,
    BudgetInputs,
    BudgetResult,
    common_draws,
    compute_budget,
    errors_for_run,
    independent_draws,
)


def truth_render_rel_se(lab_config_text: str, errors: Any = None) -> float:
    """The truth's own Monte-Carlo noise (largest band relative SE) of a virtual run: the
    `render` source if on, else the lab config's ``[render] truth_rel_se`` (the demo writes
    it); 0 for a measured truth."""
    import tomllib

    if errors is not None and errors.render_rel_se:
        return float(errors.render_rel_se)
    try:
        render_cfg = tomllib.loads(lab_config_text or "").get("render", {})
    except tomllib.TOMLDecodeError:
        return 0.0
    return float(render_cfg.get("truth_rel_se", 0.0) or 0.0)


def is_fast_renderer(metadata: dict) -> bool:
    """Whether a stored prediction came from the fast band-vector renderer: "fastrender" (the
    plain tracer), "fastrender-qmc" (one configuration by randomised QMC, since 2026-11-25)
    or "fastrender-patchset" (all patches per path).  Every path carries every band, so its
    noise is one draw for all bands of a configuration, and it was rendered to
    `FAST_TARGET_REL_SE`.  (Compared with "fastrender" alone, the budget took the QMC
    prediction's noise as independent per band and its truth's noise at the stated target, 3x
    the achieved at 30-65°: 36 of 264 null configurations marked, 28 of 96 at 70-90°.)"""
    return str(metadata.get("renderer", "")).startswith("fastrender")


#: the artifact kind of the truth's achieved render noise of a virtual reference sweep
TRUTH_SE_KIND = "truth-render-se"


def record_truth_se(store: Store, run_id: int, patches: list[int], angle_deg: np.ndarray,
                    wavelength_nm: np.ndarray, relative_se: np.ndarray) -> int:
    """Store the truth's Monte-Carlo noise as the virtual Normbox's renders achieved it
    ([patch, angle, λ] relative standard error of each configuration's render; the world's
    `truth_relative_se`) with its reference sweep, for the budget's `render` term."""
    return store.add_artifact(
        kind=TRUTH_SE_KIND, name=f"ref-run-{run_id}",
        arrays={"patches": np.asarray(patches, dtype=float),
                "angle_deg": np.asarray(angle_deg, dtype=float),
                "wavelength_nm": np.asarray(wavelength_nm, dtype=float),
                "relative_std_error": np.asarray(relative_se, dtype=float)},
        metadata={"what": "the truth render's relative standard error per configuration, "
                          "as achieved"}, run_ref=run_id)


def truth_se_of_run(store: Store, run_id: int, patches: list[int], angle_deg: np.ndarray,
                    reference: np.ndarray, wavelength_nm: np.ndarray) -> np.ndarray | None:
    """The truth's achieved standard error [patch, angle, λ] (W·sr⁻¹·m⁻²·nm⁻¹: the stored
    relative SE times the reference), or None where it was not recorded: a measured truth,
    a store from before it was recorded, or a configuration the record lacks (then the
    budget models the term from the stated target, `truth_rel_se`)."""
    from normbox_lab.core.errors import StoreError

    try:
        arrays = store.latest_artifact(TRUTH_SE_KIND, f"ref-run-{run_id}").arrays
    except StoreError:
        return None
    rec_p = [int(p) for p in arrays["patches"]]
    rec_a = [round(float(a), 1) for a in arrays["angle_deg"]]
    rel = np.asarray(arrays["relative_std_error"], dtype=float)
    out = np.zeros(np.shape(reference))
    for i, p in enumerate(patches):
        for j, a in enumerate(angle_deg):
            if int(p) not in rec_p or round(float(a), 1) not in rec_a:
                return None
            row = rel[rec_p.index(int(p)), rec_a.index(round(float(a), 1))]
            if not np.all(np.isfinite(row)):
                return None
            out[i, j] = np.interp(wavelength_nm, arrays["wavelength_nm"], row)
    return out * np.asarray(reference, dtype=float)


def _prediction_target(metadata: dict) -> float:
    """The fast renderer's target (largest band relative SE) of a stored prediction; 0 for
    another renderer."""
    if not is_fast_renderer(metadata):
        return 0.0
    from normbox_lab.predict.fastrender import FAST_TARGET_REL_SE

    return float(FAST_TARGET_REL_SE.get(str(metadata.get("quality")), 0.0))


def budget_inputs_run(store: Store, ref_run: int | str, *, n_paths: int = 1 << 14,
                      with_geometry: bool = True,
                      progress: Callable[[str, int, int], None] | None = None,
                      renderer: str | None = None
                      ) -> tuple[BudgetInputs, dict[str, float]]:
    """Reference, prediction, fit error model and the renderer's derivatives of a stored
    reference sweep (after `predict` and `compare`); `renderer`: an imported renderer's
    prediction (`predict.renderers`) and its error model instead of ours."""
    import time

    from normbox_lab.acquire.config import parse_config
    from normbox_lab.acquire.queries import (
        fit_key,
        lamp_from_light_map,
        latest_fits,
        latest_run,
        reference_data,
        white_index,
    )
    from normbox_lab.analyze.budget_derivatives import render_derivatives
    from normbox_lab.core.errors import StoreError
    from normbox_lab.predict.materials import Material
    from normbox_lab.predict.renderers import artifact_name

    run = store.get_run(ref_run)
    ref = reference_data(store, run.id)
    name = artifact_name(run.id, renderer)
    try:
        pred_artifact = store.latest_artifact("prediction", name)
        pred = pred_artifact.arrays
    except (KeyError, LookupError, StoreError) as exc:
        raise StoreError(f"run {run.id} has no prediction: run `normbox-lab predict` "
                         f"first ({exc})") from exc
    try:
        fit_nse = store.latest_artifact("error-model", name).arrays[
            "simulated_nse"]
        fit_nse = np.broadcast_to(fit_nse, ref.radiance.shape).copy()
    except (KeyError, LookupError, StoreError):
        fit_nse = None
    fits = latest_fits(store)
    geometry = parse_config(run.lab_config, f"run {run.id} lab config").geometry \
        if run.lab_config else None
    light = latest_run(store, "light-map")
    lamp = lamp_from_light_map(store, light.id if light is not None else None)
    mats = [Material.from_fit(fits[fit_key(p)]) for p in ref.patches]
    white = white_index(ref.patches)
    t0 = time.perf_counter()
    der = render_derivatives(mats, Material.from_fit(fits["wall"]), ref.angle_deg,
                             ref.wavelength_nm, geometry=geometry, lamp=lamp,
                             white=mats[white], n_paths=n_paths, with_geometry=with_geometry,
                             progress=progress)
    timings = {"derivatives": time.perf_counter() - t0}
    x = BudgetInputs(ref.wavelength_nm, ref.angle_deg, list(ref.patches), ref.radiance,
                     pred["radiance"], pred["std_error"], der["d_angle"],
                     der.get("d_geometry_rel", {}), der.get("d_homogeneity_rel"), fit_nse,
                     white, truth_rel_se=truth_render_rel_se(run.lab_config),
                     render_noise_correlated=is_fast_renderer(pred_artifact.metadata),
                     prediction_rel_se=_prediction_target(pred_artifact.metadata),
                     truth_se=truth_se_of_run(store, run.id, list(ref.patches), ref.angle_deg,
                                              ref.radiance, ref.wavelength_nm))
    return x, timings


def budget_run(store: Store, ref_run: int | str, *, sources: str | None = None,
               n_paths: int = 1 << 14, n_draws: int = 64,
               progress: Callable[[str, int, int], None] | None = None,
               renderer: str | None = None) -> BudgetResult:
    """The error budget of a stored reference sweep; stored as artifact "error-budget"
    (``ref-run-<id>@<renderer>`` for an imported renderer's prediction)."""
    import time

    from normbox_lab.acquire.queries import reference_data
    from normbox_lab.analyze.angles import estimate_angle_offsets
    from normbox_lab.predict.renderers import artifact_name

    run = store.get_run(ref_run)
    errors = errors_for_run(run.lab_config, sources)
    names = list(BUDGET_SOURCES)
    if sources and all("=" not in s for s in sources.split(",")):
        names = [n for n in BUDGET_SOURCES if n in {s.strip() for s in sources.split(",")}]
    need_geometry = any(errors.is_on(n) for n in ("geometry", "homogeneity"))
    x, timings = budget_inputs_run(store, run.id, n_paths=n_paths,
                                   with_geometry=need_geometry, progress=progress,
                                   renderer=renderer)
    t0 = time.perf_counter()
    offsets = estimate_angle_offsets(x.reference, x.prediction, x.d_angle, x.angle_deg,
                                     common=common_draws(x, errors, sources=names),
                                     independent=independent_draws(x, errors, sources=names))
    offsets.readback_deg = reference_data(store, run.id).readback_offset_deg()
    result = compute_budget(x, errors, sources=names, n_draws=n_draws, angle_offsets=offsets)
    timings["propagation"] = time.perf_counter() - t0
    result.timings_s = timings
    result.store(store, artifact_name(run.id, renderer), run_ref=run.id)
    return result


# --- the paper's observations, measured on a campaign ------------------------------------------
def paper_observations(store: Store, ref_run: int | str,
                       brdf_data: tuple[int, dict[str, Any]] | None = None
                       ) -> list[tuple[str, str, str]]:
    """(observation, the paper's value, ours) for the paper-scenario table of
    docs/error-budget.md, from a compared reference run (and its gonio run's fits).
    `brdf_data`: (gonio run id, its `fit.data_from_store_run`) when the caller has read it
    (the report), used when that run is the latest gonio run (the one this table reads)."""
    from normbox_lab.acquire.queries import latest_fits
    from normbox_lab.analyze.compare import ComparisonResult

    run = store.get_run(ref_run)
    c = ComparisonResult.from_artifact(store.latest_artifact("comparison", f"ref-run-{run.id}"))
    fits = latest_fits(store)
    return (_nrmse_rows(c) + _correlation_rows(c) + _fit_rows(fits) + _delta_e_rows(c)
            + _wall_nse_rows(store, c, fits, brdf_data) + _neighbour_rows(c)
            + _offset_rows(store, run.id))


def _paper(label: str) -> str:
    """The paper's column, read from the one table of the paper's figures."""
    from normbox_lab.analyze.paper_figures import OBSERVATIONS, quote

    return quote(OBSERVATIONS[label])


def _nrmse_rows(c: Any) -> list[tuple[str, str, str]]:
    """NRMSE at 30–60° against the paper's [2, 5] %, and NRMSE by angle."""
    ang = c.angle_deg
    small = (ang >= 30) & (ang <= 60)
    nr = 100 * c.nrmse
    label = "NRMSE at 30–60° within [2, 5] %"
    if np.any(small):
        in_band = np.mean((nr[:, small] >= 2) & (nr[:, small] <= 5))
        rows = [(label, _paper(label), (f"{100 * in_band:.0f} % of configurations "
                                        f"(median {np.median(nr[:, small]):.1f} %)"))]
    else:
        rows = [(label, _paper(label), "not measured")]
    by = np.mean(nr, axis=0)
    label = "NRMSE by angle, mean over patches (%)"
    rows.append((label, _paper(label), ", ".join(f"{a:g}° {v:.1f}" for a, v in zip(ang, by))))
    return rows


def _correlation_rows(c: Any) -> list[tuple[str, str, str]]:
    """The correlations of radiance with the NRMSE and the RMSE."""
    from normbox_lab.analyze.paper_figures import signed

    cr = c.correlations

    def r(key: str, sign: str = "") -> str:
        value = float(cr.get(key, float("nan")))
        return signed(value, 2, plus=bool(sign)) if np.isfinite(value) else "not measured"

    label_nrmse = "r(radiance, NRMSE) 65–90°"
    label_rmse = "r(radiance, RMSE) 30–60° / 65–90°"
    return [(label_nrmse, _paper(label_nrmse), r("radiance_nrmse_large", "+")),
            (label_rmse, _paper(label_rmse),
             f"{r('radiance_rmse_small')} / {r('radiance_rmse_large')}")]


def _fit_rows(fits: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The BRDF fit errors: the patches' spread, patch 18 and the wall."""
    errs = {k: float(v.fit_error_pct) for k, v in fits.items()
            if np.isfinite(float(v.fit_error_pct))}
    patch_errs = [v for k, v in errs.items() if k.startswith("p") and k != "p18"]

    def fit_error(name: str) -> str:
        # a material the gonio run did not measure (or whose fit has no error) is named so,
        # never printed as "nan %"
        return f"{errs[name]:.1f} %" if name in errs else "not measured"
    spread = (f"{min(patch_errs):.1f}–{max(patch_errs):.1f} %" if patch_errs
              else "patches not measured")
    return [("BRDF fit errors", _paper("BRDF fit errors"),
             f"{spread}, patch 18 {fit_error('p18')}, wall {fit_error('wall')}")]


def _delta_e_rows(c: Any) -> list[tuple[str, str, str]]:
    """ΔE00: the share below 2 (and 1), the maximum and the patches above 2."""
    de = c.delta_e00
    above2 = sorted({int(c.patch_names[p].split()[0]) for p, _ in zip(*np.nonzero(de > 2))})
    return [("ΔE00", _paper("ΔE00"),
             (f"{100 * np.mean(de < 2):.0f} % < 2 ({100 * np.mean(de < 1):.0f} % < 1), "
              f"max {np.max(de):.2f}; > 2: {', '.join(map(str, above2)) or 'none'}"))]


def _wall_nse_rows(store: Store, c: Any, fits: dict[str, Any],
                   brdf_data: tuple[int, dict[str, Any]] | None = None
                   ) -> list[tuple[str, str, str]]:
    """The NSE at 90° (paper's sign) against the wall's fit error at (−70°, 80°), over λ."""
    from normbox_lab.acquire.queries import latest_run
    from normbox_lab.analyze.fit import data_from_store_run, fit_error_at
    from normbox_lab.analyze.paper_figures import nse_paper_sign, signed

    ang = c.angle_deg
    brdf = latest_run(store, "brdf-inplane")
    if brdf is None or "wall" not in fits:
        return []
    data = brdf_data[1] if brdf_data is not None and brdf_data[0] == brdf.id \
        else data_from_store_run(store, brdf.id)
    if "wall" not in data or not np.any(np.isclose(ang, 90.0)):
        return []
    e = fit_error_at(fits["wall"], data["wall"], -70.0, 80.0)
    e = np.interp(c.wavelength_nm, data["wall"].wavelength_nm, e)
    # the paper's NSE sign (reference − prediction); the fit error (fit − measured)
    nse90 = nse_paper_sign(np.nanmean(c.nse[:, int(np.argmin(np.abs(ang - 90))), :], axis=0))
    ok = np.isfinite(nse90) & np.isfinite(e)
    r = float(np.corrcoef(nse90[ok], e[ok])[0, 1])
    label = "NSE (paper's sign) at 90° vs wall fit error at (−70°, 80°), r over λ"
    return [(label, _paper(label),
             (f"{signed(r, 2)} (NSE 450 / 700 nm: "
              f"{signed(100 * np.interp(450, c.wavelength_nm, nse90), 1)} / "
              f"{signed(100 * np.interp(700, c.wavelength_nm, nse90), 1)} %)"))]


def _neighbour_rows(c: Any) -> list[tuple[str, str, str]]:
    """The NSE at 65° and 80° minus its neighbours' mean (the paper's sign)."""
    from normbox_lab.analyze.paper_figures import nse_paper_sign, signed

    ang = c.angle_deg
    # in the paper's sign: its NSE is (reference − prediction) / reference, ours the opposite
    nse_mean = 100 * nse_paper_sign(np.nanmean(c.nse, axis=(0, 2)))
    rows = []
    for a in (65.0, 80.0):
        i = int(np.argmin(np.abs(ang - a)))
        if 0 < i < ang.size - 1 and abs(ang[i] - a) < 1e-6:
            dev = nse_mean[i] - 0.5 * (nse_mean[i - 1] + nse_mean[i + 1])
            label = f"NSE (paper's sign) at {a:g}° minus its neighbours' mean"
            rows.append((label, _paper(label),
                         (f"{signed(dev, 1)} % (patches with the sign of the mean: "
                          f"{_same_sign(c.nse, i):.0f} %)")))
    return rows


def _offset_rows(store: Store, run_id: int) -> list[tuple[str, str, str]]:
    """The angle offsets the latest error budget of the run estimated, 60–85°."""
    from normbox_lab.analyze.paper_figures import signed

    budgets = store.artifacts("error-budget", f"ref-run-{run_id}")
    if not budgets or "angle_offset_deg" not in budgets[-1].arrays:
        return []
    arr = budgets[-1].arrays
    label = "estimated angle offsets (budget)"
    return [(label, _paper(label), ", ".join(
        f"{a:g}° {signed(o, 2)} ± {ci:.2f}" for a, o, ci in zip(
            arr["angle_offset_angle_deg"], arr["angle_offset_deg"],
            arr["angle_offset_ci95_deg"]) if a in (60, 65, 70, 75, 80, 85)))]


def _same_sign(nse: np.ndarray, i: int) -> float:
    per_patch = np.nanmean(nse, axis=2)
    dev = per_patch[:, i] - 0.5 * (per_patch[:, i - 1] + per_patch[:, i + 1])
    return 100 * float(np.mean(np.sign(dev) == np.sign(np.mean(dev))))
