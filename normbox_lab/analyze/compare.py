"""Compare predicted with reference radiance (paper §4.5, §6) and the error model (§6.3.3).

Inputs are plain arrays: radiance [patch, angle, wavelength] in W·sr⁻¹·m⁻²·nm⁻¹ for the
reference (measured in the box) and the prediction (rendered), on one wavelength grid.

Metrics (per patch × angle):
- NSE, normalised spectral error, per wavelength: (prediction − reference) / reference.  The
  paper subtracts the other way round; we keep "prediction minus truth" so that the NSE has the
  sign of the BRDF fitting error (fit − measured)/measured it is compared with (paper Fig. 14).
- RMSE over wavelengths, in radiance units; NRMSE = RMSE / mean(reference spectrum) (the paper's
  "normalised by the averaged reference spectrum"); NRMSE by the spectrum's range is kept too.
- ΔE00 (colour maths in `normbox_lab.core.colorimetry`): XYZ (CIE 1931 2°, emissive:
  illuminant E, via colour-science) of both spectra divided by
  the Y of the *reference* white patch at 30°, Lab with the D65 white point (Y = 1), CIE 2000
  with kL = kC = kH = 1.  (colour's `sd_to_XYZ` divides by 100 when k is given; the scale
  cancels in the white normalisation, and `XYZ_to_Lab` wants the white with Y = 1.)
- Rating scale (Reinhard et al., Color Imaging, p. 461, as used by the paper): ΔE ≤ 1 below the
  JND; ≤ 2 just noticeable, not discernible side by side; ≤ 5 discernible side by side; > 5
  easily perceived.
- Pearson correlation between reference radiance (spectral mean) and RMSE, and NRMSE, across
  all patches, for the small (30–60°) and the large (65–90°) sample angles (paper Figs. 5b/c, 6b/c).

Error model (paper Fig. 12): with the direct-light share d of the radiance per patch × angle
(from a direct-only render over the full render), the patch-fit relative error err_d and the
wall-fit relative error err_i, the simulated normalised error is
    e_sim(λ) = d·err_d(λ) + (1 − d)·err_i(λ)
(scalars or spectra), its NRMSE analogue RMS_λ(ref·e_sim)/mean_λ(ref), and the two stacked
contributions d·|err_d| and (1 − d)·|err_i|.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.core.colorimetry import XYZ_to_Lab_D65, delta_e00, spectra_to_XYZ
from normbox_lab.core.errors import DataError

#: ColorChecker patch numbering of the paper (1-based): 19 = white 9.5, 24 = black 2.
WHITE_PATCH_INDEX = 18
WHITE_ANGLE_DEG = 30.0
SMALL_ANGLES_DEG = (30.0, 60.0)
LARGE_ANGLES_DEG = (65.0, 90.0)

#: (upper bound of ΔE00, label); the last class is open-ended.
RATING_SCALE: tuple[tuple[float, str], ...] = (
    (1.0, "below JND"),
    (2.0, "just noticeable"),
    (5.0, "discernible side by side"),
    (float("inf"), "easily perceived"),
)


def rating_index(delta_e: Any) -> np.ndarray:
    """Class index in RATING_SCALE for each ΔE00 (0 = below JND … 3 = easily perceived)."""
    bounds = np.array([b for b, _ in RATING_SCALE[:-1]])
    return np.searchsorted(bounds, np.asarray(delta_e, dtype=float), side="left")


def rate_delta_e(delta_e: float) -> str:
    return RATING_SCALE[int(rating_index(delta_e))][1]


def rating_class_range(k: int) -> str:
    """The ΔE00 range of rating class `k` as text: "≤ 1", "1–2", "2–5", "> 5"."""
    lo = 0.0 if k == 0 else RATING_SCALE[k - 1][0]
    hi = RATING_SCALE[k][0]
    if not np.isfinite(hi):
        return f"> {lo:g}"
    return f"≤ {hi:g}" if k == 0 else f"{lo:g}–{hi:g}"


def _corr(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.std(x[ok]) == 0 or np.std(y[ok]) == 0:
        return float("nan")
    return float(np.corrcoef(x[ok], y[ok])[0, 1])


@dataclass
class ComparisonResult:
    """Everything the report shows about one prediction vs the reference."""

    patch_names: list[str]
    angle_deg: np.ndarray
    wavelength_nm: np.ndarray
    reference: np.ndarray             # [patch, angle, λ] radiance
    prediction: np.ndarray
    nse: np.ndarray                   # [patch, angle, λ]
    rmse: np.ndarray                  # [patch, angle] radiance units
    nrmse: np.ndarray                 # [patch, angle] RMSE / mean reference
    nrmse_range: np.ndarray           # [patch, angle] RMSE / (max − min) of the reference
    radiance_mean: np.ndarray         # [patch, angle] mean reference spectral radiance
    delta_e00: np.ndarray             # [patch, angle]
    lab_reference: np.ndarray         # [patch, angle, 3]
    lab_prediction: np.ndarray
    white_patch: int = WHITE_PATCH_INDEX
    white_angle_deg: float = WHITE_ANGLE_DEG
    correlations: dict[str, float] = field(default_factory=dict)
    #: [patch, angle] ΔE00 in the adapted convention (`delta_e00_adapted`), computed once by
    #: `compare`; None in a comparison stored before it was kept
    delta_e00_adapted: np.ndarray | None = None

    def rating_counts(self) -> dict[str, int]:
        idx = rating_index(self.delta_e00)
        return {label: int(np.sum(idx == k)) for k, (_, label) in enumerate(RATING_SCALE)}

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}

    def to_metadata(self) -> dict[str, Any]:
        return {"patch_names": list(self.patch_names), "white_patch": int(self.white_patch),
                "white_angle_deg": float(self.white_angle_deg),
                "correlations": dict(self.correlations),
                "rating_counts": self.rating_counts(),
                "delta_e00_mean": float(np.nanmean(self.delta_e00)),
                "delta_e00_max": float(np.nanmax(self.delta_e00)),
                "nrmse_mean": float(np.nanmean(self.nrmse))}

    def store(self, store: Store, name: str, run_ref: int | str | None = None) -> int:
        return store.add_artifact(kind="comparison", name=name, arrays=self.to_arrays(),
                                  metadata=self.to_metadata(), run_ref=run_ref)

    @classmethod
    def from_artifact(cls, artifact: Any) -> ComparisonResult:
        md = artifact.metadata
        arrays = {k: np.asarray(v) for k, v in artifact.arrays.items()}
        return cls(patch_names=list(md["patch_names"]), white_patch=int(md["white_patch"]),
                   white_angle_deg=float(md["white_angle_deg"]),
                   correlations=dict(md.get("correlations", {})), **arrays)


def _angle_mask(angle_deg: np.ndarray, lo_hi: tuple[float, float]) -> np.ndarray:
    return (angle_deg >= lo_hi[0] - 1e-9) & (angle_deg <= lo_hi[1] + 1e-9)


def compare(reference: Any, prediction: Any, wavelength_nm: Any, angle_deg: Any,
            patch_names: Sequence[str] | None = None, *,
            white_patch: int = WHITE_PATCH_INDEX,
            white_angle_deg: float = WHITE_ANGLE_DEG) -> ComparisonResult:
    """All metrics of the paper's comparison for radiance arrays [patch, angle, λ]."""
    ref = np.asarray(reference, dtype=float)
    pred = np.asarray(prediction, dtype=float)
    wl = np.asarray(wavelength_nm, dtype=float)
    ang = np.asarray(angle_deg, dtype=float)
    if ref.shape != pred.shape or ref.ndim != 3 or ref.shape[1:] != (ang.size, wl.size):
        raise DataError("comparison", "shape",
                        f"reference {ref.shape} / prediction {pred.shape} must both be "
                        f"[patch, {ang.size} angles, {wl.size} wavelengths]")
    n_p = ref.shape[0]
    names = list(patch_names) if patch_names is not None else [f"{k + 1}" for k in range(n_p)]
    diff = pred - ref
    with np.errstate(divide="ignore", invalid="ignore"):
        nse = np.where(ref != 0, diff / ref, np.nan)
        rmse = np.sqrt(np.mean(diff ** 2, axis=-1))
        mean_ref = np.mean(ref, axis=-1)
        nrmse = rmse / mean_ref
        nrmse_range = rmse / (np.max(ref, axis=-1) - np.min(ref, axis=-1))
    # colorimetry: both normalised by the reference white patch at 30°
    wa = np.flatnonzero(np.isclose(ang, white_angle_deg))
    if not 0 <= white_patch < n_p or wa.size == 0:
        raise DataError("comparison", "white",
                        f"white patch {white_patch} at {white_angle_deg}° is not in the data")
    xyz_ref = spectra_to_XYZ(ref, wl)
    xyz_pred = spectra_to_XYZ(pred, wl)
    y_white = xyz_ref[white_patch, wa[0], 1]
    lab_ref = XYZ_to_Lab_D65(xyz_ref / y_white)
    lab_pred = XYZ_to_Lab_D65(xyz_pred / y_white)
    de = delta_e00(lab_ref, lab_pred)
    small, large = _angle_mask(ang, SMALL_ANGLES_DEG), _angle_mask(ang, LARGE_ANGLES_DEG)
    corr = {
        "radiance_rmse_small": _corr(mean_ref[:, small].ravel(), rmse[:, small].ravel()),
        "radiance_rmse_large": _corr(mean_ref[:, large].ravel(), rmse[:, large].ravel()),
        "radiance_nrmse_small": _corr(mean_ref[:, small].ravel(), nrmse[:, small].ravel()),
        "radiance_nrmse_large": _corr(mean_ref[:, large].ravel(), nrmse[:, large].ravel()),
    }
    adapted = _adapted_delta_e00(xyz_ref, xyz_pred, xyz_ref[white_patch, wa[0]])
    return ComparisonResult(names, ang, wl, ref, pred, nse, rmse, nrmse, nrmse_range, mean_ref,
                            de, lab_ref, lab_pred, white_patch, float(white_angle_deg), corr,
                            adapted)


def _adapted_delta_e00(xyz_ref: np.ndarray, xyz_pred: np.ndarray,
                       xyz_white: np.ndarray) -> np.ndarray:
    import colour

    white = xyz_white / xyz_white[1]
    d65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])

    def adapt(xyz: np.ndarray) -> np.ndarray:
        return colour.adaptation.chromatic_adaptation_VonKries(xyz / xyz_white[1], white, d65,
                                                               transform="CAT02")

    return delta_e00(XYZ_to_Lab_D65(adapt(xyz_ref)), XYZ_to_Lab_D65(adapt(xyz_pred)))


def delta_e00_adapted(c: ComparisonResult) -> np.ndarray:
    """ΔE00 [patch, angle] in the adapted convention, recomputed from `c`'s spectra: both
    spectra's XYZ divided by the Y of the reference white patch at 30°, adapted from that
    measured white to D65 with the CAT02 von Kries transform (colour-science), then Lab with
    D65, CIE 2000 (kL = kC = kH = 1).  `compare` keeps it as `ComparisonResult.delta_e00_adapted`
    (the report reads that and does not recompute it).

    The paper's convention (`ComparisonResult.delta_e00`) takes Lab with a D65 white directly,
    so under the ~3100 K lamp every colour sits on the warm side of Lab, where the same spectral
    error gives a different ΔE00 than for an observer adapted to the box's light."""
    xyz_ref = spectra_to_XYZ(c.reference, c.wavelength_nm)
    xyz_pred = spectra_to_XYZ(c.prediction, c.wavelength_nm)
    wa = int(np.flatnonzero(np.isclose(c.angle_deg, c.white_angle_deg))[0])
    return _adapted_delta_e00(xyz_ref, xyz_pred, xyz_ref[c.white_patch, wa])


# -- error model ---------------------------------------------------------------------------

def direct_light_geometry(sample_angle_deg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(θi, θo) in the gonio convention of brdf_model for the box's direct light path.

    The light is overhead, the radiometer horizontal; at sample angle s the sample normal is
    tilted s from vertical towards the radiometer, so the light arrives at −s and the radiometer
    looks from +(90 − s) (opposite sides of the normal; s = 45° is the mirror geometry).
    """
    s = np.asarray(sample_angle_deg, dtype=float)
    return -s, 90.0 - s


def direct_share(direct_only: Any, full: Any) -> np.ndarray:
    """Share of direct light per patch × angle: spectral mean of direct-only over full render."""
    d = np.asarray(direct_only, dtype=float)
    f = np.asarray(full, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.mean(d, axis=-1) / np.mean(f, axis=-1)
    return np.clip(share, 0.0, 1.0)


@dataclass
class ErrorModelResult:
    angle_deg: np.ndarray
    direct_share: np.ndarray          # [patch, angle]
    simulated_nse: np.ndarray         # [patch, angle, λ] (λ axis of length 1 for scalar errors)
    simulated_nrmse: np.ndarray       # [patch, angle]
    contribution_d: np.ndarray        # [patch, angle]  d·RMS(err_d)
    contribution_i: np.ndarray        # [patch, angle]  (1 − d)·RMS(err_i)
    observed_nrmse: np.ndarray | None = None

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray)}

    def store(self, store: Store, name: str, run_ref: int | str | None = None) -> int:
        return store.add_artifact(kind="error-model", name=name, arrays=self.to_arrays(),
                                  metadata={}, run_ref=run_ref)


def error_model(share_direct: Any, err_d: Any, err_i: Any, angle_deg: Any,
                reference: Any | None = None,
                observed_nrmse: Any | None = None) -> ErrorModelResult:
    """Simulated normalised error per patch × angle from light composition and fit errors.

    share_direct: [patch, angle] or [angle] (direct / full radiance, 0…1).
    err_d, err_i: relative errors (fractions, signed or magnitudes), scalars or arrays that
    broadcast to [patch, angle, λ] — e.g. err_d[:, None, :] per patch spectrum, err_i[None,
    None, :] for one wall spectrum.  reference: radiance [patch, angle, λ] to weight the NRMSE
    analogue; without it the spectrum is taken as flat.
    """
    ang = np.asarray(angle_deg, dtype=float)
    d = np.asarray(share_direct, dtype=float)
    if d.ndim == 1:
        d = d[None, :]
    ed = np.asarray(err_d, dtype=float)
    ei = np.asarray(err_i, dtype=float)
    sim = d[..., None] * ed + (1.0 - d[..., None]) * ei
    sim = np.broadcast_to(sim, np.broadcast_shapes(sim.shape, d.shape + (1,))).copy()
    if reference is not None:
        ref = np.asarray(reference, dtype=float)
        ref = np.broadcast_to(ref, np.broadcast_shapes(ref.shape, sim.shape))
        sim = np.broadcast_to(sim, ref.shape).copy()
        mean_ref = np.mean(ref, axis=-1)

        def rms_rel(x: np.ndarray) -> np.ndarray:
            return np.sqrt(np.mean((ref * x) ** 2, axis=-1)) / mean_ref
    else:
        def rms_rel(x: np.ndarray) -> np.ndarray:
            return np.sqrt(np.mean(x ** 2, axis=-1))
    shape = sim.shape
    c_d = rms_rel(np.broadcast_to(d[..., None] * ed, shape))
    c_i = rms_rel(np.broadcast_to((1.0 - d[..., None]) * ei, shape))
    return ErrorModelResult(ang, np.broadcast_to(d, shape[:-1]).copy(), sim, rms_rel(sim),
                            c_d, c_i,
                            None if observed_nrmse is None
                            else np.asarray(observed_nrmse, dtype=float))
