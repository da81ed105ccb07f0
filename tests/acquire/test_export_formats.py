"""Exports other tools read: NetCDF with CF units/long_name and an integer patch coordinate;
a CSV with one row per reading (every value kept, metadata once per reading)."""

from __future__ import annotations

import csv

import numpy as np

from normbox_lab.acquire.export import export_csv, export_run
from normbox_lab.acquire.store import Store
from normbox_lab.core.types import SpectralReading

WL = np.arange(380.0, 781.0)
META = {"patch_name": "dark skin", "segment": 1, "lamp_monitor_cd_m2": 1998.36,
        "colorimetry": {"X": 40.035, "Y": 30.486, "Z": 6.6161, "cct_K": 1950.0},
        "model": "CS-1000A", "time_mode": "auto"}


def _sweep(store: Store, patches=(1, 2, 3), angles=(30.0, 60.0)) -> int:
    run = store.create_run("reference-sweep", status="running")
    rng = np.random.default_rng(1)
    for a in angles:
        for p in patches:
            rad = rng.uniform(1e-5, 1e-3, WL.size)
            store.add_spectral(run.id, f"a{a:g}/p{p:02d}",
                               SpectralReading(WL, rad, None, 1.5, 1.7e9, "radiometer"),
                               {**META, "patch": p, "angle_deg": a})
    store.set_run_status(run.id, "done")
    return run.id


def test_netcdf_has_cf_units_long_names_and_an_integer_patch_coordinate(tmp_path):
    import xarray as xr

    with Store(tmp_path / "s.sqlite") as store:
        run = _sweep(store)
        nc = export_run(store, run, "netcdf", tmp_path / "o.nc")
        rows = list(store.readings(run))
    ds = xr.open_dataset(nc, decode_times=False)
    assert ds.attrs["Conventions"].startswith("CF-")
    assert ds["patch"].dtype == np.int64 and ds["patch"].values.tolist() == [1, 2, 3] * 2
    assert ds["patch"].attrs["long_name"].startswith("ColorChecker patch number")
    rad = ds["spectral_radiance_W_sr_m2_nm"]
    assert rad.attrs == {"units": "W sr-1 m-2 nm-1",
                         "long_name": "spectral radiance (spectral readings)"}
    assert ds["spectral_wavelength_nm"].attrs["units"] == "nm"
    assert ds["spectral_angle_deg"].attrs["units"] == "degree"
    assert ds["spectral_time_s"].attrs["units"] == "seconds since 1970-01-01 00:00:00"
    assert ds["spectral_colorimetry_cct_K"].attrs["units"] == "K"
    for name in ds.variables:                       # every one, coordinates included
        assert "long_name" in ds[name].attrs, name
    np.testing.assert_array_equal(rad.values[4], rows[4].arrays["radiance_W_sr_m2_nm"])
    # CF time decoding works on the epoch seconds
    assert np.issubdtype(xr.open_dataset(nc)["spectral_time_s"].dtype, np.datetime64)


def test_csv_one_row_per_reading_loses_nothing_and_is_small(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        run = _sweep(store)
        wide = export_run(store, run, "csv", tmp_path / "o.csv")
        long = export_csv(store, run, tmp_path / "long.csv", layout="long")
        rows = list(store.readings(run))
    with open(wide, newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows) == 6
    for r, line in zip(rows, table):
        back = np.array([float(line[f"radiance_W_sr_m2_nm[{w:g}]"]) for w in WL])
        np.testing.assert_array_equal(back, r.arrays["radiance_W_sr_m2_nm"])   # exact
        assert int(line["patch"]) == r.metadata["patch"]
        assert float(line["colorimetry_cct_K"]) == 1950.0
    # the long layout repeats every metadata column on each of the 401 rows of a spectrum
    assert len(long.read_text().splitlines()) == 1 + 6 * WL.size
    assert wide.stat().st_size < long.stat().st_size / 5
