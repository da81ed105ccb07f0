"""A toy campaign for the report tests: BRDFs from the fit model plus a backscatter lobe
(patches) and a grazing sheen (wall), radiance from a two-term direct + indirect model, no
rendering.  For layout and plumbing tests only; the product's report reads the store."""

from __future__ import annotations

import numpy as np

from normbox_lab.analyze.fit import BrdfData, fit_error_at
from normbox_lab.analyze.report import ReportData
from normbox_lab.predict.brdf_model import MaterialFit


def synthetic_report_data(step_nm: float = 10.0, seed: int = 0, do_fit: bool = False,
                          noise_rel: float = 0.005) -> ReportData:
    """A toy campaign from the fit model, for demos and tests (not a rendering).

    Truth BRDFs = the fit model + a blue-dominated backscatter lobe (patches) and a red-rising
    grazing sheen (wall), so fits are imperfect in the way the paper describes.  Radiance at
    sample angle s = lamp(λ)·[cos s · f(−s, 90°−s) + E_ind(s)·kd/π]; the prediction uses the fit
    for the direct part and the wall's fit error at (−70°, 80°) for the indirect part.  With
    do_fit=False the "fits" are the truth parameters (fast); with True every material is fitted.
    """
    import colour

    from normbox_lab.analyze.compare import compare, error_model
    from normbox_lab.analyze.fit import fit_material
    from normbox_lab.core.spectral import COLORCHECKER_DATASET, spectral_shape, wavelengths_nm
    from normbox_lab.predict.brdf_model import ct_ggx_brdf, gonio_geometry, inplane_directions

    rng = np.random.default_rng(seed)
    wl = wavelengths_nm(step_nm)
    shape = spectral_shape(step_nm)
    sds = colour.SDS_COLOURCHECKERS[COLORCHECKER_DATASET]
    refl = [np.asarray(sd.copy().interpolate(shape).values) for sd in sds.values()]
    names = [f"patch{k + 1:02d}" for k in range(24)] + ["wall"]
    refl.append(np.full(wl.size, 0.34))
    ti, to = gonio_geometry()
    wi, wo = inplane_directions(ti, to, 4.0)
    ramp = (wl - 380.0) / 400.0
    fits: dict[str, MaterialFit] = {}
    data: dict[str, BrdfData] = {}
    for k, (name, r) in enumerate(zip(names, refl, strict=True)):
        alpha, eta = float(rng.uniform(0.2, 0.6)), float(rng.uniform(1.4, 1.6))
        kd, ks = 0.9 * r, np.full(wl.size, float(rng.uniform(0.03, 0.08)))
        y = ct_ggx_brdf(wi, wo, kd, ks, alpha, eta, 0.0)
        if name == "wall":
            y = y + 0.03 * ramp * ((1 - wo[:, 2]) ** 3 * (1 - wi[:, 2]) ** 2)[:, None]
        else:
            back = np.exp(-((to - ti) / 20.0) ** 2)[:, None] * (1.2 - ramp) * kd / np.pi
            y = y + 0.08 * back
        y = y * (1 + noise_rel * rng.normal(size=y.shape))
        data[name] = BrdfData(name, ti, to, wl, y, 4.0)
        fits[name] = (fit_material(data[name], 2.0) if do_fit else
                      MaterialFit(name, wl, kd, ks, alpha, eta, 0.0, float("nan"), 2.0))
        if not do_fit:
            from normbox_lab.analyze.fit import fit_error_pct

            fits[name].fit_error_pct = fit_error_pct(fits[name], data[name])
    angles = np.arange(30.0, 91.0, 5.0)
    lamp = 0.05 * (0.5 + ramp)
    s = np.deg2rad(angles)
    e_dir = np.clip(np.cos(s), 0.0, None)
    e_ind = 0.12 * (0.6 + 0.4 * np.sin(s))
    wall_err = fit_error_at(fits["wall"], data["wall"], -70.0, 80.0)
    ref = np.empty((24, angles.size, wl.size))
    pred = np.empty_like(ref)
    share = np.empty((24, angles.size))
    for p in range(24):
        name = names[p]
        d_fit = np.stack([fits[name].brdf_inplane(-a, 90.0 - a) for a in angles])
        d_err = np.stack([fit_error_at(fits[name], data[name], -a, 90.0 - a) for a in angles])
        direct_true = lamp * e_dir[:, None] * d_fit / (1.0 + np.nan_to_num(d_err))
        indirect_true = lamp * e_ind[:, None] * refl[p] * 0.9 / np.pi
        ref[p] = (direct_true + indirect_true) * (1 + noise_rel * rng.normal(size=wl.size))
        pred[p] = lamp * e_dir[:, None] * d_fit + indirect_true * (1.0 + wall_err)
        share[p] = np.mean(direct_true, -1) / np.mean(direct_true + indirect_true, -1)
    patch_names = [f"{k + 1}" for k in range(24)]
    comp = compare(ref, pred, wl, angles, patch_names)
    err_d = np.stack([np.nanmean(np.abs(fit_error_at(fits[names[p]], data[names[p]], -30.0,
                                                      60.0))) for p in range(24)])
    em = error_model(share, err_d[:, None, None], np.abs(wall_err)[None, None, :], angles,
                     reference=ref, observed_nrmse=comp.nrmse)
    return ReportData(comparison=comp, fits=fits, brdf_data=data, error_model=em,
                      patch_fit_names=names[:24],
                      title="Normbox validation report (synthetic toy data)",
                      notes=[("Synthetic toy campaign from the fit model (no rendering): "
                             "for layout and plumbing only.")],
                      metadata={"seed": seed, "wavelength step nm": step_nm,
                                "fitted": do_fit})


def synthetic_budget(data: ReportData, n_draws: int = 16) -> tuple[dict, list[str]]:
    """An error budget of the toy campaign (no rendering): the CS-1000A gain, the lamp, the
    paper's 65°/80° angle offsets through a derivative of −2 %/°, and the fit's NSE; as the
    report's `ReportData.budget` (the stored artifact's arrays and sources)."""
    from normbox_lab.analyze.budget import BudgetInputs, compute_budget
    from normbox_lab.core.error_sources import parse_error_spec

    c = data.comparison
    ref = np.asarray(c.reference)
    x = BudgetInputs(c.wavelength_nm, c.angle_deg, list(range(1, ref.shape[0] + 1)), ref,
                     np.asarray(c.prediction), 1e-4 * ref, -0.02 * ref, {}, None,
                     np.asarray(c.nse), c.white_patch)
    from normbox_lab.analyze.angles import estimate_angle_offsets

    off = estimate_angle_offsets(x.reference, x.prediction, x.d_angle, x.angle_deg)
    b = compute_budget(x, parse_error_spec("cs1000=0.02,lamp=+0.01,angle-offset=65:-0.3;"
                                           "80:+0.3"), n_draws=n_draws, angle_offsets=off)
    return b.to_arrays(), b.sources
