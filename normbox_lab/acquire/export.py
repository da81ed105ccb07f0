"""Exports of a stored run: NetCDF (through xarray), CSV (long, tidy), JSON.

NetCDF layout: one dimension per reading kind (``spectral``, ``brdf``, ...), holding the
reading keys; arrays of equal shape within a kind become variables ``<kind>_<array>`` over
(``<kind>``, ``<kind>_<array>_<axis>``...); a ``wavelength_nm`` array that is the same for every
reading of a kind becomes the coordinate ``<kind>_wavelength_nm``; scalar metadata become
coordinates along the reading dimension (integers stay integers: ``patch`` is an integer
coordinate, named plainly ``patch`` when one reading kind carries it).  Every variable and
coordinate has CF ``units`` (UDUNITS spelling, from the unit in its name: ``_nm``, ``_deg``,
``_W_sr_m2_nm``, ``_per_sr``…; epoch times as "seconds since 1970-01-01 00:00:00") and a
``long_name``.  Run provenance goes into global attributes (``Conventions = "CF-1.10"``).

CSV layout: one row per reading (its key, kind, instrument, time and scalar metadata), then one
column per wavelength for every array along a wavelength grid the kind's readings share
(``radiance_W_sr_m2_nm[380]``…); other arrays as a JSON list in one cell.  The tidy long layout
(one row per reading × wavelength, every metadata column repeated on each of the 401 rows of a
spectrum) made a 312-reading reference sweep 29 MB; this one is about 1.9 MB (6.2 kB per reading) and loses nothing
(`export_csv(..., layout="long")` still writes the long one).
"""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.acquire.store import Store, StoredReading
from normbox_lab.core.errors import BadPath, StoreError

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


#: CF units (UDUNITS) of the unit suffixes this project puts in names, longest first
_UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_W_sr_m2_nm", "W sr-1 m-2 nm-1"), ("_W_sr_m2", "W sr-1 m-2"), ("_cd_m2", "cd m-2"),
    ("_per_sr", "sr-1"), ("_nm", "nm"), ("_deg", "degree"), ("_mm", "mm"), ("_K", "K"),
    ("_s", "s"), ("_pct", "percent"))
_LONG_NAMES = {
    "wavelength_nm": "wavelength", "radiance_W_sr_m2_nm": "spectral radiance",
    "brdf_per_sr": "bidirectional reflectance distribution function", "patch":
    "ColorChecker patch number (1-24)", "angle_deg": "sample angle (0 = facing the light, "
    "90 = facing the radiometer)", "theta_i_deg": "incident polar angle (signed, in plane)",
    "theta_o_deg": "outgoing polar angle (signed, in plane)", "time_s": "time of the reading",
    "instrument": "instrument that took the reading", "integration_time_s": "integration time",
    "raw_counts": "raw detector counts"}


def _cf_attrs(name: str, kind: str | None = None) -> dict[str, str]:
    """CF `units` and `long_name` of a variable or coordinate named `name` (maybe prefixed
    with its reading kind)."""
    base = name[len(kind) + 1:] if kind and name.startswith(kind + "_") else name
    if base == "time_s":
        units = "seconds since 1970-01-01 00:00:00"
    else:
        units = next((u for suffix, u in _UNIT_SUFFIXES if base.endswith(suffix)), "1")
    if kind and base == kind:
        return {"long_name": f"reading key ({kind} readings)"}
    long_name = _LONG_NAMES.get(base)
    if long_name is None:
        stem = base
        for suffix, _ in _UNIT_SUFFIXES:
            if stem.endswith(suffix) and len(stem) > len(suffix):
                stem = stem[: -len(suffix)]
                break
        long_name = stem.replace("_", " ")
    if kind:
        long_name = f"{long_name} ({kind} readings)"
    return {"units": units, "long_name": long_name}


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


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
        patch_kinds = [k for k, rr in by_kind.items()
                       if any("patch" in _scalar_metadata(r) for r in rr)]
        for name in sorted({k for m in meta for k in m}):
            vals = [m.get(name) for m in meta]
            if all(_is_int(v) for v in vals):
                cname = "patch" if name == "patch" and patch_kinds == [kind] \
                    else f"{kind}_{name}"
                ds.coords[cname] = (kind, np.array(vals, dtype=np.int64))
            elif all(isinstance(v, (int, float, bool)) and v is not None for v in vals):
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
        for name in [n for n in ds.variables if n == kind or str(n).startswith(kind + "_")
                     or (n == "patch" and patch_kinds == [kind])]:
            attrs = _cf_attrs("patch" if name == "patch" else str(name), kind)
            if name == "patch":
                attrs["long_name"] = _LONG_NAMES["patch"]
            ds[name].attrs.update(attrs)
    ds.attrs["Conventions"] = "CF-1.10"
    ds.attrs["title"] = f"normbox-lab run {ds.attrs['run_id']} ({ds.attrs['protocol']})"
    ds.to_netcdf(path, engine="netcdf4")
    return path


def export_csv(store: Store, run_ref: int | str, path: Path, layout: str = "wide") -> Path:
    """One row per reading, a column per wavelength (module docstring); `layout="long"`: one
    row per reading × array element, 1-D arrays along wavelength_nm sharing a row per
    wavelength."""
    if layout == "wide":
        return _export_csv_wide(store, run_ref, path)
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


def _shared_grid(rows: list[StoredReading]) -> np.ndarray | None:
    if not rows or not all("wavelength_nm" in r.arrays for r in rows):
        return None
    first = rows[0].arrays["wavelength_nm"]
    if all(np.array_equal(r.arrays["wavelength_nm"], first) for r in rows):
        return first
    return None


def _export_csv_wide(store: Store, run_ref: int | str, path: Path) -> Path:
    by_kind: dict[str, list[StoredReading]] = defaultdict(list)
    for r in store.readings(run_ref):
        by_kind[r.kind].append(r)
    grids = {k: _shared_grid(rows) for k, rows in by_kind.items()}
    out_rows: list[dict[str, Any]] = []
    for kind, rows in by_kind.items():
        wl = grids[kind]
        for r in rows:
            row: dict[str, Any] = {"key": r.key, "kind": r.kind, "instrument": r.instrument,
                                   "time_s": repr(float(r.time_s)), **_scalar_metadata(r)}
            for n, a in r.arrays.items():
                if wl is not None and n == "wavelength_nm":
                    continue
                if wl is not None and a.ndim == 1 and a.shape == wl.shape:
                    row.update({f"{n}[{w:g}]": repr(float(v)) for w, v in zip(wl, a)})
                else:
                    row[n] = json.dumps(np.asarray(a).tolist())
            out_rows.append(row)
    fieldnames: list[str] = []
    seen: set[str] = set()
    for row in out_rows:
        for k in row:
            if k not in seen:
                seen.add(k)
                fieldnames.append(k)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=fieldnames)
        w.writeheader()
        w.writerows(out_rows)
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
        raise BadPath(f"cannot write {out}: it is a directory")
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
    except RuntimeError as exc:        # netCDF4/HDF5 report a full disk as "NetCDF: HDF error"
        raise StoreError(f"cannot write {out}: {exc} (is the disk full?); nothing "
                         "exported") from None
    finally:
        tmp.unlink(missing_ok=True)
    return out
