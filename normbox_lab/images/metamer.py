"""Metameric reflectance spectra for sRGB colours (MIST, Hao & Funt 2020, §V.A), plus a blend.

MIST's recipe: decode the sRGB transfer function, convert linear sRGB to XYZ with the sRGB matrix
(D65 white), take the chromaticity xy, find the database reflectance whose xy under D65 (CIE 1931
2°) is nearest (a KD-tree), and scale it so its Y matches the target. This module does exactly that
(`method="nearest"`) over every suitable reflectance set that colour-science ships (see
`DATABASE_SOURCES`), and adds one step beyond MIST because that database is sparse (~130 spectra,
MIST had 1,957): `method="blend"` (the default) finds the Delaunay triangle of database
chromaticities around the target and solves for the non-negative weights of those three spectra
whose blended XYZ equals the target XYZ exactly (chromaticity is a projective map, so a point
inside the triangle is a non-negative combination of the three XYZ vectors). Where that blend
would exceed reflectance 1 (bright colours) or the target lies outside the database's xy hull,
the spectrum moves along the segment towards a physical sRGB basis blend (`srgb_basis`, three
database blends for the sRGB primaries whose sum stays ≤ 1 — Mallett & Yuksel 2019's idea) just
far enough that every band is ≤ 1; both ends have the target XYZ (the basis to within its XYZ
residual, ≈ 2e-4 for the default database), so the result does too. For a
database without such a basis, a linear programme over the whole database finds the
non-negative blend with the target XYZ and the smallest peak reflectance.

Physical limits. A reflectance lies in [0, 1]; a colour is *in range* when some non-negative blend
of the database spectra reproduces its XYZ with peak ≤ 1 + `REFLECTANCE_TOLERANCE` (the excess,
at most 0.1 %, is clipped; it exists because the sRGB matrix white and the CIE-integrated D65
white differ in the fourth decimal). With the default database every sRGB colour in [0, 1]³ is
in range (through `srgb_basis`); with a sparser one (`MetamerDatabase.from_spectra`), colours outside the database's xy hull, or too bright for
any physical blend, raise `MetamerRangeError` (`strict=True`, the default); with `strict=False`
they get MIST's behaviour: the nearest spectrum scaled by Y, clipped to [0, 1] (documented as an
approximation, not a metamer).

Costs: the database (spectra, their XYZ and xy) is computed once with colour-science and cached
on disk under ``$NORMBOX_LAB_CACHE`` (default ``~/.cache/normbox-lab``); importing this module
imports only numpy. Each database keeps a hash cache (colour → spectrum) so repeated colours are
solved once, and `metamers_for_texture` solves each distinct colour of an image once.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from normbox_lab.core.errors import NormboxError
from normbox_lab.core.spectral import wavelengths_nm

Method = Literal["blend", "nearest"]

DATABASE_VERSION = 1
REFLECTANCE_TOLERANCE = 1e-3
"""Peak reflectance above 1 that is still accepted (and clipped to 1)."""
HULL_TOLERANCE = 1e-6
"""Barycentric tolerance at the edges of the database's xy hull (pure sRGB primaries sit on it)."""
BASIS_MAX_RESIDUAL_XYZ = 2e-3
"""Largest XYZ error of the physical sRGB basis (`MetamerDatabase.srgb_basis`) still accepted."""
CACHE_MAX_ENTRIES = 1 << 16
"""The per-database colour cache is cleared when it reaches this many entries (≈ 42 MB at 5 nm)."""

DATABASE_SOURCES: tuple[str, ...] = (
    "colour.SDS_COLOURCHECKERS['ColorChecker N Ohta']",
    "colour.SDS_COLOURCHECKERS['BabelColor Average']",
    "colour.SDS_COLOURCHECKERS['ISO 17321-1']",
    "colour.SDS_COLOURCHECKERS['PMC']",
    "colour.quality.SDS_TCS['CIE 1995']",
    "colour.quality.SDS_TCS['CIE 2024']",
    "colour.quality.SDS_VS['NIST CQS 7.4']",
    "colour.quality.SDS_VS['NIST CQS 9.0']",
    "colour.recovery.SDS_SMITS1999",
    "colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019",
    "colour.recovery.CLUSTER_MEANS_OTSU2018",
)
"""Every reflectance set colour-science ships (filters, lenses and camera or display curves are not
reflectances; Munsell and the Joensuu/Krinov sets used by MIST are not shipped: colour-science has
only Munsell *renotation* xyY, no spectra). Smits 1999 spectra exceed 1 by ≤ 1.5 % and are
clipped to [0, 1]; spectra narrower than 380–780 nm are extended with their end values; exact
duplicates after resampling are dropped."""

def srgb_to_XYZ_matrix() -> np.ndarray:
    """Linear sRGB → XYZ (Y of white = 1): colour-science's sRGB colourspace matrix, which is the
    IEC 61966-2-1 matrix as printed (MIST Eq. 2). Its white, (0.9505, 1, 1.089), differs from the
    CIE-integrated D65 white (0.95043, 1, 1.08880) in the fourth decimal;
    `REFLECTANCE_TOLERANCE` absorbs that for white itself."""
    import colour

    return np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, dtype=np.float64)


class MetamerRangeError(NormboxError, ValueError):
    """No physical (reflectance ≤ 1) blend of the database reproduces this colour."""


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB transfer function inverse (MIST Eq. 1), colour-science's: encoded [0, 1] → linear."""
    import colour

    return np.asarray(colour.cctf_decoding(np.asarray(encoded, dtype=np.float64), "sRGB"))


def linear_srgb_to_XYZ(linear_rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear sRGB → XYZ with Y(white) = 1, elementwise (bit-identical for any batch)."""
    rgb = np.asarray(linear_rgb, dtype=np.float64)
    m = srgb_to_XYZ_matrix()
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return np.stack([m[i, 0] * r + m[i, 1] * g + m[i, 2] * b for i in range(3)], axis=-1)


def _as_encoded_srgb(rgb: Any) -> tuple[np.ndarray, bytes]:
    """One colour → (encoded float rgb in [0, 1], hash key). Integers are 8-bit (0–255)."""
    arr = np.asarray(rgb)
    if arr.shape != (3,):
        raise ValueError(f"an sRGB colour has 3 components, got shape {arr.shape}")
    if np.issubdtype(arr.dtype, np.integer):
        if arr.min() < 0 or arr.max() > 255:
            raise ValueError(f"8-bit sRGB components must be 0–255, got {arr.tolist()}")
        u8 = arr.astype(np.uint8)
        return u8.astype(np.float64) / 255.0, b"u" + u8.tobytes()
    values = arr.astype(np.float64)
    if not np.all(np.isfinite(values)) or values.min() < 0.0 or values.max() > 1.0:
        raise ValueError(f"float sRGB components must be finite and in [0, 1], got {values.tolist()}")
    return values, b"f" + values.tobytes()


def _cache_dir() -> Path:
    return Path(os.environ.get("NORMBOX_LAB_CACHE", Path.home() / ".cache" / "normbox-lab"))


def _build_database_arrays(wavelength_nm: np.ndarray) -> dict[str, np.ndarray]:
    """Resample every shipped reflectance set onto `wavelength_nm`; XYZ under D65 (CIE 1931 2°)."""
    import colour
    import colour.quality
    import colour.recovery

    rows: list[np.ndarray] = []
    names: list[str] = []

    def add_sds(source: str, sds: Any) -> None:
        for key, sd in sds.items():
            rows.append(np.interp(wavelength_nm, sd.wavelengths, sd.values))
            names.append(f"{source}/{key}")

    for name in ("ColorChecker N Ohta", "BabelColor Average", "ISO 17321-1", "PMC"):
        add_sds(name, colour.SDS_COLOURCHECKERS[name])
    for name in ("CIE 1995", "CIE 2024"):
        add_sds(f"TCS {name}", colour.quality.SDS_TCS[name])
    for name in ("NIST CQS 7.4", "NIST CQS 9.0"):
        add_sds(f"VS {name}", colour.quality.SDS_VS[name])
    add_sds("Smits 1999", colour.recovery.SDS_SMITS1999)
    mallett = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    for i, label in enumerate(mallett.labels):
        rows.append(np.interp(wavelength_nm, mallett.wavelengths, mallett.values[:, i]))
        names.append(f"Mallett 2019/{label}")
    otsu_shape = colour.recovery.SPECTRAL_SHAPE_OTSU2018
    for i, mean in enumerate(colour.recovery.CLUSTER_MEANS_OTSU2018):
        rows.append(np.interp(wavelength_nm, otsu_shape.wavelengths, mean))
        names.append(f"Otsu 2018 cluster mean/{i}")

    spectra = np.clip(np.array(rows), 0.0, 1.0)
    _, first = np.unique(np.round(spectra, 9), axis=0, return_index=True)
    keep = np.sort(first)
    spectra = spectra[keep]
    names = [names[i] for i in keep]

    shape = colour.SpectralShape(float(wavelength_nm[0]), float(wavelength_nm[-1]),
                                 float(wavelength_nm[1] - wavelength_nm[0]))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    weights = (cmfs.values * d65.values[:, None]).T  # (3, B)
    weights = weights / weights[1].sum()  # perfect white reflector → Y = 1
    return {"wavelength_nm": np.asarray(wavelength_nm, dtype=np.float64), "spectra": spectra,
            "XYZ": spectra @ weights.T, "names": np.array(names), "xyz_weights": weights}


@dataclass(eq=False)
class MetamerDatabase:
    """Reflectance spectra (N, B) on `wavelength_nm`, with their XYZ (Y of white = 1) and xy."""

    wavelength_nm: np.ndarray
    spectra: np.ndarray
    XYZ: np.ndarray
    names: tuple[str, ...]
    xyz_weights: np.ndarray
    """(3, B): XYZ = reflectance @ xyz_weights.T under D65 (CIE 1931 2°), Y(white) = 1."""
    _cache: dict[bytes, np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        for a in (self.wavelength_nm, self.spectra, self.XYZ, self.xyz_weights):
            a.setflags(write=False)

    @property
    def xy(self) -> np.ndarray:
        return self.XYZ[:, :2] / self.XYZ.sum(axis=1, keepdims=True)

    @classmethod
    def default(cls, step_nm: int = 5) -> MetamerDatabase:
        """All shipped reflectances on 380–780 nm at `step_nm` (5 or 1); built once, cached on disk."""
        return _default_database(int(step_nm))

    @classmethod
    def from_spectra(cls, wavelength_nm: np.ndarray, spectra: np.ndarray,
                     names: Sequence[str] | None = None) -> MetamerDatabase:
        """A database of your own reflectances (N, B) in [0, 1] on `wavelength_nm`."""
        import colour

        wl = np.asarray(wavelength_nm, dtype=np.float64)
        s = np.asarray(spectra, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != wl.size:
            raise ValueError(f"spectra must be (N, {wl.size}), got {s.shape}")
        if s.min() < 0.0 or s.max() > 1.0:
            raise ValueError("reflectances must lie in [0, 1]")
        shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
        d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
        weights = (cmfs.values * d65.values[:, None]).T
        weights = weights / weights[1].sum()
        labels = tuple(names) if names is not None else tuple(f"#{i}" for i in range(len(s)))
        return cls(wl, s.copy(), s @ weights.T, labels, weights)

    # --- lookup structures (scipy imported lazily) --------------------------------------------

    @functools.cached_property
    def _kdtree(self) -> Any:
        from scipy.spatial import cKDTree

        return cKDTree(self.xy)

    @functools.cached_property
    def _delaunay(self) -> Any:
        from scipy.spatial import Delaunay

        return Delaunay(self.xy)

    # --- solving -----------------------------------------------------------------------------

    def _nearest(self, XYZ_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MIST: nearest xy, scaled by Y. Returns (spectra (n, B), peak (n,))."""
        xy_t = XYZ_target[:, :2] / XYZ_target.sum(axis=1, keepdims=True)
        _, idx = self._kdtree.query(xy_t)
        scale = XYZ_target[:, 1] / self.XYZ[idx, 1]
        spectra = self.spectra[idx] * scale[:, None]
        return spectra, spectra.max(axis=1)

    def _triangle_blend(self, XYZ_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact-XYZ blend of the enclosing Delaunay triangle's spectra. NaN rows: outside hull."""
        xy_t = XYZ_target[:, :2] / XYZ_target.sum(axis=1, keepdims=True)
        simplex = self._delaunay.find_simplex(xy_t, tol=HULL_TOLERANCE)
        inside = simplex >= 0
        vertices = self._delaunay.simplices[np.where(inside, simplex, 0)]  # (n, 3)
        # Cramer's rule for [XYZ_a XYZ_b XYZ_c] w = XYZ_t, elementwise (batch-independent bits).
        a, b, c = (self.XYZ[vertices[:, k]] for k in range(3))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        w = np.stack([np.einsum("ij,ij->i", XYZ_target, np.cross(b, c)),
                      np.einsum("ij,ij->i", a, np.cross(XYZ_target, c)),
                      np.einsum("ij,ij->i", a, np.cross(b, XYZ_target))], axis=1) / det[:, None]
        w = np.clip(w, 0.0, None)  # rounding at the hull edge only
        spectra = (w[:, 0:1] * self.spectra[vertices[:, 0]] + w[:, 1:2] * self.spectra[vertices[:, 1]]
                   + w[:, 2:3] * self.spectra[vertices[:, 2]])
        peak = spectra.max(axis=1)
        spectra[~inside] = np.nan
        peak[~inside] = np.inf
        return spectra, peak

    def _min_peak_blend(self, XYZ_target: np.ndarray) -> tuple[np.ndarray, float]:
        """Linear programme: w ≥ 0, XYZᵀw = target, minimise max(spectraᵀw). (spectrum, peak)."""
        from scipy.optimize import linprog

        n_spectra, n_bands = self.spectra.shape
        cost = np.zeros(n_spectra + 1)
        cost[-1] = 1.0
        a_ub = np.hstack([self.spectra.T, -np.ones((n_bands, 1))])
        a_eq = np.hstack([self.XYZ.T, np.zeros((3, 1))])
        result = linprog(cost, A_ub=a_ub, b_ub=np.zeros(n_bands), A_eq=a_eq, b_eq=XYZ_target,
                         bounds=(0.0, None), method="highs")
        if result.status != 0:
            return np.full(n_bands, np.nan), float("inf")
        spectrum = result.x[:-1] @ self.spectra
        return spectrum, float(spectrum.max())

    @functools.cached_property
    def srgb_basis(self) -> np.ndarray | None:
        """(3, B): non-negative blends B_R, B_G, B_B of the database whose sum (white) stays ≤ 1
        in every band and whose XYZ come closest (least L1 residual, one linear programme) to
        the sRGB primaries; None if the residual exceeds `BASIS_MAX_RESIDUAL_XYZ`. With it every
        linear sRGB in [0, 1]³ has a physical near-metamer r·B_R + g·B_G + b·B_B — Mallett &
        Yuksel 2019's construction; the Mallett 2019 basis in the default database makes it
        exist (its residual, ≈ 3e-4, comes from the IEC matrix's rounded printed values)."""
        from scipy.optimize import linprog

        n_spectra, n_bands = self.spectra.shape
        n_weights = 3 * n_spectra
        n_vars = n_weights + 18  # weights, then slack+ (9) and slack− (9) on the 9 XYZ equations
        cost = np.zeros(n_vars)
        cost[n_weights:] = 1.0
        a_eq = np.zeros((9, n_vars))
        for i in range(3):
            a_eq[3 * i:3 * i + 3, i * n_spectra:(i + 1) * n_spectra] = self.XYZ.T
        a_eq[:, n_weights:n_weights + 9] = np.eye(9)
        a_eq[:, n_weights + 9:] = -np.eye(9)
        b_eq = srgb_to_XYZ_matrix().T.reshape(-1)  # primary i's XYZ at rows 3i..3i+2
        a_ub = np.hstack([self.spectra.T, self.spectra.T, self.spectra.T, np.zeros((n_bands, 18))])
        result = linprog(cost, A_ub=a_ub, b_ub=np.ones(n_bands), A_eq=a_eq, b_eq=b_eq,
                         bounds=(0.0, None), method="highs")
        if result.status != 0:
            return None
        residual = result.x[n_weights:n_weights + 9] - result.x[n_weights + 9:]
        if np.max(np.abs(residual)) > BASIS_MAX_RESIDUAL_XYZ:
            return None
        basis = result.x[:n_weights].reshape(3, n_spectra) @ self.spectra
        basis.setflags(write=False)
        return basis

    def _solve(self, linear_rgb: np.ndarray, XYZ_target: np.ndarray,
               method: Method) -> tuple[np.ndarray, np.ndarray]:
        """(n, B) spectra with exactly the target XYZ (blend) or MIST's (nearest), and their peak
        reflectance; a peak of inf marks "no such blend". Y must be > 0."""
        limit = 1.0 + REFLECTANCE_TOLERANCE
        if method == "nearest":
            return self._nearest(XYZ_target)
        if method != "blend":
            raise ValueError(f"method must be 'blend' or 'nearest', got {method!r}")
        spectra, peak = self._triangle_blend(XYZ_target)
        basis = self.srgb_basis
        need = np.flatnonzero(~(peak <= limit))
        if need.size and basis is not None:
            # Too bright (or outside the xy hull): move along the segment from the triangle blend
            # T towards the basis blend A (both have the target XYZ) just far enough that every
            # band is ≤ 1: alpha = max over bands of (T − 1) / (T − A).
            rgb = linear_rgb[need]
            anchor = (rgb[:, 0:1] * basis[0] + rgb[:, 1:2] * basis[1] + rgb[:, 2:3] * basis[2])
            usable = (anchor.min(axis=1) >= 0.0) & (anchor.max(axis=1) <= limit)
            tri = spectra[need]
            inside = np.isfinite(peak[need])
            with np.errstate(divide="ignore", invalid="ignore"):
                alpha_band = np.where(tri > 1.0, (tri - 1.0) / (tri - anchor), 0.0)
            alpha_band = np.where(np.isfinite(alpha_band), alpha_band, 1.0)
            alpha = np.where(inside, np.clip(alpha_band.max(axis=1), 0.0, 1.0), 1.0)
            safe_tri = np.where(inside[:, None], tri, 0.0)
            mixed = (1.0 - alpha[:, None]) * safe_tri + alpha[:, None] * anchor
            rows = need[usable]
            spectra[rows] = mixed[usable]
            peak[rows] = mixed[usable].max(axis=1)
        for i in np.flatnonzero(np.isfinite(peak) & (peak > limit)):
            spectra[i], peak[i] = self._min_peak_blend(XYZ_target[i])
        return spectra, peak

    def solve_linear(self, linear_rgb: np.ndarray, *, method: Method = "blend",
                     strict: bool = True) -> np.ndarray:
        """(n, 3) linear sRGB → (n, B) reflectances in [0, 1]. No cache; see `texture`."""
        rgb = np.atleast_2d(np.asarray(linear_rgb, dtype=np.float64))
        XYZ_target = linear_srgb_to_XYZ(rgb)
        out = np.zeros((rgb.shape[0], self.wavelength_nm.size))
        work = np.flatnonzero(XYZ_target[:, 1] > 0.0)  # black (Y = 0) stays the zero spectrum
        if work.size == 0:
            return out
        spectra, peak = self._solve(rgb[work], XYZ_target[work], method)
        bad = ~(peak <= 1.0 + REFLECTANCE_TOLERANCE)
        if np.any(bad):
            if strict:
                i = int(np.flatnonzero(bad)[0])
                why = ("outside its xy hull" if not np.isfinite(peak[i])
                       else f"needs peak reflectance {peak[i]:.3f} > 1")
                raise MetamerRangeError(
                    f"linear sRGB {rgb[work[i]].tolist()} is out of the metamer database's range "
                    f"({why}); strict=False gives MIST's nearest spectrum, clipped to [0, 1]")
            spectra[bad] = self._nearest(XYZ_target[work[bad]])[0]
        out[work] = np.clip(spectra, 0.0, 1.0)
        return out

    def in_range(self, linear_rgb: np.ndarray) -> np.ndarray:
        """(n, 3) linear sRGB → (n,) bool: `solve_linear(..., method="blend")` succeeds."""
        rgb = np.atleast_2d(np.asarray(linear_rgb, dtype=np.float64))
        XYZ_target = linear_srgb_to_XYZ(rgb)
        ok = XYZ_target[:, 1] <= 0.0
        ok &= np.all(rgb == 0.0, axis=1)  # only true black is the zero spectrum
        work = np.flatnonzero(XYZ_target[:, 1] > 0.0)
        if work.size:
            _, peak = self._solve(rgb[work], XYZ_target[work], "blend")
            ok[work] = peak <= 1.0 + REFLECTANCE_TOLERANCE
        return ok

    # --- cached entry points -----------------------------------------------------------------

    def metamer(self, rgb: Any, *, method: Method = "blend", strict: bool = True) -> np.ndarray:
        """One (encoded) sRGB colour → read-only reflectance (B,); repeated colours hit the cache."""
        encoded, key = _as_encoded_srgb(rgb)
        key = method.encode() + (b"s" if strict else b"c") + key
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        spectrum = self.solve_linear(srgb_decode(encoded)[None, :], method=method, strict=strict)[0]
        return self._remember(key, spectrum)

    def _remember(self, key: bytes, spectrum: np.ndarray) -> np.ndarray:
        if len(self._cache) >= CACHE_MAX_ENTRIES:
            self._cache.clear()
        spectrum.setflags(write=False)
        self._cache[key] = spectrum
        return spectrum

    def texture(self, image: np.ndarray, *, method: Method = "blend",
                strict: bool = True) -> np.ndarray:
        """(H, W, 3) uint8 or float [0, 1] sRGB → (H, W, B) reflectances; each colour solved once."""
        img = np.asarray(image)
        if img.ndim < 1 or img.shape[-1] != 3:
            raise ValueError(f"a texture is (..., 3), got shape {img.shape}")
        flat = img.reshape(-1, 3)
        if np.issubdtype(flat.dtype, np.integer):
            if flat.size and (flat.min() < 0 or flat.max() > 255):
                raise ValueError("8-bit sRGB textures must hold 0–255")
            flat = flat.astype(np.uint8)
            tag = b"u"
        else:
            flat = flat.astype(np.float64)
            if flat.size and (not np.all(np.isfinite(flat)) or flat.min() < 0 or flat.max() > 1):
                raise ValueError("float sRGB textures must be finite and in [0, 1]")
            tag = b"f"
        unique, inverse = np.unique(flat, axis=0, return_inverse=True)
        prefix = method.encode() + (b"s" if strict else b"c") + tag
        keys = [prefix + row.tobytes() for row in unique]
        result = np.empty((unique.shape[0], self.wavelength_nm.size))
        missing = []
        for i, key in enumerate(keys):
            hit = self._cache.get(key)
            if hit is None:
                missing.append(i)
            else:
                result[i] = hit
        if missing:
            encoded = unique[missing].astype(np.float64)
            if tag == b"u":
                encoded = encoded / 255.0
            solved = self.solve_linear(srgb_decode(encoded), method=method, strict=strict)
            for j, i in enumerate(missing):
                result[i] = solved[j]
                self._remember(keys[i], solved[j].copy())
        return result[inverse.reshape(-1)].reshape(*img.shape[:-1], self.wavelength_nm.size)


@functools.lru_cache(maxsize=4)
def _default_database(step_nm: int) -> MetamerDatabase:
    if step_nm not in (1, 5):
        raise ValueError(f"step_nm must be 1 or 5, got {step_nm}")
    wavelength_nm = wavelengths_nm(step_nm)
    path = _cache_dir() / f"metamer_db_v{DATABASE_VERSION}_380_780_{step_nm}nm.npz"
    arrays: dict[str, np.ndarray] | None = None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        if not np.array_equal(arrays["wavelength_nm"], wavelength_nm):
            arrays = None
    except (OSError, ValueError, KeyError):
        arrays = None
    if arrays is None:
        arrays = _build_database_arrays(wavelength_nm)
        from normbox_lab.core.npzfile import keep_npz

        keep_npz(path, **arrays)      # a read-only cache only costs the rebuild next time
    return MetamerDatabase(arrays["wavelength_nm"], arrays["spectra"], arrays["XYZ"],
                           tuple(str(n) for n in arrays["names"]), arrays["xyz_weights"])


# --- module-level conveniences on the default database ------------------------------------------

def metamer_for_srgb(rgb: Any, *, method: Method = "blend", strict: bool = True,
                     database: MetamerDatabase | None = None) -> tuple[np.ndarray, np.ndarray]:
    """sRGB colour (3 ints 0–255, or 3 floats in [0, 1], transfer-encoded) →
    (wavelength_nm (B,), reflectance (B,)), both read-only; raises `MetamerRangeError` if out of
    range and `strict`."""
    db = database if database is not None else MetamerDatabase.default()
    return db.wavelength_nm, db.metamer(rgb, method=method, strict=strict)


def metamers_for_texture(image: np.ndarray, *, method: Method = "blend", strict: bool = True,
                         database: MetamerDatabase | None = None) -> np.ndarray:
    """(H, W, 3) sRGB texture (uint8, or float in [0, 1]) → (H, W, B) reflectances on the
    database's `wavelength_nm`."""
    db = database if database is not None else MetamerDatabase.default()
    return db.texture(image, method=method, strict=strict)


def in_range(rgb: Any, *, database: MetamerDatabase | None = None) -> bool:
    """Whether `metamer_for_srgb(rgb)` (method "blend") succeeds with an exact-XYZ physical blend."""
    db = database if database is not None else MetamerDatabase.default()
    encoded, _ = _as_encoded_srgb(rgb)
    return bool(db.in_range(srgb_decode(encoded)[None, :])[0])
