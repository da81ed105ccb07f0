"""Self-contained HTML validation report (figures as inline base64 PNG; no external files).

`write_report(path, ReportData(...))` renders, from plain arrays / fits / comparison results,
the equivalents of the Normbox paper's figures and the tables behind them:

    id                 content                                                paper
    fig-reference      reference spectra, every patch × sample angle           (data of Figs. 5-7)
    fig-prediction     prediction vs reference spectra per angle, some patches (Fig. 1 / 13 data)
    fig-rmse           RMSE per patch × angle; radiance vs RMSE, 30–60° / 65–90° Fig. 5 a-c
    fig-nrmse          NRMSE per patch × angle; radiance vs NRMSE               Fig. 6 a-c
    fig-deltae         ΔE00 heat map patches × angles on the rating scale       Fig. 7
    fig-polar-*        BRDF polar plots, fits vs measured data                  Figs. 10/11
    fig-errormodel     simulated error d·err_d + (1−d)·err_i vs NRMSE per angle Fig. 12
    fig-nse            NSE spectra per sample angle for one patch              Fig. 13
    fig-nse-fit        NSE vs BRDF fitting error (direct: patch, 90°: wall)     Fig. 14
    tab-fits, tab-deltae, tab-nrmse, tab-rmse, tab-correlations, tab-rating, tab-errormodel

matplotlib is imported lazily and used through `matplotlib.figure.Figure` (Agg canvas, no pyplot
state), so the module imports fast and works headless.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.analyze.compare import RATING_SCALE, ComparisonResult, ErrorModelResult
from normbox_lab.analyze.fit import BrdfData, fit_error_at, polar_plot
from normbox_lab.predict.brdf_model import MaterialFit

RATING_COLOURS = ("#2e7d32", "#9ccc65", "#ffb300", "#c62828")


@dataclass
class ReportData:
    """Everything the report shows; plain data, so it works from synthetic data or the store."""

    comparison: ComparisonResult | None = None
    fits: dict[str, MaterialFit] = field(default_factory=dict)
    brdf_data: dict[str, BrdfData] = field(default_factory=dict)
    error_model: ErrorModelResult | None = None
    budget: tuple[dict[str, Any], list[str]] | None = None   # error-budget arrays, sources
    title: str = "Normbox validation report"
    polar_wavelength_nm: float = 730.0
    polar_materials: Sequence[str] | None = None   # default: patch08, patch18 (as the paper), wall
    prediction_patches: Sequence[int] = (0, 5, 12, 18)   # 0-based indices for fig-prediction
    nse_patch: int = 21                                # paper Fig. 13: patch 22
    nse_fit_patches: Sequence[int] = (18, 22, 23)      # paper Fig. 14a: patches 19, 23, 24
    wall_name: str = "wall"
    wall_geometry_deg: tuple[float, float] = (-70.0, 80.0)   # paper Fig. 14b
    patch_fit_names: Sequence[str] | None = None       # fit name per patch index (fig-nse-fit)
    notes: list[str] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)
    images: list[ImageFigure] = field(default_factory=list)   # virtual-camera figures
    flags: list[Any] = field(default_factory=list)   # quality flags (`analyze.qa.Flag`)


@dataclass
class ImagePanel:
    """One panel of an image figure: an encoded sRGB image (H, W, 3) in [0, 1] or uint8, or a
    scalar map (H, W) shown with a colour bar (`vmax`; default: its 99th percentile)."""

    label: str
    data: np.ndarray
    vmax: float | None = None
    unit: str = ""


@dataclass
class ImageFigure:
    """A row of image panels (e.g. the paper's Fig. 1: truth | prediction | ΔE00 map).

    Stored in the store as an ``image-figure`` artifact named `fid` (arrays ``p0``, ``p1``…;
    labels, colour-bar limits and units in the metadata) by `to_artifact`."""

    fid: str
    title: str
    caption: str
    panels: list[ImagePanel]

    def store(self, store: Any, run_ref: int | str | None = None) -> int:
        # the store keeps float64: sRGB panels go in as encoded values in [0, 1]
        arrays = {f"p{k}": (np.asarray(p.data) / 255.0 if np.asarray(p.data).dtype == np.uint8
                            else np.asarray(p.data)) for k, p in enumerate(self.panels)}
        meta = {"title": self.title, "caption": self.caption,
                "panels": [{"label": p.label, "vmax": p.vmax, "unit": p.unit}
                           for p in self.panels]}
        return store.add_artifact("image-figure", self.fid, arrays, metadata=meta,
                                  run_ref=run_ref)

    @classmethod
    def from_artifact(cls, a: Any) -> ImageFigure:
        m = a.metadata
        panels = [ImagePanel(p["label"], np.asarray(a.arrays[f"p{k}"]), p.get("vmax"),
                             p.get("unit", "")) for k, p in enumerate(m["panels"])]
        return cls(a.name, m["title"], m["caption"], panels)


# -- helpers ---------------------------------------------------------------------------------

def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=72)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure_html(fid: str, title: str, fig: Any, caption: str) -> str:
    return (f'<figure id="{fid}"><h3>{html.escape(title)}</h3>'
            f'<img alt="{html.escape(title)}" src="data:image/png;base64,{_png(fig)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _table_html(tid: str, title: str, header: Sequence[str], rows: Sequence[Sequence[Any]],
                cell_class: Any = None) -> str:
    out = [f'<div class="table" id="{tid}"><h3>{html.escape(title)}</h3><table><thead><tr>']
    out += [f"<th>{html.escape(str(h))}</th>" for h in header]
    out.append("</tr></thead><tbody>")
    for i, row in enumerate(rows):
        out.append("<tr>")
        for j, v in enumerate(row):
            cls = cell_class(i, j, v) if cell_class else ""
            txt = f"{v:.4g}" if isinstance(v, float | np.floating) else str(v)
            out.append(f'<td{f" class={chr(34)}{cls}{chr(34)}" if cls else ""}>'
                       f"{html.escape(txt)}</td>")
        out.append("</tr>")
    out.append("</tbody></table></div>")
    return "".join(out)


def _new_fig(w: float, h: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h))


def _angle_colours(n: int) -> list[Any]:
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(k / max(n - 1, 1)) for k in range(n)]


# -- figures ---------------------------------------------------------------------------------

def fig_reference(c: ComparisonResult) -> Any:
    n_p = len(c.patch_names)
    ncol = 6
    nrow = int(np.ceil(n_p / ncol))
    fig = _new_fig(2.2 * ncol, 1.7 * nrow)
    cols = _angle_colours(c.angle_deg.size)
    for p in range(n_p):
        ax = fig.add_subplot(nrow, ncol, p + 1)
        for a in range(c.angle_deg.size):
            ax.plot(c.wavelength_nm, c.reference[p, a], color=cols[a], lw=0.8)
        ax.set_title(c.patch_names[p], fontsize=7)
        ax.tick_params(labelsize=5)
    fig.suptitle("Reference spectral radiance [W sr⁻¹ m⁻² nm⁻¹]; colour = sample angle "
                 f"{c.angle_deg[0]:g}° (dark) … {c.angle_deg[-1]:g}° (light)", fontsize=9)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig


def fig_prediction(c: ComparisonResult, patches: Sequence[int]) -> Any:
    patches = [p for p in patches if 0 <= p < len(c.patch_names)]
    fig = _new_fig(3.6 * len(patches), 3.0)
    cols = _angle_colours(c.angle_deg.size)
    for k, p in enumerate(patches):
        ax = fig.add_subplot(1, len(patches), k + 1)
        for a in range(c.angle_deg.size):
            ax.plot(c.wavelength_nm, c.reference[p, a], "-", color=cols[a], lw=0.9)
            ax.plot(c.wavelength_nm, c.prediction[p, a], "--", color=cols[a], lw=0.9)
        ax.set_title(f"{c.patch_names[p]}: reference (—) vs prediction (--)", fontsize=7)
        ax.set_xlabel("wavelength [nm]", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig


def _bars_and_scatter(c: ComparisonResult, values: np.ndarray, label: str,
                      key_small: str, key_large: str) -> Any:
    from normbox_lab.analyze.compare import LARGE_ANGLES_DEG, SMALL_ANGLES_DEG

    fig = _new_fig(12, 3.4)
    gs = fig.add_gridspec(1, 4)
    ax = fig.add_subplot(gs[0, :2])
    n_p, n_a = values.shape
    cols = _angle_colours(n_a)
    width = 0.8 / n_a
    x = np.arange(n_p)
    for a in range(n_a):
        ax.bar(x + (a - n_a / 2) * width, values[:, a], width, color=cols[a],
               label=f"{c.angle_deg[a]:g}°")
    ax.set_xticks(x, [str(n) for n in c.patch_names], fontsize=5, rotation=90)
    ax.set_ylabel(label, fontsize=7)
    ax.legend(fontsize=5, ncol=7)
    for k, (rng, key) in enumerate(((SMALL_ANGLES_DEG, key_small), (LARGE_ANGLES_DEG, key_large))):
        sel = (c.angle_deg >= rng[0] - 1e-9) & (c.angle_deg <= rng[1] + 1e-9)
        axs = fig.add_subplot(gs[0, 2 + k])
        axs.scatter(c.radiance_mean[:, sel].ravel(), values[:, sel].ravel(), s=6)
        r = c.correlations.get(key, float("nan"))
        axs.set_title(f"{rng[0]:g}–{rng[1]:g}°: r = {r:.2f}", fontsize=8)
        axs.set_xlabel("mean radiance", fontsize=7)
        axs.set_ylabel(label, fontsize=7)
        axs.tick_params(labelsize=6)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig


def fig_deltae(c: ComparisonResult) -> Any:
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from normbox_lab.analyze.compare import rating_index

    fig = _new_fig(8, 7)
    ax = fig.add_subplot(1, 1, 1)
    bounds = [0.0] + [b for b, _ in RATING_SCALE[:-1]] + [max(10.0, float(np.nanmax(
        c.delta_e00)) + 1)]
    cmap = ListedColormap(RATING_COLOURS)
    im = ax.imshow(c.delta_e00, aspect="auto", cmap=cmap, norm=BoundaryNorm(bounds, cmap.N))
    for p in range(c.delta_e00.shape[0]):
        for a in range(c.delta_e00.shape[1]):
            v = c.delta_e00[p, a]
            dark = np.isfinite(v) and int(rating_index(v)) in (0, 3)
            ax.text(a, p, f"{v:.1f}", ha="center", va="center", fontsize=5,
                    color="white" if dark else "black")
    ax.set_xticks(range(c.angle_deg.size), [f"{v:g}" for v in c.angle_deg], fontsize=6)
    ax.set_yticks(range(len(c.patch_names)), c.patch_names, fontsize=6)
    ax.set_xlabel("sample angle [°]", fontsize=8)
    cb = fig.colorbar(im, ax=ax, ticks=[(bounds[k] + bounds[k + 1]) / 2 for k in range(4)])
    cb.ax.set_yticklabels([f"{lab}" for _, lab in RATING_SCALE], fontsize=6)
    ax.set_title("ΔE00 (CIE 2000, kL = kC = kH = 1)", fontsize=9)
    return fig


def fig_error_model(em: ErrorModelResult, nrmse: np.ndarray | None) -> Any:
    fig = _new_fig(7, 3.4)
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(em.angle_deg.size)
    cd = np.nanmean(em.contribution_d, axis=0)
    ci = np.nanmean(em.contribution_i, axis=0)
    ax.bar(x, cd, color="tab:blue", label="d·err_d (patch fit)")
    ax.bar(x, ci, bottom=cd, color="tab:red", label="(1 − d)·err_i (wall fit)")
    ax.plot(x, np.nanmean(em.simulated_nrmse, axis=0), "k^-", ms=4, label="simulated (RMS)")
    obs = em.observed_nrmse if em.observed_nrmse is not None else nrmse
    if obs is not None:
        ax.plot(x, np.nanmean(np.atleast_2d(obs), axis=0), "ko--", ms=4, label="observed NRMSE")
    ax.set_xticks(x, [f"{v:g}" for v in em.angle_deg], fontsize=7)
    ax.set_xlabel("sample angle [°]", fontsize=8)
    ax.set_ylabel("normalised error (mean over patches)", fontsize=8)
    ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig


def fig_nse(c: ComparisonResult, patch: int) -> Any:
    n_a = c.angle_deg.size
    ncol = 5
    nrow = int(np.ceil(n_a / ncol))
    fig = _new_fig(2.4 * ncol, 1.8 * nrow)
    lim = np.nanmax(np.abs(c.nse[patch])) if np.isfinite(c.nse[patch]).any() else 1.0
    for a in range(n_a):
        ax = fig.add_subplot(nrow, ncol, a + 1)
        ax.plot(c.wavelength_nm, c.nse[patch, a], lw=0.8)
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.set_ylim(-1.05 * lim - 1e-12, 1.05 * lim + 1e-12)
        ax.set_title(f"{c.angle_deg[a]:g}°", fontsize=7)
        ax.tick_params(labelsize=5)
    fig.suptitle(f"NSE (prediction − reference)/reference of {c.patch_names[patch]}", fontsize=9)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig


def fig_nse_fit(c: ComparisonResult, d: ReportData) -> tuple[Any, list[list[Any]]] | None:
    """Paper Fig. 14: NSE at the smallest angle vs patch fit error at the direct geometry;
    NSE at the largest angle vs the wall's fit error at a grazing geometry."""
    from normbox_lab.analyze.compare import direct_light_geometry

    names = list(d.patch_fit_names) if d.patch_fit_names is not None else list(c.patch_names)
    pairs = [(p, names[p]) for p in d.nse_fit_patches
             if p < len(names) and names[p] in d.fits and names[p] in d.brdf_data]
    have_wall = d.wall_name in d.fits and d.wall_name in d.brdf_data
    if not pairs and not have_wall:
        return None
    fig = _new_fig(10, 5)
    rows: list[list[Any]] = []
    ti, to = direct_light_geometry(c.angle_deg[0])
    ax1 = fig.add_subplot(2, 2, 1)
    ax3 = fig.add_subplot(2, 2, 3)
    for k, (p, name) in enumerate(pairs):
        ax1.plot(c.wavelength_nm, c.nse[p, 0], color=f"C{k}", lw=0.8, label=c.patch_names[p])
        err = fit_error_at(d.fits[name], d.brdf_data[name], float(ti), float(to))
        ax3.plot(d.brdf_data[name].wavelength_nm, err, color=f"C{k}", lw=0.8, label=name)
        rows.append([c.patch_names[p], f"{c.angle_deg[0]:g}°",
                     float(np.sqrt(np.nanmean(c.nse[p, 0] ** 2))),
                     f"patch fit at θi={float(ti):g}°, θo={float(to):g}°",
                     float(np.sqrt(np.nanmean(err ** 2)))])
    ax1.set_title(f"(a) NSE at {c.angle_deg[0]:g}°", fontsize=8)
    ax3.set_title("fitting error, direct-light geometry", fontsize=8)
    ax2 = fig.add_subplot(2, 2, 2)
    ax4 = fig.add_subplot(2, 2, 4)
    ax2.plot(c.wavelength_nm, np.nanmean(c.nse[:, -1], axis=0), lw=0.8, label="mean of patches")
    ax2.set_title(f"(b) NSE at {c.angle_deg[-1]:g}° (mean over patches)", fontsize=8)
    if have_wall:
        wti, wto = d.wall_geometry_deg
        werr = fit_error_at(d.fits[d.wall_name], d.brdf_data[d.wall_name], wti, wto)
        ax4.plot(d.brdf_data[d.wall_name].wavelength_nm, werr, color="tab:red", lw=0.8)
        ax4.set_title(f"wall fitting error at θi={wti:g}°, θo={wto:g}°", fontsize=8)
        rows.append(["all (mean)", f"{c.angle_deg[-1]:g}°",
                     float(np.sqrt(np.nanmean(np.nanmean(c.nse[:, -1], axis=0) ** 2))),
                     f"wall fit at θi={wti:g}°, θo={wto:g}°",
                     float(np.sqrt(np.nanmean(werr ** 2)))])
    for ax in (ax1, ax2, ax3, ax4):
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.tick_params(labelsize=6)
    for ax in (ax1, ax3):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.12, top=0.88, wspace=0.35, hspace=0.6)
    return fig, rows


def fig_images(f: ImageFigure) -> Any:
    """The panels side by side at their pixel aspect; maps with a colour bar."""
    n = len(f.panels)
    h, w = np.asarray(f.panels[0].data).shape[:2]
    fig = _new_fig(min(4.2 * n, 16.0), min(4.2 * n, 16.0) / n * h / w + 0.6)
    for k, p in enumerate(f.panels):
        ax = fig.add_subplot(1, n, k + 1)
        data = np.asarray(p.data)
        if data.ndim == 3:
            ax.imshow(data if data.dtype == np.uint8 else np.clip(data, 0.0, 1.0))
        else:
            finite = data[np.isfinite(data)]
            vmax = p.vmax if p.vmax is not None else (
                float(np.percentile(finite, 99)) if finite.size else 1.0)
            im = ax.imshow(data, cmap="magma", vmin=0.0, vmax=max(vmax, 1e-12))
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
            cb.ax.tick_params(labelsize=6)
            if p.unit:
                cb.set_label(p.unit, fontsize=7)
        ax.set_title(p.label, fontsize=8)
        ax.set_axis_off()
    fig.subplots_adjust(left=0.01, right=0.97, bottom=0.02, top=0.9, wspace=0.08)
    return fig


# -- the report ------------------------------------------------------------------------------

_CSS = """
body{font-family:sans-serif;max-width:1200px;margin:1em auto;color:#222}
h1{font-size:1.5em} h2{border-bottom:1px solid #ccc;font-size:1.2em} h3{font-size:1em}
figure{margin:1em 0} img{max-width:100%} figcaption{font-size:.85em;color:#555}
table{border-collapse:collapse;font-size:.75em} td,th{border:1px solid #ccc;padding:2px 5px;
text-align:right} th{background:#eee} .r0{background:#c8e6c9} .r1{background:#f1f8e9}
.r2{background:#ffe082} .r3{background:#ef9a9a} .note{font-size:.9em;color:#444}
"""


def _rating_class(_i: int, j: int, v: Any) -> str:
    from normbox_lab.analyze.compare import rating_index

    if j == 0 or not isinstance(v, float | np.floating) or not np.isfinite(v):
        return ""
    return f"r{int(rating_index(v))}"


def _qa_html(flags: Sequence[Any], max_rows: int = 200) -> str:
    """The QA summary the report opens with: counts, then one row per flag (errors first)."""
    errors = sum(1 for f in flags if f.severity == "error")
    head = (f'<section id="qa"><h2>Quality</h2><p class="qa-summary">{len(flags)} flags: '
            f"{errors} errors, {len(flags) - errors} warnings</p>")
    if not flags:
        return head + "</section>"
    ordered = sorted(flags, key=lambda f: (f.severity != "error", f.run_id or 0, f.key))
    rows = [[f.severity, str(f.run_id or ""), f.key or "(run)", f.gate,
             "" if f.value is None else float(f.value),
             "" if f.limit is None else float(f.limit), f.message]
            for f in ordered[:max_rows]]
    more = (f"<p>… and {len(flags) - max_rows} more (normbox-lab qa RUN_ID)</p>"
            if len(flags) > max_rows else "")
    return head + _table_html("tab-qa", "Quality flags",
                              ["severity", "run", "reading / artifact", "gate", "value",
                               "limit", "message"], rows) + more + "</section>"


def build_html(d: ReportData) -> tuple[str, list[str], list[str]]:
    """(html, figure ids, table ids)."""
    parts: list[str] = []
    figs: list[str] = []
    tabs: list[str] = []

    def add_fig(fid: str, title: str, fig: Any, caption: str) -> None:
        parts.append(_figure_html(fid, title, fig, caption))
        figs.append(fid)

    def add_tab(tid: str, *args: Any, **kw: Any) -> None:
        parts.append(_table_html(tid, *args, **kw))
        tabs.append(tid)

    parts.append(_qa_html(d.flags))
    if d.flags:
        tabs.append("tab-qa")
    c = d.comparison
    if c is not None:
        ang_hdr = ["patch"] + [f"{v:g}°" for v in c.angle_deg]
        parts.append("<h2>Reference and prediction</h2>")
        add_fig("fig-reference", "Reference spectra", fig_reference(c),
                "Measured spectral radiance of every patch at every sample angle.")
        add_fig("fig-prediction", "Prediction vs reference per angle",
                fig_prediction(c, d.prediction_patches),
                "Solid: reference; dashed: prediction; colour: sample angle.")
        parts.append("<h2>Physical comparison</h2>")
        add_fig("fig-rmse", "RMSE and its correlation with radiance (paper Fig. 5)",
                _bars_and_scatter(c, c.rmse, "RMSE [W sr⁻¹ m⁻² nm⁻¹]",
                                  "radiance_rmse_small", "radiance_rmse_large"),
                "RMSE over wavelengths per patch and angle; scatter of mean reference "
                "radiance against RMSE for small and large sample angles with Pearson r.")
        add_fig("fig-nrmse", "NRMSE per angle (paper Fig. 6)",
                _bars_and_scatter(c, c.nrmse, "NRMSE", "radiance_nrmse_small",
                                  "radiance_nrmse_large"),
                "RMSE divided by the mean reference spectrum.")
        add_tab("tab-rmse", "RMSE [W sr⁻¹ m⁻² nm⁻¹]", ang_hdr,
                [[n, *map(float, c.rmse[p])] for p, n in enumerate(c.patch_names)])
        add_tab("tab-nrmse", "NRMSE", ang_hdr,
                [[n, *map(float, c.nrmse[p])] for p, n in enumerate(c.patch_names)])
        add_tab("tab-correlations", "Correlation of radiance with RMSE / NRMSE",
                ["pair", "Pearson r"], [[k, float(v)] for k, v in c.correlations.items()])
        parts.append("<h2>Perceptual comparison</h2>")
        add_fig("fig-deltae", "ΔE00 heat map (paper Fig. 7)", fig_deltae(c),
                f"XYZ normalised by the reference white ({c.patch_names[c.white_patch]}) at "
                f"{c.white_angle_deg:g}°, Lab with D65; classes: "
                + "; ".join(f"≤ {b:g}: {lab}" if np.isfinite(b) else f"> 5: {lab}"
                            for b, lab in RATING_SCALE))
        add_tab("tab-deltae", "ΔE00", ang_hdr,
                [[n, *map(float, c.delta_e00[p])] for p, n in enumerate(c.patch_names)],
                cell_class=_rating_class)
        counts = c.rating_counts()
        add_tab("tab-rating", "Rating scale", ["class", "ΔE00 up to", "count"],
                [[lab, f"{b:g}", counts[lab]] for b, lab in RATING_SCALE])
        add_fig("fig-nse", f"NSE per sample angle (paper Fig. 13), {c.patch_names[d.nse_patch]}"
                if d.nse_patch < len(c.patch_names) else "NSE per sample angle",
                fig_nse(c, min(d.nse_patch, len(c.patch_names) - 1)),
                "Normalised spectral error (prediction − reference)/reference.")
    if d.images:
        parts.append("<h2>Images (virtual camera)</h2>")
        for f in d.images:
            add_fig(f.fid, f.title, fig_images(f), f.caption)
    if d.fits:
        parts.append("<h2>BRDF fits</h2>")
        add_tab("tab-fits", "Fitted parameters", ["material", "α", "η", "c [sr⁻¹]", "w",
                                                   "fit error %", "Löw cost"],
                [[n, f.alpha, f.eta, f.c, f.w, f.fit_error_pct, f.cost]
                 for n, f in d.fits.items()])
        names = list(d.polar_materials) if d.polar_materials is not None else (
            [n for n in ("patch08", "patch18") if n in d.fits]
            or [n for n in d.fits if n != d.wall_name][:1])
        names += [d.wall_name] if d.polar_materials is None and d.wall_name in d.fits else []
        for n in names:
            if n not in d.fits:
                continue
            fig = polar_plot(d.brdf_data.get(n), {n: d.fits[n]}, d.polar_wavelength_nm)
            add_fig(f"fig-polar-{n}", f"BRDF polar plot of {n} at {d.polar_wavelength_nm:g} nm "
                    "(paper Figs. 10/11)", fig,
                    "Points: measured in-plane BRDF; line: fit (tilted geometry); one panel "
                    "per incident angle, θo on the polar axis, dotted ray = light direction.")
    if d.error_model is not None:
        em = d.error_model
        parts.append("<h2>Error model</h2>")
        add_fig("fig-errormodel", "Error model vs NRMSE (paper Fig. 12)",
                fig_error_model(em, c.nrmse if c is not None else None),
                "Simulated normalised error from the direct-light share d per angle, the patch "
                "fit error err_d and the wall fit error err_i, against the observed NRMSE.")
        obs = em.observed_nrmse if em.observed_nrmse is not None else (
            c.nrmse if c is not None else None)
        rows = []
        for a, ang in enumerate(em.angle_deg):
            rows.append([f"{ang:g}°", float(np.nanmean(em.direct_share[:, a])),
                         float(np.nanmean(em.contribution_d[:, a])),
                         float(np.nanmean(em.contribution_i[:, a])),
                         float(np.nanmean(em.simulated_nrmse[:, a])),
                         float(np.nanmean(np.atleast_2d(obs)[:, a])) if obs is not None
                         else float("nan")])
        add_tab("tab-errormodel", "Error model per angle (means over patches)",
                ["angle", "direct share", "d·err_d", "(1−d)·err_i", "simulated",
                 "observed NRMSE"], rows)
    if d.budget is not None:
        from normbox_lab.analyze.budget import budget_figure, budget_rows

        arrays, sources = d.budget
        parts.append("<h2>Error budget</h2>")
        add_fig("fig-budget", "Error budget per angle (paper Fig. 12, every source)",
                budget_figure(arrays, sources),
                "Each source's share of the total NRMSE (stacked), propagated from its "
                "distribution (normbox-lab budget), against the observed NRMSE with its 95 % "
                "interval.")
        header, rows = budget_rows(arrays, sources)
        add_tab("tab-budget", "Error budget per angle: NRMSE contributions [%], estimated "
                "sample-angle offset", header, rows)
    if c is not None and d.fits:
        got = fig_nse_fit(c, d)
        if got is not None:
            fig, rows = got
            add_fig("fig-nse-fit", "NSE vs fitting error (paper Fig. 14)", fig,
                    "Top: NSE at the smallest and largest sample angle; bottom: relative BRDF "
                    "fitting error at the matching geometry (patch: direct light; wall: grazing).")
            add_tab("tab-nse-fit", "NSE vs fitting error (RMS over wavelengths)",
                    ["patch", "angle", "RMS NSE", "fit error at", "RMS fit error"], rows)
    head = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(d.title)}"
            f"</title><style>{_CSS}</style></head><body><h1>{html.escape(d.title)}</h1>")
    meta = "".join(f"<li>{html.escape(str(k))}: {html.escape(str(v))}</li>"
                   for k, v in d.metadata.items())
    notes = "".join(f"<p class='note'>{html.escape(n)}</p>" for n in d.notes)
    toc = "<ul>" + "".join(f"<li><a href='#{i}'>{i}</a></li>" for i in figs + tabs) + "</ul>"
    body = head + (f"<ul>{meta}</ul>" if meta else "") + notes + toc + "".join(parts)
    return body + "</body></html>", figs, tabs


def write_report(path: str | Path, data: ReportData) -> Path:
    """Write the self-contained HTML report and return its path."""
    out = Path(path)
    text, _figs, _tabs = build_html(data)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    return out
