"""Fit the Cook-Torrance/GGX model (brdf_model) to one material's in-plane spectral BRDF.

Cost (paper Eqs. 7-9, after Löw et al. 2012):
    E(p) = Σ_geometries Σ_λ [ ln(1 + μ·f_model) − ln(1 + μ·f_meas) ]²,   μ = cos^w θi
with cosθi = ωi·n of the (tilted) light direction and w the weighting exponent (default 2, the
paper used 1…4 and 6).  NaN samples and blocked geometries are left out.

Separable solve (variable projection):
- outer: (α, η, c) by `scipy.optimize.least_squares` (trf, box bounds, a few starts in α), on
  the *projected* residuals, i.e. residuals evaluated at the optimal (kd, ks) for those (α, η, c),
  with Kaufman's variable-projection Jacobian (`FitProblem.projected_jacobian`; one inner solve
  per iteration instead of four for finite differences, ~4x faster);
- inner: for fixed (α, η, c) the model f = kd·(1/π) + ks·S_g(α, η) − c is linear in (kd, ks)
  per wavelength, but the log cost is not.  Per wavelength we (1) solve the first-order
  linearisation ln(1+μf) − ln(1+μy) ≈ μ(f − y)/(1 + μy) as a weighted 2-variable NNLS, which is
  exact at the optimum to first order in the residual, and (2) refine with projected Gauss-Newton
  steps on the exact log residuals (each step is again a 2-variable NNLS, solved in closed form by
  enumerating the four active sets; a step that raises the cost is halved).  It is iterated to
  convergence (|Δ| < 1e-10 relative; two or three steps), so the inner optimum is the true log-cost optimum with
  kd, ks ≥ 0, vectorised over all wavelengths at once.
- coarse-to-fine: the three global parameters are first found on a 10 nm subset of the spectrum
  (`outer_step_nm`; α, η, c are shared by all wavelengths and the spectra are smooth, so 41 bands
  carry the same information as 401), then polished on the full grid, then kd, ks are solved at
  every wavelength.

c and kd/π are interchangeable as long as kd stays ≥ 0 (only the difference kd/π − c enters f).
The result is made unique by taking the smallest c in its bounds that gives the same f
(c is lowered and kd lowered by π·Δc until c hits its lower bound or min kd hits 0), which is
the paper's "for some materials it assumes value zero".

Fit error: relative RMS over all valid samples, 100·√mean(((f_fit − f_meas)/f_meas)²) in %.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import DataError
from normbox_lab.predict.brdf_model import (
    GONIO_TILT_DEG,
    MaterialFit,
    inplane_directions,
    specular_basis,
)

#: Box bounds of the outer parameters: α (GGX roughness), η (refractive index), c (sr⁻¹).
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "alpha": (1e-3, 1.5), "eta": (1.01, 3.0), "c": (0.0, 0.1)}
#: Start points (α, η, c) of the multi-start outer fit.
DEFAULT_STARTS: tuple[tuple[float, float, float], ...] = (
    (0.08, 1.5, 0.0), (0.3, 1.5, 0.0), (0.8, 1.5, 0.0))

_INV_PI = 1.0 / np.pi
#: the wavelength step (nm) of the coarse outer fit (see the module docstring)
OUTER_STEP_NM = 10.0
#: inner optima a `FitProblem` keeps (an outer evaluation's Jacobian, the polish's start and
#: the final solve at the optimum find theirs there)
_SOLVED_KEPT = 64


@dataclass
class BrdfData:
    """One material's in-plane spectral BRDF: values [geometry, wavelength] in sr⁻¹ (NaN = none)."""

    name: str
    theta_i_deg: np.ndarray
    theta_o_deg: np.ndarray
    wavelength_nm: np.ndarray
    brdf_per_sr: np.ndarray
    tilt_deg: float = GONIO_TILT_DEG

    def __post_init__(self) -> None:
        self.theta_i_deg = np.asarray(self.theta_i_deg, dtype=np.float64).ravel()
        self.theta_o_deg = np.asarray(self.theta_o_deg, dtype=np.float64).ravel()
        self.wavelength_nm = np.asarray(self.wavelength_nm, dtype=np.float64).ravel()
        self.brdf_per_sr = np.asarray(self.brdf_per_sr, dtype=np.float64)
        n_g, n_l = self.theta_i_deg.size, self.wavelength_nm.size
        if self.theta_o_deg.size != n_g or self.brdf_per_sr.shape != (n_g, n_l):
            raise DataError(self.name, "brdf_per_sr",
                            f"shape {self.brdf_per_sr.shape} does not match {n_g} geometries "
                            f"x {n_l} wavelengths")

    @classmethod
    def from_readings(cls, name: str, readings: Iterable[Any]) -> BrdfData:
        """From `BrdfReading`s of one material; blocked geometries become NaN rows."""
        rs = list(readings)
        if not rs:
            raise DataError(name, "readings", "no BRDF readings")
        wl = rs[0].wavelength_nm
        rows = []
        for r in rs:
            if r.wavelength_nm.shape != wl.shape or not np.allclose(r.wavelength_nm, wl):
                raise DataError(name, f"θi={r.theta_i_deg} θo={r.theta_o_deg}",
                                "wavelength grid differs from the first reading")
            rows.append(np.full(wl.shape, np.nan) if r.blocked else r.brdf_per_sr)
        return cls(name, [r.theta_i_deg for r in rs], [r.theta_o_deg for r in rs], wl,
                   np.array(rows), float(rs[0].tilt_deg))

    def wavelength_subset(self, step_nm: float | None) -> BrdfData:
        """Every sample closest to a multiple of step_nm (None or ≤ grid spacing: all)."""
        if step_nm is None or self.wavelength_nm.size < 3:
            return self
        wl = self.wavelength_nm
        keep = np.abs((wl - wl[0]) / step_nm - np.round((wl - wl[0]) / step_nm)) < 1e-6
        if keep.sum() < 3 or keep.all():
            return self
        return BrdfData(self.name, self.theta_i_deg, self.theta_o_deg, wl[keep],
                        self.brdf_per_sr[:, keep], self.tilt_deg)


def _nnls2(m00, m01, m11, v0, v1):
    """min ½xᵀMx − vᵀx s.t. x ≥ 0 for many 2×2 problems at once (exact: all active sets)."""
    tiny = 1e-300
    det = m00 * m11 - m01 * m01
    ok = det > 1e-14 * np.maximum(m00 * m11, tiny)
    safe = np.where(ok, det, 1.0)
    fx0 = np.where(ok, (m11 * v0 - m01 * v1) / safe, -1.0)
    fx1 = np.where(ok, (m00 * v1 - m01 * v0) / safe, -1.0)
    a0 = np.where(m00 > tiny, np.maximum(v0, 0.0) / np.maximum(m00, tiny), 0.0)
    b1 = np.where(m11 > tiny, np.maximum(v1, 0.0) / np.maximum(m11, tiny), 0.0)
    zero = np.zeros_like(v0)
    cand0 = np.stack([fx0, a0, zero, zero])
    cand1 = np.stack([fx1, zero, b1, zero])
    obj = 0.5 * (m00 * cand0 ** 2 + 2 * m01 * cand0 * cand1 + m11 * cand1 ** 2) \
        - v0 * cand0 - v1 * cand1
    obj[0] = np.where((fx0 >= 0) & (fx1 >= 0), obj[0], np.inf)
    k = np.argmin(obj, axis=0)
    idx = np.arange(v0.size)
    return cand0[k, idx], cand1[k, idx]


class FitProblem:
    """Precomputed geometry and data for one material at one w."""

    def __init__(self, data: BrdfData, w: float = 2.0) -> None:
        self.data = data
        self.w = float(w)
        self.wi, self.wo = inplane_directions(data.theta_i_deg, data.theta_o_deg, data.tilt_deg)
        cos_i = self.wi[:, 2]
        y = data.brdf_per_sr
        self.mu = (np.clip(cos_i, 0.0, 1.0) ** self.w)[:, None]            # (n_g, 1)
        self.valid = np.isfinite(y) & (cos_i > 0)[:, None] & (self.wo[:, 2] > 0)[:, None]
        if not self.valid.any():
            raise DataError(data.name, "brdf_per_sr", "no valid samples to fit")
        self.y = np.where(self.valid, y, 0.0)
        if np.any(1.0 + self.mu * self.y <= 0.0):
            raise DataError(data.name, "brdf_per_sr", "values below −1/cos^w θi: log undefined")
        self.m = self.valid.astype(np.float64)
        self.g_hat = np.log1p(self.mu * self.y)
        # weights of the linearised problem, μ/(1 + μy)
        self.s_lin = self.m * self.mu / (1.0 + self.mu * self.y)
        #: (α, η, c) → the inner optimum (kd, ks), the last `_SOLVED_KEPT` solved
        self._solved_at: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}

    # -- model pieces ----------------------------------------------------------------------
    def basis(self, alpha: float, eta: float) -> np.ndarray:
        return specular_basis(self.wi, self.wo, alpha, eta)[:, None]      # (n_g, 1)

    def model(self, kd, ks, alpha, eta, c) -> np.ndarray:
        return kd[None, :] * _INV_PI + ks[None, :] * self.basis(alpha, eta) - c

    def residuals(self, kd, ks, alpha, eta, c) -> np.ndarray:
        """(n_g, n_λ) log residuals, 0 where not valid."""
        f = self.model(kd, ks, alpha, eta, c)
        q = np.maximum(1.0 + self.mu * f, 1e-12)
        return self.m * (np.log(q) - self.g_hat)

    def cost(self, kd, ks, alpha, eta, c) -> float:
        return float(np.sum(self.residuals(kd, ks, alpha, eta, c) ** 2))

    # -- inner linear-in-(kd, ks) problem -------------------------------------------------
    def inner(self, alpha: float, eta: float, c: float, *, max_iter: int = 40,
              tol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
        b = self.basis(alpha, eta)
        a = _INV_PI
        # (1) linearised weighted NNLS: min Σ s²(kd·a + ks·B − (y + c))²
        s2 = self.s_lin ** 2
        t = self.y + c
        kd, ks = _nnls2((s2 * a * a).sum(0), (s2 * a * b).sum(0), (s2 * b * b).sum(0),
                        (s2 * a * t).sum(0), (s2 * b * t).sum(0))
        # (2) projected Gauss-Newton on the exact log residuals; each cost evaluation keeps
        # its q = 1 + μf and residuals, which the next step's Jacobian uses (no second log)
        cost, q, r = self._cost_q_r(kd, ks, b, c)
        mm = self.m * self.mu
        for _ in range(max_iter):
            j0 = mm * a / q
            j1 = mm * b / q
            jx = j0 * kd + j1 * ks - r          # target of the step problem in x' = x + δ
            n_kd, n_ks = _nnls2((j0 * j0).sum(0), (j0 * j1).sum(0), (j1 * j1).sum(0),
                                (j0 * jx).sum(0), (j1 * jx).sum(0))
            new_cost, n_q, n_r = self._cost_q_r(n_kd, n_ks, b, c)
            step = np.maximum(np.abs(n_kd - kd), np.abs(n_ks - ks))
            scale = np.maximum(np.abs(kd) + np.abs(ks), 1e-12)
            # damp steps that raise the cost, but not a step already below the tolerance: it
            # raises the cost by rounding at the optimum and is refused as it is (halving it
            # 8 times, as was done, moved kd, ks by less than the tolerance)
            worse = np.flatnonzero((new_cost > cost) & (step > tol * scale))
            if worse.size:
                self._halve(kd, ks, n_kd, n_ks, new_cost, cost, worse, b, c)
                n_q[:, worse], n_r[:, worse] = self._q_r(n_kd[worse], n_ks[worse], b, c,
                                                         worse)
                step = np.maximum(np.abs(n_kd - kd), np.abs(n_ks - ks))
            accept = new_cost <= cost
            if accept.all():
                kd, ks, cost, q, r = n_kd, n_ks, new_cost, n_q, n_r
            else:
                kd = np.where(accept, n_kd, kd)
                ks = np.where(accept, n_ks, ks)
                cost = np.where(accept, new_cost, cost)
                q = np.where(accept, n_q, q)
                r = np.where(accept, n_r, r)
            if np.all((step <= tol * scale) | ~accept):
                break
        return kd, ks

    def _halve(self, kd, ks, n_kd, n_ks, new_cost, cost, worse, b, c) -> None:
        """The wavelengths `worse` (steps that raised the cost): their step halved until the
        cost is no longer higher, at most 8 times (`n_kd`, `n_ks`, `new_cost` updated in
        place).  Near the optimum a few wavelengths' steps raise the cost by rounding and are
        halved all 8 times: the 8 halvings are evaluated at once, for those wavelengths only,
        and the first that does not raise the cost is taken (else the 8th), as halving one at
        a time would."""
        k_kd, k_ks = kd[worse], ks[worse]
        h_kd, h_ks = np.empty((8, worse.size)), np.empty((8, worse.size))
        x_kd, x_ks = n_kd[worse], n_ks[worse]
        for h in range(8):
            x_kd = 0.5 * (k_kd + x_kd)
            x_ks = 0.5 * (k_ks + x_ks)
            h_kd[h], h_ks[h] = x_kd, x_ks
        costs = self._cost_per_wl(h_kd.ravel(), h_ks.ravel(), b, c,
                                  np.tile(worse, 8)).reshape(8, worse.size)
        ok = ~(costs > cost[worse])
        level = np.where(ok.any(axis=0), ok.argmax(axis=0), 7)
        pick = np.arange(worse.size)
        n_kd[worse], n_ks[worse] = h_kd[level, pick], h_ks[level, pick]
        new_cost[worse] = costs[level, pick]

    def _q_r(self, kd, ks, b, c, columns: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """q = 1 + μf (at least 1e-12) and the log residuals; `columns`: only those
        wavelengths (kd, ks theirs)."""
        m, g_hat = (self.m, self.g_hat) if columns is None else \
            (self.m[:, columns], self.g_hat[:, columns])
        f = kd * _INV_PI + ks * b - c
        q = np.maximum(1.0 + self.mu * f, 1e-12)
        return q, m * (np.log(q) - g_hat)

    def _cost_q_r(self, kd, ks, b, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The log cost per wavelength, with `_q_r`'s q and residuals."""
        q, r = self._q_r(kd, ks, b, c)
        return np.sum(r ** 2, axis=0), q, r

    def _cost_per_wl(self, kd, ks, b, c, columns: np.ndarray | None = None) -> np.ndarray:
        """The log cost per wavelength; `columns`: only those wavelengths (kd, ks theirs)."""
        return np.sum(self._q_r(kd, ks, b, c, columns)[1] ** 2, axis=0)

    def _solved(self, p: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        key = tuple(float(v) for v in p)
        found = self._solved_at.pop(key, None)
        if found is None:
            found = self.inner(*key)
            if len(self._solved_at) >= _SOLVED_KEPT:
                del self._solved_at[next(iter(self._solved_at))]
        self._solved_at[key] = found          # the most recent last
        return found

    def projected_residuals(self, p: Sequence[float]) -> np.ndarray:
        """Residuals at the inner optimum for (α, η, c): the outer least-squares function."""
        kd, ks = self._solved(p)
        return self.residuals(kd, ks, *(float(v) for v in p))[self.valid]

    def projected_jacobian(self, p: Sequence[float]) -> np.ndarray:
        """Kaufman's variable-projection Jacobian: P⊥·∂r/∂(α, η, c) at the inner optimum.

        Per wavelength, the columns for (α, η, c) are projected onto the orthogonal complement
        of the inner Jacobian's free columns (kd, ks not at their bound 0).  This makes c, which
        kd can absorb, correctly flat; Jᵀr is the exact gradient of the projected cost (the
        inner problem is at its optimum); only the Gauss-Newton curvature is approximated.
        ∂S/∂α, ∂S/∂η by central differences on the 153-value specular basis (cheap).
        """
        alpha, eta, c = (float(v) for v in p)
        kd, ks = self._solved(p)
        b = self.basis(alpha, eta)
        f = kd * _INV_PI + ks * b - c
        g = self.m * self.mu / np.maximum(1.0 + self.mu * f, 1e-12)      # ∂r/∂f
        j0 = g * _INV_PI
        j1 = g * b
        free0, free1 = kd > 0.0, ks > 0.0
        m00 = np.where(free0, (j0 * j0).sum(0), 1.0)
        m11 = np.where(free1, (j1 * j1).sum(0), 1.0)
        m01 = np.where(free0 & free1, (j0 * j1).sum(0), 0.0)
        det = m00 * m11 - m01 * m01
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        ha, he = 1e-6 * max(alpha, 1e-3), 1e-6 * eta
        d_alpha = (self.basis(alpha + ha, eta) - self.basis(alpha - ha, eta)) / (2 * ha)
        d_eta = (self.basis(alpha, eta + he) - self.basis(alpha, eta - he)) / (2 * he)
        cols = []
        for jp in (g * ks * d_alpha, g * ks * d_eta, -g):
            u0 = np.where(free0, (j0 * jp).sum(0), 0.0)
            u1 = np.where(free1, (j1 * jp).sum(0), 0.0)
            c0 = (m11 * u0 - m01 * u1) / det
            c1 = (m00 * u1 - m01 * u0) / det
            cols.append((jp - j0 * c0 - j1 * c1)[self.valid])
        return np.stack(cols, axis=1)


def _outer(problem: FitProblem, x0: Sequence[float], lo: np.ndarray, hi: np.ndarray,
           max_nfev: int | None = None):
    from scipy.optimize import least_squares

    x0 = np.clip(np.asarray(x0, dtype=np.float64), lo + 1e-9, hi - 1e-9)
    return least_squares(problem.projected_residuals, x0, jac=problem.projected_jacobian,
                         bounds=(lo, hi), method="trf",
                         x_scale=np.array([0.1, 0.1, 0.01]), xtol=1e-10, ftol=1e-12,
                         gtol=1e-12, max_nfev=max_nfev)


def canonical_c(kd: np.ndarray, c: float, c_lower: float) -> tuple[np.ndarray, float]:
    """Lowest c (≥ c_lower) with the same f: kd/π − c is what the data constrain."""
    if kd.size == 0:
        return kd, c
    delta = max(0.0, min(c - c_lower, float(np.min(kd)) * _INV_PI))
    return kd - np.pi * delta, c - delta


def fit_material(data: BrdfData, w: float = 2.0, *,
                 bounds: dict[str, tuple[float, float]] | None = None,
                 starts: Sequence[Sequence[float]] | None = None,
                 outer_step_nm: float | None = OUTER_STEP_NM) -> MaterialFit:
    """Fit one material; see the module docstring for the method."""
    t0 = time.perf_counter()
    b = {**DEFAULT_BOUNDS, **(bounds or {})}
    lo = np.array([b["alpha"][0], b["eta"][0], b["c"][0]])
    hi = np.array([b["alpha"][1], b["eta"][1], b["c"][1]])
    coarse = FitProblem(data.wavelength_subset(outer_step_nm), w)
    full = FitProblem(data, w) if coarse.data is not data else coarse
    runs = [_outer(coarse, s, lo, hi) for s in (starts or DEFAULT_STARTS)]
    best = min(runs, key=lambda r: r.cost)
    nfev = sum(r.nfev for r in runs)
    x = best.x
    final = best
    if full is not coarse:
        polish = _outer(full, x, lo, hi)
        nfev += polish.nfev
        if 2.0 * polish.cost <= full.cost(*full._solved(x), *x):
            x, final = polish.x, polish
    alpha, eta, c = (float(v) for v in x)
    kd, ks = full._solved((alpha, eta, c))  # the polish solved it (kept): not again
    kd, c = canonical_c(kd, c, float(lo[2]))
    fit = MaterialFit(data.name, data.wavelength_nm, kd, ks, alpha, eta, c, 0.0, float(w),
                      cost=full.cost(kd, ks, alpha, eta, c), tilt_deg=data.tilt_deg,
                      metadata={"n_starts": len(runs), "nfev": int(nfev),
                                "start_costs": [float(2 * r.cost) for r in runs],
                                "outer_step_nm": outer_step_nm,
                                "converged": bool(final.status > 0),
                                "status_message": str(final.message),
                                "bounds": {k: [float(v[0]), float(v[1])] for k, v in b.items()},
                                "fit_time_s": time.perf_counter() - t0})
    fit.fit_error_pct = fit_error_pct(fit, data)
    return fit


def fit_job(payload: tuple[BrdfData, float]) -> MaterialFit:
    """One material's fit, ``(data, w)`` → `fit_material` (the `offload` job)."""
    data, w = payload
    return fit_material(data, w)


def fit_materials(data: Mapping[str, BrdfData], w: float = 2.0, *,
                  children: int | None = None,
                  on_fit: Callable[[str, MaterialFit], None] | None = None
                  ) -> dict[str, MaterialFit]:
    """`fit_material` of every material, in this process and `children` child processes
    (default `offload.idle_children()`), each taking the next material as it finishes one.
    The materials are independent, so each fit is the one this process would compute, bit
    for bit.  `on_fit(name, fit)` is called in name order, here (the store sees the same
    artifacts in the same order).  Data that cannot be fitted raise their `DataError` after
    the fits of the materials before it in name order, as fitting one after the other would:
    each material's problem is built here first (milliseconds)."""
    from normbox_lab.analyze.offload import Offload, idle_children

    names = sorted(data)
    todo, failure = names, None
    for k, name in enumerate(names):
        try:                               # what fit_material would refuse, before it runs
            FitProblem(data[name].wavelength_subset(OUTER_STEP_NM), w)
            FitProblem(data[name], w)
        except DataError as exc:
            todo, failure = names[:k], exc
            break
    n = min(idle_children() if children is None else int(children), len(todo) - 1)
    offload = Offload("normbox_lab.analyze.fit:fit_job", n)
    fits: dict[str, MaterialFit] = {}

    def deliver() -> None:                 # the fits ready in name order, to on_fit
        while len(fits) < len(todo) and offload.done(todo[len(fits)]):
            name = todo[len(fits)]
            fits[name] = offload.results[name]
            if on_fit is not None:
                on_fit(name, fits[name])

    try:
        for name in todo:
            offload.submit(name, (data[name], w))
        while (item := offload.take()) is not None:
            offload.finish(item[0], fit_job(item[1]))
            deliver()
        offload.finish_here(fit_job)
    finally:
        offload.close()
    deliver()
    if failure is not None:
        raise failure
    return fits


def fit_cost(fit: MaterialFit, data: BrdfData, w: float | None = None) -> float:
    """Löw log cost E (paper Eq. 9) of a fit on data (w defaults to the fit's)."""
    p = FitProblem(data, fit.w if w is None else w)
    return p.cost(np.interp(data.wavelength_nm, fit.wavelength_nm, fit.kd),
                  np.interp(data.wavelength_nm, fit.wavelength_nm, fit.ks),
                  fit.alpha, fit.eta, fit.c)


def relative_error(fit: MaterialFit, data: BrdfData) -> np.ndarray:
    """(f_fit − f_meas)/f_meas per [geometry, wavelength]; NaN where not valid or f_meas ≤ 0."""
    f = fit.brdf_inplane(data.theta_i_deg, data.theta_o_deg)
    if f.shape[-1] != data.wavelength_nm.size or not np.allclose(fit.wavelength_nm,
                                                                   data.wavelength_nm):
        f = np.stack([np.interp(data.wavelength_nm, fit.wavelength_nm, row) for row in f])
    y = data.brdf_per_sr
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (f - y) / y
    return np.where(np.isfinite(y) & (y > 0), rel, np.nan)


#: width (σ, deg) of the Gaussian kernel over (θi, θo) that `fit_error_at` averages with: on
#: the 10° gonio grid it gives a geometry on a grid point and one between four points nearly
#: the same effective number of samples (5.5 and 6.1), so the error model does not alternate
#: between adjacent sample angles (nearest samples only: one sample at 30°, 40°…, the mean of
#: four at 35°, 45°…, so the gonio noise in it halved every other angle)
FIT_ERROR_KERNEL_DEG = 7.0


def fit_error_at(fit: MaterialFit, data: BrdfData, theta_i_deg: float,
                 theta_o_deg: float, kernel_deg: float = FIT_ERROR_KERNEL_DEG) -> np.ndarray:
    """Relative fit error spectrum at a geometry: the mean over the measured gonio geometries
    weighted by a Gaussian of their distance to (θi, θo) (σ = `kernel_deg`; samples beyond 3σ
    ignored), NaNs skipped; the nearest samples alone with ``kernel_deg=0``."""
    d = np.hypot(data.theta_i_deg - theta_i_deg, data.theta_o_deg - theta_o_deg)
    rel = relative_error(fit, data)
    ok = np.isfinite(rel).any(axis=1)
    if not ok.any():
        return np.full(data.wavelength_nm.size, np.nan)
    if kernel_deg <= 0:
        w = (ok & (d <= d[ok].min() + 1e-9)).astype(float)
    else:
        w = np.where(ok & (d <= 3.0 * kernel_deg), np.exp(-0.5 * (d / kernel_deg) ** 2), 0.0)
        if not np.any(w > 0):
            w = (ok & (d <= d[ok].min() + 1e-9)).astype(float)
    valid = np.isfinite(rel) & (w[:, None] > 0)
    num = np.sum(np.where(valid, rel, 0.0) * w[:, None], axis=0)
    den = np.sum(valid * w[:, None], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):   # a wavelength with no sample: NaN
        return np.where(den > 0, num / den, np.nan)


def fit_error_pct(fit: MaterialFit, data: BrdfData, mask: np.ndarray | None = None) -> float:
    """Relative RMS error in %, over all valid samples (or the geometries selected by mask)."""
    rel = relative_error(fit, data)
    if mask is not None:
        rel = rel[np.asarray(mask)]
    rel = rel[np.isfinite(rel)]
    return float(100.0 * np.sqrt(np.mean(rel ** 2))) if rel.size else float("nan")


def data_from_store_run(store: Store, run_ref: int | str) -> dict[str, BrdfData]:
    """Group a gonio run's BRDF readings by material (the key's first path component)."""
    groups: dict[str, list[Any]] = {}
    for r in store.readings(run_ref, kind="brdf"):
        groups.setdefault(r.key.split("/")[0], []).append(store.as_brdf(r))
    return {name: BrdfData.from_readings(name, rs) for name, rs in groups.items()}


def half_polar_axes(fig: Any, nrow: int, ncol: int, k: int) -> Any:
    """Panel k of an nrow × ncol grid: a polar half-plane for in-plane BRDFs (0° up, angles
    clockwise, −90…90°)."""
    ax = fig.add_subplot(nrow, ncol, k + 1, projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    return ax


def polar_plot(data: BrdfData | None, fits: MaterialFit | dict[str, MaterialFit],
               wavelength_nm: float, theta_i_deg: Sequence[float] | None = None,
               title: str | None = None):
    """Paper Figs. 10/11: one polar panel per incident angle, measured points vs fitted curves.

    Angles on the polar axis are θo (0 = normal, up); the light sits at θi (marked by a ray),
    the specular direction at −θi.  Returns a matplotlib Figure (Agg, no pyplot state).
    """
    from matplotlib.figure import Figure

    if isinstance(fits, MaterialFit):
        fits = {"fit": fits}
    if theta_i_deg is None:
        theta_i_deg = (np.unique(data.theta_i_deg) if data is not None
                       else np.arange(-80.0, 1.0, 10.0))
    tis = sorted(np.asarray(theta_i_deg, dtype=float), key=lambda t: abs(t))
    n = len(tis)
    ncol = 3 if n > 4 else n
    nrow = int(np.ceil(n / ncol))
    fig = Figure(figsize=(3.2 * ncol, 2.6 * nrow + 0.6))
    th_fine = np.linspace(-89.0, 89.0, 357)
    for k, ti in enumerate(tis):
        ax = half_polar_axes(fig, nrow, ncol, k)
        rmax = 0.0
        if data is not None:
            li = int(np.argmin(np.abs(data.wavelength_nm - wavelength_nm)))
            sel = np.isclose(data.theta_i_deg, ti)
            to = data.theta_o_deg[sel]
            y = data.brdf_per_sr[sel, li]
            ok = np.isfinite(y)
            ax.plot(np.deg2rad(to[ok]), y[ok], "o", ms=3, color="k", label="measured")
            rmax = max(rmax, float(np.nanmax(y)) if ok.any() else 0.0)
        for j, (label, fit) in enumerate(fits.items()):
            f = fit.brdf_inplane(np.full_like(th_fine, ti), th_fine)
            fl = np.array([np.interp(wavelength_nm, fit.wavelength_nm, row) for row in f])
            ax.plot(np.deg2rad(th_fine), np.maximum(fl, 0.0), "-", lw=1.2, color=f"C{j}",
                    label=f"{label} (w={fit.w:g})")
            rmax = max(rmax, float(np.max(fl)))
        ax.plot([np.deg2rad(ti)] * 2, [0, rmax * 1.05 or 1.0], ":", color="0.5", lw=0.8)
        ax.set_rmax(rmax * 1.05 or 1.0)
        ax.set_yticklabels([])
        ax.set_title(f"θi = {ti:.0f}° (r max {rmax:.3g})", fontsize=8)
        ax.tick_params(labelsize=6)
        if k == 0:
            ax.legend(fontsize=6, loc="lower left", bbox_to_anchor=(-0.3, -0.25))
    fig.suptitle(title or f"{(data.name if data is not None else '')} BRDF at "
                 f"{wavelength_nm:g} nm [sr⁻¹]", fontsize=10)
    return fig
