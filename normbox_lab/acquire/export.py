"""Exports of a stored run: NetCDF (through xarray), CSV (long, tidy), JSON.

NetCDF layout: one dimension per reading kind (``spectral``, ``brdf``, ...), holding the
reading keys; arrays of equal shape within a kind become variables ``<kind>_<array>`` over
(``<kind>``, ``<kind>_<array>_<axis>``...); a ``wavelength_nm`` array that is the same for every
reading of a kind becomes the coordinate ``<kind>_wavelength_nm``; scalar metadata become
coordinates along the reading dimension.  Run provenance goes into global attributes.
"""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.acquire.store import Store, StoredReading
from normbox_lab.core.errors import StoreError

FORMATS = ("netcdf", "csv", "json")
SUFFIX = {"netcdf": ".nc", "csv": ".csv", "json": ".json"}


def _scalar_metadata(r: StoredReading) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in r.metadata.items():
        if isinstance(v, dict):
            for k2, v2 in v.items():
                if isinstance(v2, (int, float, str, bool)):
                    out[f"{k}_{k2}"] = v2
        elif isinstance(v, (int, float, str, bool)):
            out[k] = v
    return out


def _run_attrs(store: Store, run_ref: int | str) -> dict[str, Any]:
    run = store.get_run(run_ref)
    return {"run_id": run.id, "run_uuid": run.uuid, "protocol": run.protocol,
            "status": run.status, "code_version": run.code_version,
            "parameters": json.dumps(run.parameters, sort_keys=True),
            "seeds": json.dumps(run.seeds, sort_keys=True), "lab_config": run.lab_config,
            "instruments": json.dumps(store.instruments(run.id), sort_keys=True)}


def export_netcdf(store: Store, run_ref: int | str, path: Path) -> Path:
    import xarray as xr

    by_kind: dict[str, list[StoredReading]] = defaultdict(list)
    for r in store.readings(run_ref):
        by_kind[r.kind].append(r)
    ds = xr.Dataset(attrs=_run_attrs(store, run_ref))
    for kind, rows in by_kind.items():
        ds.coords[kind] = np.array([r.key for r in rows], dtype=object)
        ds.coords[f"{kind}_time_s"] = (kind, np.array([r.time_s for r in rows]))
        ds.coords[f"{kind}_instrument"] = (kind, np.array([r.instrument for r in rows],
                                                          dtype=object))
        meta = [_scalar_metadata(r) for r in rows]
        for name in sorted({k for m in meta for k in m}):
            vals = [m.get(name) for m in meta]
            if all(isinstance(v, (int, float, bool)) and v is not None for v in vals):
                ds.coords[f"{kind}_{name}"] = (kind, np.array(vals, dtype=float))
            else:
                ds.coords[f"{kind}_{name}"] = (kind, np.array(
                    ["" if v is None else str(v) for v in vals], dtype=object))
        names = sorted({n for r in rows for n in r.arrays})
        wl_dim = None
        if all("wavelength_nm" in r.arrays for r in rows):
            first = rows[0].arrays["wavelength_nm"]
            if all(r.arrays["wavelength_nm"].shape == first.shape
                   and np.array_equal(r.arrays["wavelength_nm"], first) for r in rows):
                wl_dim = f"{kind}_wavelength_nm"
                ds.coords[wl_dim] = first
        for name in names:
            if name == "wavelength_nm" and wl_dim:
                continue
            arrs = [r.arrays.get(name) for r in rows]
            shapes = {a.shape for a in arrs if a is not None}
            if len(shapes) != 1:
                continue  # ragged: left to CSV/JSON
            shape = shapes.pop()
            stacked = np.stack([a if a is not None else np.full(shape, np.nan) for a in arrs])
            dims = [kind]
            for axis, n in enumerate(shape):
                dims.append(wl_dim if (wl_dim and axis == len(shape) - 1 and
                                       n == ds.sizes[wl_dim]) else f"{kind}_{name}_{axis}")
            ds[f"{kind}_{name}"] = (tuple(dims), stacked)
    ds.to_netcdf(path, engine="netcdf4")
    return path


def export_csv(store: Store, run_ref: int | str, path: Path) -> Path:
    """Long format: one row per reading × array element; 1-D arrays along wavelength_nm share
    a row per wavelength."""
    rows: list[dict[str, Any]] = []
    for r in store.readings(run_ref):
        base = {"key": r.key, "kind": r.kind, "instrument": r.instrument, "time_s": r.time_s,
                **_scalar_metadata(r)}
        wl = r.arrays.get("wavelength_nm")
        along = {n: a for n, a in r.arrays.items()
                 if wl is not None and n != "wavelength_nm" and a.shape == wl.shape}
        for i in range(0 if wl is None else len(wl)):
            rows.append({**base, "wavelength_nm": wl[i], **{n: a[i] for n, a in along.items()}})
        for n, a in r.arrays.items():
            if n == "wavelength_nm" or n in along:
                continue
            for idx, v in np.ndenumerate(a):
                rows.append({**base, "array": n, "index": ",".join(map(str, idx)), "value": v})
    fieldnames: list[str] = []
    for row in rows:
        for k in row:
            if k not in fieldnames:
                fieldnames.append(k)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=fieldnames)
        w.writeheader()
        w.writerows(rows)
    return path


def export_json(store: Store, run_ref: int | str, path: Path) -> Path:
    run = store.get_run(run_ref)
    doc = {"run": {**_run_attrs(store, run.id), "parameters": run.parameters,
                   "seeds": run.seeds, "instruments": store.instruments(run.id),
                   "planned": run.planned, "events": [
                       {"time_s": t, "kind": k, "detail": d} for t, k, d in store.events(run.id)]},
           "readings": [{"key": r.key, "kind": r.kind, "instrument": r.instrument,
                         "time_s": r.time_s, "metadata": r.metadata,
                         "arrays": {n: a.tolist() for n, a in r.arrays.items()}}
                        for r in store.readings(run.id)]}
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


def export_run(store: Store, run_ref: int | str, fmt: str, path: str | Path | None = None) -> Path:
    """Export one run.  The store is checked first (a damaged store is refused, not exported
    in part); the file is written next to its destination and renamed into place only when
    complete, with as many readings as the store counts for the run."""
    if fmt not in FORMATS:
        raise StoreError(f"unknown export format {fmt!r}; choose {', '.join(FORMATS)}")
    run = store.get_run(run_ref)
    problems = store.quick_check()
    if problems:
        raise StoreError(f"{store.path}: the store is damaged ({problems[0]}); nothing exported")
    out = Path(path) if path else Path(f"run-{run.id}-{run.protocol}{SUFFIX[fmt]}")
    if out.is_dir():
        raise StoreError(f"cannot write {out}: it is a directory")
    tmp = out.with_name(f".{out.stem}.partial{out.suffix}")
    try:
        exported = {"netcdf": export_netcdf, "csv": export_csv,
                    "json": export_json}[fmt](store, run.id, tmp)
        count = sum(1 for _ in store.readings(run.id))
        if count != run.done:
            raise StoreError(f"run {run.id}: {count} readings readable of {run.done} stored; "
                             "the store is damaged; nothing exported")
        exported.replace(out)
    except OSError as exc:
        raise StoreError(f"cannot write {out}: {exc.strerror or exc}") from None
    finally:
        tmp.unlink(missing_ok=True)
    return out
