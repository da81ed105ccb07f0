import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from normbox_lab.acquire.export import export_run
from normbox_lab.acquire.importers import load_brdf_json, parse_brdf_json, store_brdf
from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import DataError

WL = [400.0, 500.0, 600.0]


def _doc(n=3):
    return [{"wavelengths": WL}] + [
        {"thetaIn": 30.0, "phiIn": 180.0, "thetaOut": float(t), "phiOut": 0.0,
         "spectrum": [0.1 * (i + 1), 0.2, 0.3]} for i, t in enumerate(range(0, 10 * n, 10))]


def test_valid_document_round_trips_through_store_and_exports(tmp_path):
    path = tmp_path / "patch-7.json"
    path.write_text(json.dumps(_doc()))
    data = load_brdf_json(path)
    assert data.material == "patch-7"
    assert data.theta_i_deg.tolist() == [-30.0, -30.0, -30.0]   # φ=180 → signed negative
    assert data.theta_o_deg.tolist() == [0.0, 10.0, 20.0]
    assert data.brdf_per_sr.shape == (3, 3)
    with Store(tmp_path / "s.sqlite") as store:
        run_id = store_brdf(store, data, tilt_deg=4.0)
        rows = list(store.readings(run_id, "brdf"))
        assert len(rows) == 3 and rows[1].metadata["theta_o_deg"] == 10.0
        assert np.allclose(rows[0].arrays["brdf_per_sr"], [0.1, 0.2, 0.3])
        nc = export_run(store, run_id, "netcdf", tmp_path / "o.nc")
        js = export_run(store, run_id, "json", tmp_path / "o.json")
        cs = export_run(store, run_id, "csv", tmp_path / "o.csv")
    import xarray as xr

    ds = xr.load_dataset(nc)
    assert ds["brdf_brdf_per_sr"].shape == (3, 3)
    assert ds["brdf_wavelength_nm"].values.tolist() == WL
    assert ds["brdf_theta_o_deg"].values.tolist() == [0.0, 10.0, 20.0]
    assert json.loads(js.read_text())["readings"][2]["arrays"]["brdf_per_sr"][0] == 0.1 * 3
    assert len(cs.read_text().splitlines()) == 1 + 3          # one row per reading


@pytest.mark.parametrize("mutate,where", [
    (lambda d: d.__setitem__(0, {"wl": WL}), "element 0"),
    (lambda d: d[0].__setitem__("wavelengths", [500.0, 400.0]), "element 0: wavelengths"),
    (lambda d: d[2].pop("thetaOut"), "element 2"),
    (lambda d: d[2].__setitem__("thetaOut", "ten"), "element 2: thetaOut"),
    (lambda d: d[1].__setitem__("thetaIn", 95.0), "element 1: thetaIn"),
    (lambda d: d[3]["spectrum"].pop(), "element 3: spectrum"),
    (lambda d: d[3]["spectrum"].__setitem__(1, None), "element 3: spectrum[1]"),
    (lambda d: d.append(dict(d[1])), "element 4"),
])
def test_malformed_documents_name_the_place(mutate, where):
    doc = _doc()
    mutate(doc)
    with pytest.raises(DataError) as info:
        parse_brdf_json(doc, "f.json")
    assert info.value.location == where and str(info.value).startswith(f"f.json: {where}:")


def test_not_json_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("[{\"wavelengths\": [1, 2,")
    with pytest.raises(DataError, match="not valid JSON"):
        load_brdf_json(bad)
    with pytest.raises(DataError, match="cannot read"):
        load_brdf_json(tmp_path / "none.json")


json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda children: st.lists(children, max_size=4) |
    st.dictionaries(st.sampled_from(["wavelengths", "thetaIn", "phiIn", "thetaOut", "phiOut",
                                     "spectrum", "x"]), children, max_size=6),
    max_leaves=30)


@settings(max_examples=300, deadline=None)
@given(json_values)
def test_any_json_value_gives_data_or_a_data_error(doc):
    try:
        parse_brdf_json(doc, "fuzz.json")
    except DataError as err:
        assert err.file == "fuzz.json" and err.location


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_on_disk_give_data_or_a_data_error(tmp_path_factory, raw):
    path = tmp_path_factory.mktemp("fz") / "x.json"
    path.write_bytes(raw)
    try:
        load_brdf_json(path)
    except DataError as err:
        assert err.file == str(path)


def _doc_of(geoms):
    return [{"wavelengths": [400.0, 500.0]}] + [
        {"thetaIn": ti, "phiIn": 0, "thetaOut": to, "phiOut": 0, "spectrum": [0.1, 0.2]}
        for ti, to in geoms]


def test_near_duplicate_geometry_is_refused_before_any_write(tmp_path):
    path = tmp_path / "near.json"
    path.write_text(json.dumps(_doc_of([(30, 10), (30, 20), (30, 20.01)])))
    with pytest.raises(DataError, match="duplicates element 2"):
        load_brdf_json(path)
    with Store(tmp_path / "s.sqlite") as store:
        assert store.runs() == []


def test_failed_import_leaves_no_half_run(tmp_path):
    from normbox_lab.acquire.importers import ImportedBrdf
    from normbox_lab.core.errors import StoreError

    bad = ImportedBrdf("m", np.array([400.0, 500.0]), np.array([30.0, 30.0]),
                       np.array([20.0, 20.0]), np.ones((2, 2)))      # same key twice
    with Store(tmp_path / "s.sqlite") as store:
        with pytest.raises(StoreError):
            store_brdf(store, bad)
        assert store.runs() == []


def test_geometry_count_is_refused_before_decoding(tmp_path, monkeypatch):
    from normbox_lab.acquire import importers

    monkeypatch.setattr(importers, "MAX_GEOMETRIES", 50)
    path = tmp_path / "many.json"
    path.write_text(json.dumps(_doc_of([(30, t / 10) for t in range(60)])))
    with pytest.raises(DataError, match="refused before decoding"):
        load_brdf_json(path)


def test_huge_integer_is_a_data_error(tmp_path):
    path = tmp_path / "big.json"
    path.write_text('[{"wavelengths": [400, 500]}, {"thetaIn": 1' + "0" * 400 +
                    ', "phiIn": 0, "thetaOut": 20, "phiOut": 0, "spectrum": [0.1, 0.2]}]')
    with pytest.raises(DataError, match="out of range|finite"):
        load_brdf_json(path)
