"""Fill the report's `ReportData` from the store: the comparison, fits, error model, image
figures, the campaign's runs and instruments, quality flags, and the methods (software
versions, seeds, render quality, Monte-Carlo error).

Quality flags come from `normbox_lab.analyze.qa` (the store's flags table) for every run of
the campaign; the error budget from the latest ``error-budget`` artifact (`normbox-lab budget`).
"""

from __future__ import annotations

import datetime as dt
import platform
from collections.abc import Iterable
from importlib import metadata as importlib_metadata
from typing import Any

import numpy as np

from normbox_lab.acquire.queries import fit_key, latest_fits
from normbox_lab.acquire.store_api import Store
from normbox_lab.analyze.compare import ComparisonResult, ErrorModelResult
from normbox_lab.analyze.report_data import ImageFigure, ReportData
from normbox_lab.core.errors import StoreError

#: distributions whose versions the methods section lists (no import: metadata only)
SOFTWARE = ("normbox-lab", "numpy", "scipy", "colour-science", "mitsuba", "drjit",
            "matplotlib", "pyserial", "xarray")


def _date(wall_s: float | None) -> str:
    if wall_s is None:
        return ""
    return dt.datetime.fromtimestamp(float(wall_s), dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def software_versions() -> dict[str, str]:
    out = {"Python": platform.python_version()}
    for name in SOFTWARE:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def campaign_runs(store: Store, run_ids: Iterable[int]) -> list[dict[str, Any]]:
    rows = []
    for rid in run_ids:
        r = store.get_run(rid)
        rows.append({"id": r.id, "protocol": r.protocol, "status": r.status,
                     "readings": f"{r.done}/{r.planned}", "started": _date(r.created_s),
                     "finished": _date(r.finished_s), "date": _date(r.created_s)[:10],
                     "seeds": ", ".join(f"{k}={v}" for k, v in sorted(r.seeds.items()))
                     or "none recorded"})
    return rows


def campaign_instruments(store: Store, run_ids: Iterable[int]) -> list[dict[str, Any]]:
    """One row per distinct instrument (role, model, serial) with the runs that used it."""
    seen: dict[tuple[str, str, str], dict[str, Any]] = {}
    for rid in run_ids:
        for inst in store.instruments(rid):
            ident = inst["identity"]
            key = (inst["role"], str(ident.get("model", "")), str(ident.get("serial_number", "")))
            row = seen.get(key)
            cal = inst.get("calibration") or {}
            if row is None:
                cal_txt = "; ".join(f"{k}: {v}" for k, v in sorted(cal.items()))
                if "certificate" in cal:
                    cal_txt = f"{cal['certificate']}, due {cal['due']} (see Calibrations)"
                sim = " (emulated)" if ident.get("port", "").startswith("sim://") else ""
                row = seen[key] = {
                    "role": inst["role"], "model": f"{ident.get('model', '')}{sim}",
                    "serial": ident.get("serial_number") or "not reported by the device",
                    "firmware": ident.get("firmware") or "—",
                    "calibration": cal_txt or "none recorded in the store", "runs": []}
            if "certificate" in cal:
                _calibration_in_force(row, cal, store.get_run(rid))
            row["runs"].append(str(rid))
    for row in seen.values():
        row["runs"] = ", ".join(row["runs"])
    return list(seen.values())


def _calibration_in_force(row: dict[str, Any], cal: dict[str, Any], run: Any) -> None:
    """The calibration record a run stored with an instrument, with whether it was in force
    on the run's date (`row["calibration_record"]`, the report's Calibrations table)."""
    day = _date(run.created_s)[:10]
    record = row.setdefault("calibration_record", {**cal, "expired_in_runs": []})
    if day > str(cal["due"]):
        record["expired_in_runs"].append(f"{run.id} ({day})")


def quality_flags(store: Store, run_ids: Iterable[int]) -> list[Any]:
    """The quality flags (`analyze.qa.Flag`) of the runs."""
    from normbox_lab.analyze import qa

    return [f for rid in run_ids for f in qa.flags(store, rid)]


def prediction_methods(store: Store, run_id: int) -> dict[str, str]:
    """Render quality and Monte-Carlo error of the stored prediction, and what one standard
    error does to ΔE00 (computed once by `pipeline.compare_run`, read from the comparison)."""
    found = store.artifacts("prediction", f"ref-run-{run_id}")
    if not found:
        return {}
    a = found[-1]
    md = a.metadata
    out = {"prediction: render quality": str(md.get("quality", "?")),
           "prediction: render time": f"{float(md.get('render_s', np.nan)):.1f} s"}
    rad = np.asarray(a.arrays.get("radiance"))
    se = np.asarray(a.arrays.get("std_error"))
    if rad.size and se.shape == rad.shape:
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.nanmean(se, -1) / np.nanmean(rad, -1)
        out["prediction: Monte-Carlo standard error (spectral mean / mean radiance)"] = (
            f"median {100 * np.nanmedian(rel):.2f} %, max {100 * np.nanmax(rel):.2f} %")
    comparisons = store.artifacts("comparison", f"ref-run-{run_id}")
    shift = comparisons[-1].metadata.get("delta_e00_one_se_shift") if comparisons else None
    if shift:
        out["prediction: ΔE00 change for a one-standard-error shift"] = (
            f"median {float(shift['median']):.3f}, max {float(shift['max']):.3f}")
    return out


def report_data_from_store(store: Store, ref_run: int | str, brdf_run: int | str | None = None,
                           notes: Iterable[str] = (), renderer: str | None = None) -> ReportData:
    """Everything the report of reference run `ref_run` shows, from the store; `renderer`:
    the comparison of an imported renderer's prediction instead of ours."""
    from normbox_lab.predict.renderers import artifact_name

    run_id = store.get_run(ref_run).id
    comparison = ComparisonResult.from_artifact(
        store.latest_artifact("comparison", artifact_name(run_id, renderer)))
    em = None
    found = store.artifacts("error-model", artifact_name(run_id, renderer))
    if found:
        em = ErrorModelResult(**{k: np.asarray(v) for k, v in found[-1].arrays.items()})
    fits = latest_fits(store)
    data = {}
    brdf_id = store.get_run(brdf_run).id if brdf_run is not None else None
    if brdf_id is not None:
        from normbox_lab.analyze.fit import data_from_store_run

        data = data_from_store_run(store, brdf_id)
    patch_fit_names = [fit_key(n.split()[0]) for n in comparison.patch_names]
    latest_images = {a.name: a for a in store.artifacts("image-figure", run_ref=run_id)}
    images = [ImageFigure.from_artifact(a) for a in latest_images.values()]
    # the campaign: the BRDF run, light maps, and the reference run
    run_ids = sorted({r.id for r in store.runs()
                      if r.id in (run_id, brdf_id) or r.protocol == "light-map"})
    budgets = store.artifacts("error-budget", f"ref-run-{run_id}")
    budget = (budgets[-1].arrays, budgets[-1].metadata["sources"]) if budgets else None
    methods = {f"software: {k}": v for k, v in software_versions().items()}
    methods.update(prediction_methods(store, run_id))
    instruments = campaign_instruments(store, run_ids)
    from normbox_lab.analyze.report_renderers import renderer_rows, rendering_error

    rows = renderer_rows(store, run_id)
    rgb = [r.renderer for r in rows if "rgb" in (r.renderer + r.version).lower()]
    spectral = [r.renderer for r in rows if r.renderer != "normbox-lab"
                and "spectral" in (r.renderer + r.version).lower()]
    errors = [e for e in (rendering_error(store, run_id, spectral[0] if spectral else None, n)
                          for n in rgb) if e is not None]
    try:
        from normbox_lab.analyze.budget_store import paper_observations

        paper = paper_observations(store, run_id,
                                   (brdf_id, data) if brdf_id is not None else None)
    except (StoreError, KeyError, ValueError):
        paper = []
    return ReportData(
        simulated=any("(emulated)" in str(i.get("model", "")) for i in instruments)
        or "sim://" in store.get_run(run_id).lab_config,
        renderers=rows, rendering_errors=errors, paper=paper,
        comparison=comparison, fits=fits, brdf_data=data, error_model=em,
        title=f"Normbox validation report — reference run {run_id}"
        + (f", renderer {renderer}" if renderer else ""),
        polar_materials=[m for m in ("p08", "p18", "wall") if m in fits] or None,
        patch_fit_names=patch_fit_names, notes=list(notes), images=images,
        runs=campaign_runs(store, run_ids), instruments=instruments,
        flags=quality_flags(store, run_ids), budget=budget, methods=methods,
        metadata={"store": str(store.path), "reference run": run_id,
                  "BRDF run": brdf_id if brdf_id is not None else "—"})
