"""MIST metameric spectra (normbox_lab.images.metamer), checked independently with colour-science."""

from __future__ import annotations

import subprocess
import sys

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from normbox_lab.images import metamer as m

_CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
_D65 = colour.SDS_ILLUMINANTS["D65"]
_D65_XY = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]


def delta_e00(srgb8: np.ndarray, wavelength_nm: np.ndarray, reflectance: np.ndarray) -> np.ndarray:
    """ΔE00 between sRGB colours (n, 3) in 0–255 and reflectances (n, B) seen under D65 (CIE 1931
    2°, Y of the perfect white = 1), Lab relative to D65 — all through colour-science."""
    shape = colour.SpectralShape(float(wavelength_nm[0]), float(wavelength_nm[-1]),
                                 float(wavelength_nm[1] - wavelength_nm[0]))
    msds = colour.MultiSpectralDistributions(np.atleast_2d(reflectance).T, wavelength_nm)
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        XYZ = colour.msds_to_XYZ(msds, _CMFS, _D65, method="Integration", shape=shape) / 100.0
    ref = colour.sRGB_to_XYZ(np.asarray(srgb8, dtype=float) / 255.0)
    return colour.delta_E(colour.XYZ_to_Lab(XYZ, _D65_XY), colour.XYZ_to_Lab(ref, _D65_XY),
                          method="CIE 2000")


@pytest.fixture(scope="module")
def db() -> m.MetamerDatabase:
    return m.MetamerDatabase.default()


@pytest.fixture(scope="module")
def colorchecker_db() -> m.MetamerDatabase:
    """A deliberately sparse database (24 ColorChecker patches): small xy hull, peak ≤ 0.9."""
    wl = np.arange(380.0, 781.0, 5.0)
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    spectra = np.array([np.interp(wl, sd.wavelengths, sd.values) for sd in sds.values()])
    return m.MetamerDatabase.from_spectra(wl, spectra, list(sds))


def test_import_is_cheap() -> None:
    code = ("import sys, normbox_lab.images.metamer; "
            "print(any(k in sys.modules for k in ('colour', 'scipy.spatial', 'mitsuba')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_srgb_matrix_matches_iec_and_colour_science() -> None:
    iec = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    assert np.array_equal(m.srgb_to_XYZ_matrix(), iec)
    rgb = np.array([[0.2, 0.5, 0.9], [1.0, 1.0, 1.0], [0.01, 0.03, 0.04]])
    assert np.allclose(m.linear_srgb_to_XYZ(m.srgb_decode(rgb)), colour.sRGB_to_XYZ(rgb), atol=1e-6)


def test_database_contents(db: m.MetamerDatabase) -> None:
    assert db.wavelength_nm[0] == 380.0 and db.wavelength_nm[-1] == 780.0
    assert np.all(np.diff(db.wavelength_nm) == 5.0)
    assert db.spectra.shape == (len(db.names), 81) and len(db.names) >= 120
    assert db.spectra.min() >= 0.0 and db.spectra.max() <= 1.0
    assert db.xy.shape == (len(db.names), 2)
    sources = {name.split("/")[0] for name in db.names}
    assert {"ColorChecker N Ohta", "TCS CIE 1995", "VS NIST CQS 9.0", "Smits 1999",
            "Mallett 2019", "Otsu 2018 cluster mean", "PMC"} <= sources
    # XYZ under D65 matches colour-science's own integration of the same spectra
    shape = colour.SpectralShape(380.0, 780.0, 5.0)
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        XYZ = colour.msds_to_XYZ(colour.MultiSpectralDistributions(db.spectra.T, db.wavelength_nm),
                                 _CMFS, _D65, method="Integration", shape=shape) / 100.0
    assert np.allclose(XYZ, db.XYZ, atol=1e-9)


def test_database_is_cached_on_disk(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NORMBOX_LAB_CACHE", str(tmp_path))
    m._default_database.cache_clear()
    try:
        first = m.MetamerDatabase.default()
        files = list(tmp_path.glob("metamer_db_v*_380_780_5nm.npz"))
        assert len(files) == 1
        m._default_database.cache_clear()
        second = m.MetamerDatabase.default()  # read back from the file
        assert np.array_equal(first.spectra, second.spectra) and first.names == second.names
        assert np.array_equal(first.XYZ, second.XYZ)
    finally:
        m._default_database.cache_clear()


def _grid(step: int) -> np.ndarray:
    levels = np.arange(0, 256, step)
    return np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)


def test_blend_reproduces_srgb_grid_within_de00_1(db: m.MetamerDatabase) -> None:
    colours = np.vstack([_grid(51), [[255, 255, 255], [255, 0, 0], [0, 255, 0], [0, 0, 255],
                                     [255, 255, 0], [1, 1, 1], [254, 1, 128]]])
    assert all(m.in_range(c, database=db) for c in colours)
    spectra = db.texture(colours[:, None, :].astype(np.uint8))[:, 0, :]
    assert spectra.min() >= 0.0 and spectra.max() <= 1.0
    de = delta_e00(colours, db.wavelength_nm, spectra)
    assert np.nanmax(de) < 1.0, f"worst ΔE00 {np.max(de):.3f} at {colours[np.argmax(de)]}"
    assert np.max(de) < 0.1  # exact-XYZ blends: what remains is colour-science vs our matrix


@settings(max_examples=60, deadline=None)
@given(st.tuples(*(st.integers(0, 255),) * 3))
def test_blend_reproduces_any_8bit_colour(rgb: tuple[int, int, int]) -> None:
    db = m.MetamerDatabase.default()
    wl, reflectance = m.metamer_for_srgb(rgb, database=db)
    assert reflectance.min() >= 0.0 and reflectance.max() <= 1.0
    sd = colour.SpectralDistribution(reflectance, wl)
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        XYZ = colour.sd_to_XYZ(sd, _CMFS, _D65) / 100.0  # colour-science's ASTM E308 path
    ref = colour.sRGB_to_XYZ(np.array(rgb) / 255.0)
    de = colour.delta_E(colour.XYZ_to_Lab(XYZ, _D65_XY), colour.XYZ_to_Lab(ref, _D65_XY),
                        method="CIE 2000")
    assert de < 1.0


def test_mist_nearest_is_a_scaled_database_spectrum(db: m.MetamerDatabase) -> None:
    rgb = (180, 90, 60)
    _, spectrum = m.metamer_for_srgb(rgb, method="nearest", database=db)
    target = colour.sRGB_to_XYZ(np.array(rgb) / 255.0)
    xy_target = target[:2] / target.sum()
    i = int(np.argmin(np.linalg.norm(db.xy - xy_target, axis=1)))
    scale = target[1] / db.XYZ[i, 1]
    assert np.allclose(spectrum, db.spectra[i] * scale, atol=1e-5)
    assert np.isclose(spectrum @ db.xyz_weights[1], target[1], atol=1e-5)  # Y matched


def test_cache_hits_return_identical_arrays(db: m.MetamerDatabase) -> None:
    _, a = m.metamer_for_srgb((12, 200, 77), database=db)
    _, b = m.metamer_for_srgb(np.array([12, 200, 77], dtype=np.uint8), database=db)
    assert a is b and not a.flags.writeable
    _, c = m.metamer_for_srgb((0.25, 0.5, 0.75), database=db)
    _, d = m.metamer_for_srgb([0.25, 0.5, 0.75], database=db)
    assert c is d
    assert not np.array_equal(a, c)


def test_texture_equals_per_colour_path() -> None:
    rng = np.random.default_rng(7)
    palette = rng.integers(0, 256, (40, 3), dtype=np.uint8)
    image = palette[rng.integers(0, 40, (24, 32))]  # repeated colours
    fresh = m.MetamerDatabase.default()
    fresh._cache.clear()
    tex = m.metamers_for_texture(image, database=fresh)
    assert tex.shape == (24, 32, 81)
    fresh._cache.clear()
    per_colour = np.array([[m.metamer_for_srgb(px, database=fresh)[1] for px in row]
                           for row in image])
    assert np.array_equal(tex, per_colour)
    float_image = image.astype(np.float64) / 255.0
    tex_f = m.metamers_for_texture(float_image, database=fresh)
    per_f = np.array([[m.metamer_for_srgb(px, database=fresh)[1] for px in row]
                      for row in float_image])
    assert np.array_equal(tex_f, per_f)


def test_one_nm_database(db: m.MetamerDatabase) -> None:
    fine = m.MetamerDatabase.default(step_nm=1)
    assert fine.wavelength_nm.size == 401 and fine.spectra.shape[0] == db.spectra.shape[0]
    colours = np.array([[200, 30, 40], [30, 160, 210], [240, 240, 230], [90, 60, 30]])
    spectra = fine.texture(colours[None].astype(np.uint8))[0]
    assert np.max(delta_e00(colours, fine.wavelength_nm, spectra)) < 1.0


def test_sparse_database_blend_still_within_de00_1(colorchecker_db: m.MetamerDatabase) -> None:
    db = colorchecker_db
    assert db.srgb_basis is None  # no physical sRGB basis inside 24 patches
    # grid inside the ColorChecker hull at moderate Y, where plain nearest misses badly
    colours = _grid(32)
    inside = colours[[m.in_range(c, database=db) for c in colours]]
    assert len(inside) >= 20
    blend = db.texture(inside[:, None, :].astype(np.uint8))[:, 0, :]
    nearest = db.texture(inside[:, None, :].astype(np.uint8), method="nearest", strict=False)[:, 0]
    de_blend = delta_e00(inside, db.wavelength_nm, blend)
    de_nearest = delta_e00(inside, db.wavelength_nm, nearest)
    assert np.max(de_blend) < 1.0
    assert np.median(de_nearest) > 1.0  # why the blend exists


def test_out_of_range_colours(colorchecker_db: m.MetamerDatabase) -> None:
    db = colorchecker_db
    too_bright = (255, 255, 255)  # the ColorChecker white peaks at ≈ 0.89
    outside_hull = (0, 0, 255)  # pure sRGB blue: outside the 24 patches' xy hull
    for rgb in (too_bright, outside_hull):
        assert not m.in_range(rgb, database=db)
        with pytest.raises(m.MetamerRangeError, match="out of the metamer database's range"):
            m.metamer_for_srgb(rgb, database=db)
        _, approx = m.metamer_for_srgb(rgb, database=db, strict=False)  # MIST nearest, clipped
        assert approx.min() >= 0.0 and approx.max() <= 1.0
    with pytest.raises(m.MetamerRangeError):
        db.texture(np.array([[[120, 120, 120], [255, 255, 255]]], dtype=np.uint8))
    assert isinstance(m.MetamerRangeError("x"), ValueError)


def test_black_and_bad_inputs(db: m.MetamerDatabase) -> None:
    _, black = m.metamer_for_srgb((0, 0, 0), database=db)
    assert np.all(black == 0.0) and m.in_range((0, 0, 0), database=db)
    with pytest.raises(ValueError):
        m.metamer_for_srgb((0.5, 1.2, 0.0), database=db)
    with pytest.raises(ValueError):
        m.metamer_for_srgb((10, 20), database=db)
    with pytest.raises(ValueError):
        m.metamer_for_srgb((10, 20, 300), database=db)
    with pytest.raises(ValueError):
        m.metamers_for_texture(np.full((2, 2, 3), 1.5), database=db)
    with pytest.raises(ValueError):
        m.metamer_for_srgb((10, 20, 30), method="closest", database=db)  # type: ignore[arg-type]
