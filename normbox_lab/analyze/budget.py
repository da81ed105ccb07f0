"""The error budget: each error source's contribution to NSE / NRMSE / ΔE00, per patch × angle.

Each source of the error path (`normbox_lab.core.error_sources`, plus the fitting error) is a
distribution; its effect on the reference-minus-prediction difference is propagated through
the comparison by sampling its draws with the structure the source has in the lab (per reading,
per sweep angle, per campaign), linearised where that is accurate:

| source | perturbation δL of the difference | from |
|---|---|---|
| angle, angle-sweep, angle-offset | u · ∂P/∂s | the fast renderer, central differences with common random numbers |
| geometry | Σ_f u_f · ∂P/∂f (f: sample height, aperture x/y, box size) | renderer, per angle (white patch), relative |
| homogeneity | u · ∂P/∂h | renderer, per angle (white patch), relative |
| cs1000 | u · R | — |
| cs1000-wl | u · ∂R/∂λ | the reference spectrum |
| lamp, diffusivity | u · R (one draw per campaign) | — |
| gonio-cal | u · P (the fitted BRDFs scale with the calibration) | — |
| qepro-nonlin | −x · P / 2 (mean of the residual compression over a reading, fixed sign) | linear model |
| qepro-snr | P · N(0, 1/(SNR·√n_geometries)) per material (noise averaged by the fit) | linear model |
| render | N(0, SE_pred) + the truth's own: its achieved SE where known (`truth_se`), else SE_pred scaled to a worst band of x (the `render` switch, else the virtual run's `truth_rel_se`; none for a measured truth) | the prediction's standard errors |
| fit | R · (d·err_d + (1 − d)·err_i) (the paper's error model, Fig. 12) | the fits' residuals |

A source's contribution is the RMS over its draws of NRMSE(R, R + δ) (and the mean ΔE00(R, R + δ)):
the NRMSE it alone would produce.  The total is the RMS over draws of the NRMSE of all sources'
perturbations together (random ones drawn, fixed ones adding coherently), so it is not simply
the quadrature sum where fixed sources share a sign.
`significant`: the observed NRMSE (ΔE00) exceeds the 95th percentile of what the measurement
sources (all but fit) produce together, i.e. the prediction's difference is beyond what the
ground truth's own errors explain; the percentile from `SIGNIFICANCE_DRAWS` (1024) draws, so
that a prediction the sources explain is marked 5 % of the time, not the 6-7 % of 64 draws.
The observed NRMSE and ΔE00 get 95 % intervals from a parametric bootstrap over the
measurement sources (the same draws).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.core.error_sources import (
    GEOMETRY_FIELDS,
    PAPER_FIGURES,
    SOURCE_FIELDS,
    ErrorSources,
    parse_error_spec,
)
from normbox_lab.core.errors import ConfigError

#: the budget's sources, in table order
BUDGET_SOURCES = ("angle", "angle-sweep", "angle-offset", "geometry", "cs1000", "cs1000-wl",
                  "qepro-snr", "qepro-nonlin", "gonio-cal", "homogeneity", "diffusivity",
                  "lamp", "render", "fit")
N_GONIO_GEOMETRIES = 153


@dataclass
class BudgetInputs:
    """Arrays [patch, angle, λ] on one wavelength grid; derivatives per unit of the source."""

    wavelength_nm: np.ndarray
    angle_deg: np.ndarray
    patches: list[int]
    reference: np.ndarray
    prediction: np.ndarray
    prediction_se: np.ndarray
    d_angle: np.ndarray | None = None                      # ∂P/∂s, per degree
    #: relative derivatives, [patch, angle, λ] (or [angle, λ]: one for every patch)
    d_geometry_rel: dict[str, np.ndarray] = field(default_factory=dict)  # per mm
    d_homogeneity_rel: np.ndarray | None = None            # per unit fraction
    fit_nse: np.ndarray | None = None                      # error model's simulated NSE
    white_patch_index: int = 0
    #: the truth's own Monte-Carlo noise, as the largest band's relative standard error: the
    #: virtual Normbox renders the truth independently of the prediction (its lab config's
    #: ``[render] truth_rel_se``); 0 for a measured truth
    truth_rel_se: float = 0.0
    #: the prediction's own target (largest band relative SE; 0 = unknown): a truth rendered
    #: like the prediction, with the same adaptive first pass, to `truth_rel_se` instead has
    #: the prediction's standard errors × truth_rel_se / prediction_rel_se (both renders beat
    #: a loose target by the same margin)
    prediction_rel_se: float = 0.0
    #: truth and prediction rendered with common random numbers (a validation that wants the
    #: sources alone): their Monte-Carlo noise cancels unless the `render` source is on
    shared_noise: bool = False
    #: the renders' noise is one draw for all bands of a configuration (the fast band-vector
    #: renderer: every path carries every band; measured: a configuration's mean z spreads as
    #: much as its single bands), not independent per band (Mitsuba's spectral sampling)
    render_noise_correlated: bool = False
    #: the truth's own Monte-Carlo standard error as achieved, [patch, angle, λ] (the virtual
    #: world's renders), or None: then it is modelled from `truth_rel_se` / the `render`
    #: source's stated worst band (a randomised-QMC render can beat a stated target by 2-4x:
    #: the stated value then overstates the term)
    truth_se: np.ndarray | None = None


@dataclass
class BudgetResult:
    sources: list[str]
    spec: str
    angle_deg: np.ndarray
    patches: list[int]
    nrmse: np.ndarray                 # [source, patch, angle] contribution (fraction)
    delta_e00: np.ndarray             # [source, patch, angle]
    nse: np.ndarray                   # [source, angle, λ] RMS over patches and draws
    total_nrmse: np.ndarray           # [patch, angle] quadrature sum
    observed_nrmse: np.ndarray        # [patch, angle]
    observed_nrmse_ci: np.ndarray     # [2, patch, angle] 95 % interval
    observed_delta_e00: np.ndarray
    observed_delta_e00_ci: np.ndarray
    measurement_nrmse_p95: np.ndarray  # [patch, angle]
    measurement_delta_e00_p95: np.ndarray
    significant_nrmse: np.ndarray     # [patch, angle] bool
    significant_delta_e00: np.ndarray
    angle_offsets: Any = None         # analyze.angles.AngleOffsets
    timings_s: dict[str, float] = field(default_factory=dict)
    #: where the `render` term's truth noise came from (`truth_noise_source`)
    truth_noise: str = ""

    def share_by_angle(self) -> np.ndarray:
        """[source, angle]: each source's share of the total NRMSE² (mean over patches)."""
        c2 = np.mean(self.nrmse ** 2, axis=1)
        tot = np.maximum(c2.sum(axis=0, keepdims=True), 1e-300)
        return c2 / tot

    def nrmse_by_angle(self) -> np.ndarray:
        """[source, angle]: RMS over patches of each source's NRMSE contribution."""
        return np.sqrt(np.mean(self.nrmse ** 2, axis=1))

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {k: np.asarray(getattr(self, k)) for k in (
            "angle_deg", "nrmse", "delta_e00", "nse", "total_nrmse", "observed_nrmse",
            "observed_nrmse_ci", "observed_delta_e00", "observed_delta_e00_ci",
            "measurement_nrmse_p95", "measurement_delta_e00_p95")}
        out["significant_nrmse"] = self.significant_nrmse.astype(float)
        out["significant_delta_e00"] = self.significant_delta_e00.astype(float)
        out["patches"] = np.array(self.patches, dtype=float)
        if self.angle_offsets is not None:
            out.update(self.angle_offsets.to_arrays())
        return out

    def store(self, store: Store, name: str, run_ref: Any = None) -> int:
        return store.add_artifact(
            kind="error-budget", name=name, arrays=self.to_arrays(),
            metadata={"sources": list(self.sources), "spec": self.spec,
                      "timings_s": dict(self.timings_s), "truth_noise": self.truth_noise},
            run_ref=run_ref)

    def table(self) -> str:
        """Per angle: each source's NRMSE contribution (%, RMS over patches), the total, the
        observed NRMSE (mean, with the mean 95 % interval), significant configurations."""
        by = 100 * self.nrmse_by_angle()
        head = ["source".ljust(13)] + [f"{a:>6g}°" for a in self.angle_deg]
        lines = [" ".join(head)]
        for s, row in zip(self.sources, by):
            lines.append(" ".join([s.ljust(13)] + [f"{v:7.2f}" for v in row]))
        tot = 100 * np.sqrt(np.mean(self.total_nrmse ** 2, axis=0))
        obs = 100 * np.mean(self.observed_nrmse, axis=0)
        lo = 100 * np.mean(self.observed_nrmse_ci[0], axis=0)
        hi = 100 * np.mean(self.observed_nrmse_ci[1], axis=0)
        lines.append(" ".join(["total".ljust(13)] + [f"{v:7.2f}" for v in tot]))
        lines.append(" ".join(["observed".ljust(13)] + [f"{v:7.2f}" for v in obs]))
        lines.append(" ".join(["  95% low".ljust(13)] + [f"{v:7.2f}" for v in lo]))
        lines.append(" ".join(["  95% high".ljust(13)] + [f"{v:7.2f}" for v in hi]))
        de = np.mean(self.observed_delta_e00, axis=0)
        lines.append(" ".join(["ΔE00 obs".ljust(13)] + [f"{v:7.2f}" for v in de]))
        sig = np.sum(self.significant_nrmse, axis=0)
        lines.append(" ".join(["signif. n".ljust(13)] + [f"{int(v):7d}" for v in sig]))
        return "\n".join(lines)


# --- perturbations ------------------------------------------------------------------------------
def _draws(m: Any, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return np.asarray(m.draw(rng, shape), dtype=float).reshape(shape)


def perturbations(name: str, errors: ErrorSources, x: BudgetInputs, n_draws: int,
                  rng: np.random.Generator) -> np.ndarray | None:
    """δ of the reference-minus-prediction difference, [draw, patch, angle, λ]; None when off or
    not computable from the inputs."""
    R, P = x.reference, x.prediction
    n_p, n_a, _ = R.shape
    K = n_draws
    if name == "fit":
        return None if x.fit_nse is None else (R * x.fit_nse)[None]
    if name == "render":
        if x.shared_noise and not errors.render_rel_se:
            return None            # truth and prediction share their random numbers
        def noise() -> np.ndarray:
            if x.render_noise_correlated:
                return rng.standard_normal((K,) + R.shape[:-1] + (1,))
            return _band_noise(rng, K, R.shape, x.wavelength_nm)

        se = x.prediction_se[None] * noise()
        truth_rel_se = errors.render_rel_se or (0.0 if x.shared_noise else x.truth_rel_se)
        if x.truth_se is not None and (errors.render_rel_se or not x.shared_noise):
            # the truth's noise as its renders achieved it
            se = se + np.asarray(x.truth_se, dtype=float)[None] * noise()
        elif truth_rel_se and not errors.render_rel_se and x.prediction_rel_se:
            # the world's truth, rendered as the prediction is, to its own target
            se = se + (x.prediction_se * (truth_rel_se / x.prediction_rel_se))[None] * noise()
        elif truth_rel_se:
            # the truth rendered to a largest band error x: the prediction's SE spectrum scaled
            with np.errstate(divide="ignore", invalid="ignore"):
                worst = np.nanmax(np.where(P > 0, x.prediction_se / P, 0.0), axis=-1)
            scale = truth_rel_se / np.maximum(worst, 1e-12)
            se = se + (x.prediction_se * scale[..., None])[None] * noise()
        return se
    if not errors.is_on(name):
        return None
    if name in ("angle", "angle-sweep", "angle-offset"):
        if x.d_angle is None:
            return None
        if name == "angle":
            u = _draws(errors.angle_deg, rng, (K, n_p, n_a))
        elif name == "angle-sweep":
            u = np.broadcast_to(_draws(errors.angle_sweep_deg, rng, (K, 1, n_a)), (K, n_p, n_a))
        else:
            off = np.array([sum(v for a0, v in errors.angle_offset_deg.items()
                                if abs(a0 - a) < 0.05) for a in x.angle_deg])
            u = np.broadcast_to(off[None, None, :], (1, n_p, n_a))
        return u[..., None] * x.d_angle[None]
    if name == "geometry":
        if not x.d_geometry_rel:
            return None
        d = np.zeros((K,) + R.shape)
        for f in GEOMETRY_FIELDS:
            if f in x.d_geometry_rel:
                u = _draws(errors.geometry_mm, rng, (K, 1, 1, 1))
                d += u * _per_patch(x.d_geometry_rel[f])[None] * P[None]
        return d
    if name == "homogeneity":
        if x.d_homogeneity_rel is None:
            return None
        u = _draws(errors.homogeneity, rng, (K, 1, 1, 1))
        return u * _per_patch(x.d_homogeneity_rel)[None] * P[None]
    if name == "cs1000":
        return _draws(errors.cs1000_gain, rng, (K, n_p, n_a))[..., None] * R[None]
    if name == "cs1000-wl":
        slope = np.gradient(R, x.wavelength_nm, axis=-1)
        return _draws(errors.cs1000_shift_nm, rng, (K, n_p, n_a))[..., None] * slope[None]
    if name in ("lamp", "diffusivity"):
        m = errors.lamp_repeatability if name == "lamp" else errors.diffusivity
        return _draws(m, rng, (K, 1, 1))[..., None] * R[None]
    if name == "gonio-cal":
        return _draws(errors.gonio_calibration, rng, (K, 1, 1))[..., None] * P[None]
    if name == "qepro-nonlin":
        return (-errors.qepro_nonlinearity / 2.0 * P)[None]
    if name == "qepro-snr":
        sigma = 1.0 / (errors.qepro_snr * np.sqrt(N_GONIO_GEOMETRIES))
        return rng.normal(0.0, sigma, (K, n_p, 1, 1)) * P[None]
    raise ValueError(f"unknown budget source {name!r}")


def _per_patch(rel: np.ndarray) -> np.ndarray:
    """A relative derivative as [patch, angle, λ] (an [angle, λ] one holds for every patch)."""
    rel = np.asarray(rel, dtype=float)
    return rel if rel.ndim == 3 else rel[None]


#: the sources whose errors every patch at one sweep angle shares (campaign-wide light,
#: geometry, gonio calibration, and the fit's error model): the second part of the
#: angle-offset intervals (`analyze.angles`)
COMMON_SOURCES = ("geometry", "homogeneity", "diffusivity", "lamp", "gonio-cal",
                  "qepro-nonlin", "fit")


#: the sources whose errors differ between the patches at one angle (per reading, or per
#: material): the model's part of the angle-offset intervals next to the jackknife
PATCH_INDEPENDENT_SOURCES = ("cs1000", "cs1000-wl", "render", "qepro-snr")


def common_draws(x: BudgetInputs, errors: ErrorSources, *,
                 sources: Sequence[str] = BUDGET_SOURCES, n_draws: int = 64,
                 seed: int = 1) -> np.ndarray | None:
    """Draws [draw, patch, angle, λ] of the reference-minus-prediction error that all patches
    share (`COMMON_SOURCES` among `sources`, random ones drawn, fixed ones in every draw);
    None when none is on."""
    return _source_draws(x, errors, COMMON_SOURCES, sources, n_draws, seed)


def independent_draws(x: BudgetInputs, errors: ErrorSources, *,
                      sources: Sequence[str] = BUDGET_SOURCES, n_draws: int = 64,
                      seed: int = 2) -> np.ndarray | None:
    """Draws [draw, patch, angle, λ] of the reference-minus-prediction error that differs
    between patches (`PATCH_INDEPENDENT_SOURCES` among `sources`); None when none is on."""
    return _source_draws(x, errors, PATCH_INDEPENDENT_SOURCES, sources, n_draws, seed)


def _source_draws(x: BudgetInputs, errors: ErrorSources, names: Sequence[str],
                  sources: Sequence[str], n_draws: int, seed: int) -> np.ndarray | None:
    rng = np.random.default_rng(seed)
    total = None
    for name in names:
        if name not in sources:
            continue
        d = perturbations(name, errors, x, n_draws, rng)
        if d is not None:
            total = d if total is None else total + d
    return None if total is None else np.broadcast_to(total, (n_draws,) + x.reference.shape)


def _band_noise(rng: np.random.Generator, n_draws: int, shape: tuple[int, ...],
                wavelength_nm: np.ndarray) -> np.ndarray:
    """Unit normal noise drawn per 5 nm render band and interpolated to the grid, as the
    renders' noise is (the 1 nm spectra are the bands interpolated)."""
    z = rng.standard_normal((n_draws,) + shape[:-1] + (_band_interpolation(
        tuple(np.asarray(wavelength_nm, dtype=float))).shape[0],))
    return z @ _band_interpolation(tuple(np.asarray(wavelength_nm, dtype=float)))


@functools.lru_cache(maxsize=8)
def _band_interpolation(wavelength_nm: tuple[float, ...]) -> np.ndarray:
    """[band, λ]: linear interpolation from the render's band centres to the grid (a matrix
    product is an order of magnitude faster than gathering for many draws)."""
    from normbox_lab.predict.render import BAND_CENTRES_NM

    wl = np.asarray(wavelength_nm)
    idx = np.interp(wl, BAND_CENTRES_NM, np.arange(BAND_CENTRES_NM.size))
    lo = np.floor(idx).astype(int)
    hi = np.minimum(lo + 1, BAND_CENTRES_NM.size - 1)
    t = idx - lo
    m = np.zeros((BAND_CENTRES_NM.size, wl.size))
    m[lo, np.arange(wl.size)] += 1 - t
    m[hi, np.arange(wl.size)] += t
    return m


def _nrmse(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((other - ref) ** 2, axis=-1)) / np.mean(ref, axis=-1)


class _Colour:
    """ΔE00 of spectra against the reference, normalised by the reference white (compare.py's
    convention), for many draws at once.  XYZ is linear in the spectrum: one matrix
    [λ, XYZ] (`spectra_to_XYZ` of the unit spectra) serves every draw."""

    def __init__(self, x: BudgetInputs) -> None:
        from normbox_lab.analyze.compare import XYZ_to_Lab_D65, spectra_to_XYZ

        self.wl = x.wavelength_nm
        self.to_xyz = spectra_to_XYZ(np.eye(self.wl.size), self.wl)      # [λ, 3]
        self.xyz_ref = x.reference @ self.to_xyz
        self.y_white = self.xyz_ref[x.white_patch_index, 0, 1]
        self.lab_ref = XYZ_to_Lab_D65(self.xyz_ref / self.y_white)

    def delta_e(self, spectra: np.ndarray) -> np.ndarray:
        from normbox_lab.analyze.compare import XYZ_to_Lab_D65, delta_e00

        lab = XYZ_to_Lab_D65((spectra @ self.to_xyz) / self.y_white)
        return delta_e00(np.broadcast_to(self.lab_ref, lab.shape), lab)


#: draws of the measurement sources behind the significance marks and the observed metrics'
#: intervals: the 95th percentile of K draws is itself a draw; with K = 64 a perfect model
#: exceeded it 6-7 % of the time instead of 5 % (the order statistic's bias and scatter), with
#: K = 1024 the exceedance is 5.0 ± 0.7 %
SIGNIFICANCE_DRAWS = 1024
#: draws per chunk of the significance draws ([chunk, patch, angle, λ] in memory at once)
SIGNIFICANCE_CHUNK = 64


def truth_noise_source(x: BudgetInputs, errors: ErrorSources) -> str:
    """In words, the truth's Monte-Carlo noise the `render` term propagates (the branches of
    `perturbations("render", …)`)."""
    if x.shared_noise and not errors.render_rel_se:
        return "none (the truth shares the prediction's random numbers)"
    if x.truth_se is not None:
        return "as achieved (recorded with the sweep)"
    stated = errors.render_rel_se or (0.0 if x.shared_noise else x.truth_rel_se)
    if stated:
        return f"the stated target, worst band {100 * stated:.3g} % (achieved not recorded)"
    return "none (a measured truth)"


def compute_budget(x: BudgetInputs, errors: ErrorSources, *,
                   sources: Sequence[str] = BUDGET_SOURCES, n_draws: int = 64,
                   seed: int = 0, angle_offsets: Any = None,
                   significance_draws: int = SIGNIFICANCE_DRAWS) -> BudgetResult:
    """Every source's contribution (see the module doc) and the observed metrics' intervals.

    `n_draws` per source for the contributions; `significance_draws` of all measurement
    sources together (in chunks) for the 95th percentiles behind the marks and the
    bootstrap intervals."""
    rng = np.random.default_rng(seed)
    R, P = x.reference, x.prediction
    colour = _Colour(x)
    names, c_nrmse, c_de, c_nse = [], [], [], []
    measurement = np.zeros((n_draws,) + R.shape)
    fixed = np.zeros(R.shape)
    for name in sources:
        d = perturbations(name, errors, x, n_draws, rng)
        if d is None:
            continue
        names.append(name)
        nr = np.sqrt(np.mean(_nrmse(R[None], R[None] + d) ** 2, axis=0))
        c_nrmse.append(nr)
        c_de.append(np.mean(colour.delta_e(R[None] + d[: min(len(d), 16)]), axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(R[None] != 0, d / R[None], 0.0)
        c_nse.append(np.sqrt(np.mean(rel ** 2, axis=(0, 1))))
        if name == "fit":
            fixed = fixed + d[0]
        else:
            measurement += d
    nrmse = np.array(c_nrmse) if c_nrmse else np.zeros((0,) + R.shape[:2])
    de = np.array(c_de) if c_de else np.zeros((0,) + R.shape[:2])
    # all sources together (fixed ones add coherently, random ones by their draws)
    total = np.sqrt(np.mean(_nrmse(R[None], R[None] + measurement + fixed) ** 2, axis=0))
    observed = _nrmse(R, P)
    observed_de = colour.delta_e(P[None])[0]
    # the measurement sources together: what they alone produce (the marks), and the
    # observed metric's parametric bootstrap, from enough draws for a 95th percentile
    meas_names = [n for n in names if n != "fit"]
    meas_nrmse, boot_nrmse, meas_de, boot_de = _significance_draws(
        x, errors, meas_names, max(int(significance_draws), 1), seed + 1, colour)
    ci_nrmse = _pivot(observed, boot_nrmse)
    ci_de = _pivot(observed_de, boot_de)
    p95_n = np.percentile(meas_nrmse, 95, axis=0)
    p95_d = np.percentile(meas_de, 95, axis=0)
    return BudgetResult(names, errors.spec(), x.angle_deg, list(x.patches), nrmse, de,
                        np.array(c_nse) if c_nse else np.zeros((0,) + R.shape[1:]), total,
                        observed, ci_nrmse, observed_de, ci_de, p95_n, p95_d,
                        observed > p95_n, observed_de > p95_d, angle_offsets,
                        truth_noise=truth_noise_source(x, errors))


def _significance_draws(x: BudgetInputs, errors: ErrorSources, names: Sequence[str],
                        n_draws: int, seed: int, colour: _Colour
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """NRMSE and ΔE00 [draw, patch, angle] of R + δ (what the measurement sources alone
    produce) and of P + δ (the bootstrap), δ the sum of `names`' perturbations, drawn in
    chunks of `SIGNIFICANCE_CHUNK`."""
    rng = np.random.default_rng(seed)
    R, P = x.reference, x.prediction
    out: list[list[np.ndarray]] = [[], [], [], []]
    done = 0
    while done < n_draws:
        k = min(SIGNIFICANCE_CHUNK, n_draws - done)
        delta = np.zeros((k,) + R.shape)
        for name in names:
            d = perturbations(name, errors, x, k, rng)
            if d is not None:
                delta += d
        out[0].append(_nrmse(R[None], R[None] + delta))
        out[1].append(_nrmse(R[None], P[None] + delta))
        out[2].append(colour.delta_e(R[None] + delta))
        out[3].append(colour.delta_e(P[None] + delta))
        done += k
    meas_n, boot_n, meas_d, boot_d = (np.concatenate(v, axis=0) for v in out)
    return meas_n, boot_n, meas_d, boot_d


def _pivot(observed: np.ndarray, boot: np.ndarray) -> np.ndarray:
    """Basic bootstrap 95 % interval around the observed value."""
    lo, med, hi = np.percentile(boot, [2.5, 50, 97.5], axis=0)
    return np.array([np.maximum(observed - (hi - med), 0.0), observed + (med - lo)])


def errors_for_run(lab_config_text: str, sources: str | None) -> ErrorSources:
    """The distributions the budget propagates: the run's `[render] errors` if the run came
    from the virtual Normbox with a spec, else the paper's figures; `sources` (a spec, or
    names alone to keep those magnitudes) on top."""
    import tomllib

    try:
        render_cfg = tomllib.loads(lab_config_text or "").get("render", {})
    except tomllib.TOMLDecodeError:
        render_cfg = {}
    base = parse_error_spec(render_cfg.get("errors") or PAPER_FIGURES)
    if not sources:
        return base
    names = [s.strip() for s in sources.split(",") if s.strip()]
    if all("=" not in s for s in names):
        unknown = [n for n in names if n not in SOURCE_FIELDS and n != "fit"]
        if unknown:
            raise ConfigError("--sources", 0, f"errors.{unknown[0]}",
                              f"unknown error source; known: {', '.join(BUDGET_SOURCES)}")
        return base.only(*[n for n in names if n != "fit"])
    return parse_error_spec(sources, source="--sources")
