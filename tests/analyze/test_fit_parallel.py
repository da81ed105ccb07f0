"""`fit_materials` on two processes (this one and a child): the fits this process computes, bit for bit, handed on
in name order; unfittable data raise after the fits before them, as one after the other."""

import numpy as np
import pytest

from normbox_lab.analyze.fit import BrdfData, fit_material, fit_materials
from normbox_lab.core.errors import DataError
from normbox_lab.predict.brdf_model import ct_ggx_brdf, gonio_geometry, inplane_directions

WL = np.arange(380.0, 781.0, 5.0)
TI, TO = gonio_geometry()
WI, WO = inplane_directions(TI, TO, 4.0)


def _material(name: str, alpha: float, seed: int) -> BrdfData:
    rng = np.random.default_rng(seed)
    kd = 0.05 + 0.5 * np.exp(-((WL - 450.0 - 40 * seed) / 60.0) ** 2)
    ks = np.full(WL.shape, 0.05)
    y = ct_ggx_brdf(WI, WO, kd, ks, alpha, 1.5, 0.0) * (1 + 0.01 * rng.standard_normal(
        (TI.size, WL.size)))
    y[TI == TO] = np.nan
    return BrdfData(name, TI, TO, WL, y, 4.0)


def _same(a, b) -> None:
    assert (a.alpha, a.eta, a.c, a.cost, a.fit_error_pct) == (b.alpha, b.eta, b.c, b.cost,
                                                              b.fit_error_pct)
    np.testing.assert_array_equal(a.kd, b.kd)
    np.testing.assert_array_equal(a.ks, b.ks)


def test_two_processes_give_the_same_fits_bit_for_bit_in_name_order():
    data = {n: _material(n, a, k) for k, (n, a) in
            enumerate([("wall", 0.4), ("p02", 0.2), ("p01", 0.3), ("p03", 0.6)])}
    seen: list[str] = []
    fits = fit_materials(data, 2.0, children=1, on_fit=lambda name, fit: seen.append(name))
    assert seen == ["p01", "p02", "p03", "wall"]
    for name, d in data.items():
        _same(fits[name], fit_material(d, 2.0))


def test_unfittable_data_raise_after_the_fits_before_them():
    data = {"p01": _material("p01", 0.3, 1), "p03": _material("p03", 0.5, 3)}
    bad = _material("p02", 0.3, 2)
    bad.brdf_per_sr[:] = np.nan                      # no valid sample
    data["p02"] = bad
    seen: list[str] = []
    with pytest.raises(DataError, match="no valid samples"):
        fit_materials(data, 2.0, children=1, on_fit=lambda name, fit: seen.append(name))
    assert seen == ["p01"]
