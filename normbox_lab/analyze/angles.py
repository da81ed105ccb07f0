"""Sample-angle misadjustment from a reference sweep (the Normbox paper's §6.3.5, computed).

The sweep sets each sample angle once and measures all patches there, so a misadjusted angle
a shifts every patch's reading at that angle by δ_a · ∂L/∂s.  With the reference R, the
prediction P and the renderer's angle derivative D = ∂P/∂s (per degree) on [patch, angle, λ],

    (R − P) / P̄  =  t(angle; patch, λ)  +  δ_angle · D / P̄  +  noise

where P̄ is the spectral mean of P (so dark bands do not dominate) and t is the part of the
residual that varies *smoothly* with the angle (fit errors, light composition): a polynomial
of `trend_degree` in the angle per patch × wavelength, projected out.  The offsets δ (one per
sweep angle, shared by all patches) follow by linear least squares; the smooth part of δ that
the trend absorbs is not identifiable and the small ridge sets it to zero.  So the estimate is
of the angle-to-angle *misadjustment* (what the paper saw by eye), not of a common tilt.

95 % intervals, from two parts added in quadrature:

- the errors that differ between patches (radiometer gain and wavelength per reading,
  placement, Monte-Carlo noise): the larger of a jackknife over patches (leave one patch out;
  it also carries what no model names) and, given draws of those errors (`independent`: the
  budget's perturbations of the per-reading sources), the RMS of the offsets the estimator
  makes of them.  The jackknife alone rests on a few patches where the angle derivative is
  concentrated on them: over 125 null campaigns it flagged 8–10 % at 80–90°;
- the errors *common to all patches at one angle* that are not smooth in the angle: the
  jackknife cannot see them (every patch moves alike), and a misadjusted angle looks almost
  exactly like them (∂L/∂s / L differs little between patches).  Given draws of those errors
  (`common`: the error budget's perturbations of the campaign-wide sources — geometry, panel
  homogeneity, light, gonio calibration and non-linearity, the fit — as [draw, patch, angle,
  λ]), the estimator, which is linear in the residual, is applied to each draw; the RMS of
  the resulting offsets (a fixed source's bias included) is the second part.

`significant()`: |offset| beyond the half-width.  The false-alarm rate of this test is
measured by a null test (tests/analyze/test_angle_offsets.py fast, on synthetic campaigns;
tests/analyze/test_budget_null.py over independent virtual campaigns, docs/error-budget.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class AngleOffsets:
    angle_deg: np.ndarray          # sweep angles
    offset_deg: np.ndarray         # estimated misadjustment per angle
    ci95_deg: np.ndarray           # half-width of the 95 % interval per angle
    trend_degree: int | None
    #: the two parts of the interval (standard deviations, deg): jackknife over patches, and
    #: the RMS effect of the common errors (zeros when none were given)
    jackknife_sd_deg: np.ndarray | None = None
    common_rms_deg: np.ndarray | None = None
    #: the RMS effect of the per-reading errors' draws (zeros when none were given)
    independent_rms_deg: np.ndarray | None = None
    #: what the rotator itself reported per angle: mean readback − setpoint over the patches
    #: (`ReferenceData.readback_offset_deg`; NaN where the store has no readback)
    readback_deg: np.ndarray | None = None

    def unexplained_deg(self) -> np.ndarray:
        """The estimated offset less the stage's own readback offset (where recorded): the
        misadjustment the stage did not see (a mounting tilt, a shifted encoder zero)."""
        if self.readback_deg is None:
            return self.offset_deg
        rb = np.asarray(self.readback_deg, dtype=float)
        return self.offset_deg - np.where(np.isfinite(rb), rb, 0.0)

    def significant(self) -> np.ndarray:
        return np.abs(self.offset_deg) > self.ci95_deg

    def rows(self) -> list[tuple[float, float, float, bool]]:
        return [(float(a), float(o), float(c), bool(s)) for a, o, c, s in
                zip(self.angle_deg, self.offset_deg, self.ci95_deg, self.significant())]

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"angle_offset_angle_deg": self.angle_deg, "angle_offset_deg": self.offset_deg,
               "angle_offset_ci95_deg": self.ci95_deg}
        if self.jackknife_sd_deg is not None:
            out["angle_offset_jackknife_sd_deg"] = self.jackknife_sd_deg
        if self.common_rms_deg is not None:
            out["angle_offset_common_rms_deg"] = self.common_rms_deg
        if self.independent_rms_deg is not None:
            out["angle_offset_independent_rms_deg"] = self.independent_rms_deg
        if self.readback_deg is not None:
            out["angle_offset_readback_deg"] = self.readback_deg
        return out


def _detrend_matrix(angle_deg: np.ndarray, degree: int | None) -> np.ndarray:
    n = angle_deg.size
    if degree is None or degree < 0:
        return np.eye(n)
    x = (angle_deg - angle_deg.mean()) / max(np.ptp(angle_deg) / 2, 1e-12)
    V = np.polynomial.legendre.legvander(x, min(int(degree), n - 2))
    Q, _ = np.linalg.qr(V)
    return np.eye(n) - Q @ Q.T


def _normal_terms(e: np.ndarray, g: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per patch: N_p = Σ_λ diag(g) M diag(g), b_p = Σ_λ diag(g) M e  (e, g: [patch, angle, λ])."""
    N = np.einsum("pal,ab,pbl->pab", g, M, g)
    b = np.einsum("pal,ab,pbl->pa", g, M, e)
    return N, b


def _solve(N: np.ndarray, b: np.ndarray, ridge: float) -> np.ndarray:
    scale = float(np.trace(N)) / N.shape[0] if np.trace(N) > 0 else 1.0
    return np.linalg.solve(N + ridge * scale * np.eye(N.shape[0]), b)


def estimate_angle_offsets(reference: Any, prediction: Any, derivative_per_deg: Any,
                           angle_deg: Any, *, trend_degree: int | None = 2,
                           ridge: float = 1e-3, common: Any = None,
                           independent: Any = None) -> AngleOffsets:
    """One sample-angle offset per sweep angle (deg) from [patch, angle, λ] arrays; `common`:
    draws [draw, patch, angle, λ] of the reference-minus-prediction errors shared by all
    patches, `independent`: of those that differ between patches (see the module doc), or
    None."""
    R = np.asarray(reference, dtype=float)
    P = np.asarray(prediction, dtype=float)
    D = np.asarray(derivative_per_deg, dtype=float)
    ang = np.asarray(angle_deg, dtype=float)
    if not (R.shape == P.shape == D.shape and R.ndim == 3 and R.shape[1] == ang.size):
        raise ValueError(f"reference {R.shape}, prediction {P.shape}, derivative {D.shape} "
                         f"must all be [patch, {ang.size} angles, λ]")
    scale = np.mean(np.abs(P), axis=-1, keepdims=True)
    scale = np.where(scale > 0, scale, 1.0)
    e = np.nan_to_num((R - P) / scale)
    g = np.nan_to_num(D / scale)
    M = _detrend_matrix(ang, trend_degree)
    N_p, b_p = _normal_terms(e, g, M)
    N, b = N_p.sum(axis=0), b_p.sum(axis=0)
    offset = _solve(N, b, ridge)
    n = R.shape[0]
    if n >= 3:
        loo = np.array([_solve(N - N_p[k], b - b_p[k], ridge) for k in range(n)])
        sd = np.sqrt((n - 1) / n * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
        q = _jackknife_quantile(N_p)
    else:
        sd = np.full(ang.size, np.inf)
        q = np.full(ang.size, 1.96)

    def draws_rms(draws: Any, what: str) -> np.ndarray:
        """RMS over draws [draw, patch, angle, λ] of the offsets the estimator makes."""
        d = np.asarray(draws, dtype=float)
        if d.ndim == 3:
            d = d[None]
        if d.shape[1:] != R.shape:
            raise ValueError(f"{what} draws {d.shape} must be [draw, {R.shape}]")
        eb = d / scale[None]
        if not np.isfinite(eb).all():
            eb = np.nan_to_num(eb)
        # b_k[a] = Σ_b M[a, b] Σ_{p, λ} g[p, a, λ] e_k[p, b, λ]  (one matrix product)
        G = np.tensordot(g, eb, axes=([0, 2], [1, 3]))          # [a, k, b]
        b_k = np.einsum("ab,akb->ka", M, G)
        scale_n = float(np.trace(N)) / N.shape[0] if np.trace(N) > 0 else 1.0
        offsets_k = np.linalg.solve(N + ridge * scale_n * np.eye(N.shape[0]), b_k.T).T
        return np.sqrt(np.mean(offsets_k ** 2, axis=0))

    rms = draws_rms(common, "common") if common is not None else np.zeros(ang.size)
    rms_ind = (draws_rms(independent, "independent") if independent is not None
               else np.zeros(ang.size))
    half = np.hypot(np.maximum(q * sd, 1.96 * rms_ind), 1.96 * rms)
    return AngleOffsets(ang, offset, half, trend_degree, sd, rms, rms_ind)


def _jackknife_quantile(N_p: np.ndarray) -> np.ndarray:
    """Per angle, the 97.5 % Student-t quantile for the jackknife's standard deviation, with
    the patches' effective number as degrees of freedom: the patches weigh in unequally (by
    Σ_λ (∂L/∂s / L̄)², bright-coloured spectra more), so fewer than n of them carry the
    estimate and its interval needs the heavier tail (measured on null campaigns: 1.96 left
    up to 9 % false alarms at some angles)."""
    from scipy.stats import t

    diag = np.einsum("paa->pa", N_p)
    w = diag / np.maximum(diag.sum(axis=0, keepdims=True), 1e-300)
    n_eff = 1.0 / np.maximum(np.sum(w ** 2, axis=0), 1e-300)
    return t.ppf(0.975, np.maximum(n_eff - 1.0, 1.0))


def finite_difference_derivative(render: Any, angle_deg: Any, *, step_deg: float = 0.5
                                 ) -> np.ndarray:
    """∂L/∂s per degree by central differences: `render(angle_deg)` → [..., λ] must use common
    random numbers for s ± step (the same seed), so the Monte-Carlo noise cancels."""
    out = []
    for a in np.asarray(angle_deg, dtype=float):
        out.append((np.asarray(render(a + step_deg)) - np.asarray(render(a - step_deg)))
                   / (2.0 * step_deg))
    return np.stack(out, axis=-2)
