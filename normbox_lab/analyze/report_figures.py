"""The report's figures (matplotlib, no pyplot state), all in `report_style`'s style: labelled
axes with units, colour-blind-safe colours, text at print size.

Each function returns a `matplotlib.figure.Figure`; `report.py` embeds it as inline SVG.
Error metrics are shown in percent (NRMSE, NSE, fit errors), ΔE00 as is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import wraps
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from normbox_lab.analyze.compare import (
    RATING_SCALE,
    ComparisonResult,
    ErrorModelResult,
    rating_class_range,
)
from normbox_lab.analyze.fit import fit_error_at, half_polar_axes
from normbox_lab.analyze.paper_figures import NSE_PAPER_SIGN, nse_paper_sign, signed
from normbox_lab.analyze.report_style import (
    FONT_PT,
    MAX_WIDTH_IN,
    RADIANCE_UNIT,
    RATING_COLOURS,
    RATING_TEXT,
    SEQUENTIAL_CMAP,
    angle_colours,
    new_figure,
    rc,
)

if TYPE_CHECKING:
    from normbox_lab.analyze.report_data import ImageFigure, ReportData

F = TypeVar("F", bound=Callable[..., Any])


def styled(func: F) -> F:
    """Run a figure function inside the report's rcParams (axes read them when created)."""

    @wraps(func)
    def inner(*args: Any, **kwargs: Any) -> Any:
        import matplotlib

        with matplotlib.rc_context(rc()):
            return func(*args, **kwargs)

    return inner  # type: ignore[return-value]


def _angle_colourbar(fig: Any, axes: Any, angle_deg: np.ndarray) -> None:
    """A discrete colour bar for the sample angle (instead of a 13-entry legend)."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm, ListedColormap

    cols = angle_colours(angle_deg.size)
    step = float(angle_deg[1] - angle_deg[0]) if angle_deg.size > 1 else 1.0
    bounds = np.concatenate([angle_deg - step / 2, [angle_deg[-1] + step / 2]])
    sm = ScalarMappable(norm=BoundaryNorm(bounds, len(cols)), cmap=ListedColormap(cols))
    if fig.get_layout_engine() is None:                  # a hand-placed grid: own axes
        cax = fig.add_axes([fig.subplotpars.right + 0.02, 0.15, 0.012, 0.7])
        cb = fig.colorbar(sm, cax=cax)
    else:
        cb = fig.colorbar(sm, ax=axes, fraction=0.025, pad=0.01, aspect=30)
    ticks = angle_deg if angle_deg.size <= 7 else angle_deg[::2]
    cb.set_ticks(ticks, labels=[f"{v:g}°" for v in ticks])
    cb.set_label("sample angle")


@styled
def fig_reference(c: ComparisonResult) -> Any:
    """Every patch's reference spectra, one panel per patch, colour = sample angle.  4 panels
    a row at 7.8 in, so that at 800 px its text keeps its 9 pt; the radiance in one power of
    ten for every panel (in the axis label) and one tick format (the same decimals)."""
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator

    n_p = len(c.patch_names)
    ncol = 4
    nrow = int(np.ceil(n_p / ncol))
    height_in = 1.45 * nrow + 0.9
    fig = new_figure(7.8, height_in, layout=None)
    fig.subplots_adjust(left=0.12, right=0.86, bottom=0.55 / height_in, top=1 - 0.3 / height_in,
                        wspace=0.5, hspace=0.5)
    cols = angle_colours(c.angle_deg.size)
    ref, label = scaled_for_axis(c.reference, f"spectral radiance [{RADIANCE_UNIT}]",
                                 force=True)
    axes = fig.subplots(nrow, ncol, sharex=True, squeeze=False)
    steps = []
    for p in range(nrow * ncol):
        ax = axes.flat[p]
        if p >= n_p:
            ax.set_visible(False)
            continue
        for a in range(c.angle_deg.size):
            ax.plot(c.wavelength_nm, ref[p, a], color=cols[a], lw=0.9)
        ax.set_title(_short_patch(c.patch_names[p]), fontsize=FONT_PT["tick"], pad=2)
        ax.set_xticks([400, 550, 700])
        ax.yaxis.set_major_locator(MaxNLocator(nbins=3, min_n_ticks=2))
        ax.set_ylim(bottom=0.0)
        ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
        if len(ticks) > 1:
            steps.append(min(np.diff(ticks)))
    decimals = max([0, *(int(np.ceil(-np.log10(s) - 1e-9)) for s in steps if s > 0)])
    for ax in axes.flat[:n_p]:
        ax.yaxis.set_major_formatter(FormatStrFormatter(f"%.{decimals}f"))
    fig.supxlabel("wavelength [nm]")
    fig.supylabel(label.replace(" [", "\n[", 1))    # two lines: it fits one row of panels
    _angle_colourbar(fig, axes, c.angle_deg)
    return fig


def _deg(v: float) -> str:
    """An angle with a typographic minus: "−30°"."""
    return f"{float(v):g}°".replace("-", "\u2212")


def _short_patch(name: str) -> str:
    """"19 white 9.5 (.05 D)" → "19 white": a panel title fits its panel."""
    words = str(name).split()
    return " ".join(words[:2]) if len(words) > 1 and words[0].isdigit() else str(name)


@styled
def fig_prediction(c: ComparisonResult, patches: Sequence[int]) -> Any:
    """Reference (solid) and prediction (dashed) spectra of some patches at every angle."""
    from matplotlib.lines import Line2D

    patches = [p for p in patches if 0 <= p < len(c.patch_names)]
    ncol = min(max(len(patches), 1), 2)            # two panels a row at 8 in
    nrow = int(np.ceil(max(len(patches), 1) / ncol))
    fig = new_figure(MAX_WIDTH_IN, 3.4 * nrow)
    cols = angle_colours(c.angle_deg.size)
    axes = fig.subplots(nrow, ncol, squeeze=False).flat
    for ax in list(axes)[len(patches):]:
        ax.set_visible(False)
    for k, p in enumerate(patches):
        ax = axes[k]
        for a in range(c.angle_deg.size):
            ax.plot(c.wavelength_nm, c.reference[p, a], "-", color=cols[a], lw=1.0)
            ax.plot(c.wavelength_nm, c.prediction[p, a], "--", color=cols[a], lw=1.0)
        ax.set_title(f"patch {c.patch_names[p]}")
        ax.set_xlabel("wavelength [nm]")
        ax.locator_params(axis="y", nbins=4)
    axes[0].set_ylabel(f"radiance\n[{RADIANCE_UNIT}]")
    axes[0].legend([Line2D([], [], color="0.2", ls="-"), Line2D([], [], color="0.2", ls="--")],
                   ["reference", "prediction"], loc="upper left")
    _angle_colourbar(fig, list(axes), c.angle_deg)
    return fig


@styled
def fig_metric(c: ComparisonResult, values: np.ndarray, label: str, key_small: str,
               key_large: str) -> Any:
    """The metric per patch (bars, colour = angle) and its scatter against the mean
    radiance for the small (30–60°) and large (65–90°) sample angles, with Pearson r."""
    from matplotlib.ticker import MaxNLocator

    from normbox_lab.analyze.compare import LARGE_ANGLES_DEG, SMALL_ANGLES_DEG

    fig = new_figure(MAX_WIDTH_IN, 7.0)
    gs = fig.add_gridspec(2, 2, height_ratios=[1.0, 1.0])
    ax = fig.add_subplot(gs[0, :])
    values, label = scaled_for_axis(values, label)
    radiance, radiance_label = scaled_for_axis(c.radiance_mean,
                                               f"mean reference radiance [{RADIANCE_UNIT}]",
                                               force=True)
    n_p, n_a = values.shape
    cols = angle_colours(n_a)
    width = 0.84 / n_a
    x = np.arange(n_p)
    for a in range(n_a):
        ax.bar(x + (a - (n_a - 1) / 2) * width, values[:, a], width, color=cols[a])
    # the patch numbers only: 24 names side by side run into one unreadable strip
    ax.set_xticks(x, [str(n).split()[0] for n in c.patch_names])
    ax.set_xlim(-0.6, n_p - 0.4)
    ax.set_xlabel("ColorChecker patch (number)")
    ax.set_ylabel(label)
    ax.grid(axis="x", visible=False)
    _angle_colourbar(fig, ax, c.angle_deg)
    for k, (rng, key) in enumerate(((SMALL_ANGLES_DEG, key_small), (LARGE_ANGLES_DEG, key_large))):
        sel = (c.angle_deg >= rng[0] - 1e-9) & (c.angle_deg <= rng[1] + 1e-9)
        axs = fig.add_subplot(gs[1, k])
        xs = radiance[:, sel]
        ys = values[:, sel]
        for j, a in enumerate(np.flatnonzero(sel)):
            axs.scatter(xs[:, j], ys[:, j], s=14, color=cols[a], edgecolor="none")
        r = c.correlations.get(key, float("nan"))
        axs.set_title(f"sample angles {rng[0]:g}–{rng[1]:g}°\nPearson r = "
                      f"{signed(r, 2, plus=False)}")
        axs.set_xlabel(radiance_label)
        axs.set_ylabel(label)
        axs.xaxis.set_major_locator(MaxNLocator(nbins=5, min_n_ticks=3))
    return fig


#: the printable width of an A4 page with the report's 14 mm margins, inches
A4_TEXT_WIDTH_IN = (210.0 - 2 * 14.0) / 25.4
_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def scaled_for_axis(values: np.ndarray, label: str, force: bool = False
                    ) -> tuple[np.ndarray, str]:
    """Values in units of 10ⁿ when they are below 10⁻² or from 10⁴ on (`force`: whenever the
    largest is not in [1, 10)), the power written into the axis label ("RMSE [10⁻⁵
    W·sr⁻¹·m⁻²·nm⁻¹]") instead of matplotlib's "1e-5" offset text."""
    v = np.asarray(values, dtype=float)
    top = float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else 0.0
    if top == 0.0 or (1e-2 <= top < 1e4 and not force) or 1.0 <= top < 10.0:
        return v, label
    n = int(np.floor(np.log10(top)))
    power = f"10{str(n).translate(_SUPERSCRIPT)}"
    if "[" in label and label.endswith("]"):
        head, unit = label[:-1].split("[", 1)
        return v / 10.0 ** n, f"{head}[{power} {unit}]"
    return v / 10.0 ** n, f"{label} [{power}]"


@styled
def fig_deltae(c: ComparisonResult, adapted: np.ndarray | None = None) -> Any:
    """ΔE00 heat map(s) patches × angles on the rating scale: the paper's convention and,
    when given, the adapted one below it.  Each cell prints its value with two decimals and
    takes the rating colour of the value as printed (a "1.00" is below the JND), the cell's
    colour and the text's from the same class index."""
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from normbox_lab.analyze.compare import rating_index

    maps = [("paper convention (D65 white)", c.delta_e00)]
    if adapted is not None:
        maps.append(("adapted to the measured white (CAT02)", adapted))
    # one map per row at the printable width of an A4 page (182 mm): printed, the figure
    # keeps its size and its numbers their point size (side by side they shrank to ~4 px)
    n_p = len(c.patch_names)
    fig = new_figure(A4_TEXT_WIDTH_IN, (0.3 * n_p + 0.9) * len(maps) + 0.9)
    axes = fig.subplots(len(maps), 1, squeeze=False)[:, 0]
    n_cls = len(RATING_SCALE)
    cmap = ListedColormap(RATING_COLOURS)
    norm = BoundaryNorm(np.arange(n_cls + 1) - 0.5, cmap.N)
    im = None
    for ax, (title, de) in zip(axes, maps, strict=True):
        shown = np.round(np.asarray(de, dtype=float), 2)
        cls = np.where(np.isfinite(shown), rating_index(np.nan_to_num(shown)), np.nan)
        im = ax.imshow(cls, aspect="auto", cmap=cmap, norm=norm, interpolation="nearest")
        for p in range(de.shape[0]):
            for a in range(de.shape[1]):
                if not np.isfinite(shown[p, a]):
                    continue
                ax.text(a, p, f"{shown[p, a]:.2f}", ha="center", va="center",
                        fontsize=FONT_PT["annotation"], color=RATING_TEXT[int(cls[p, a])])
        ax.set_xticks(range(c.angle_deg.size), [f"{v:g}" for v in c.angle_deg])
        ax.set_yticks(range(n_p), c.patch_names)
        ax.set_xlabel("sample angle [°]")
        ax.set_ylabel("ColorChecker patch")
        ax.set_title(title)
        ax.grid(False)
    cb = fig.colorbar(im, ax=axes, ticks=range(n_cls), location="bottom", fraction=0.04,
                      pad=0.03, aspect=40)
    cb.ax.set_xticklabels([f"{lab}\n(ΔE00 {rating_class_range(k)})"
                           for k, (_, lab) in enumerate(RATING_SCALE)])
    return fig


@styled
def fig_rating_counts(counts: Sequence[int], labels: Sequence[str], title: str) -> Any:
    """One horizontal bar split into the four rating classes, with the counts written in."""
    from matplotlib.patches import Patch

    fig = new_figure(6.0, 2.6)
    ax = fig.add_subplot(1, 1, 1)
    total = max(sum(counts), 1)
    left = 0.0
    for k, n in enumerate(counts):
        ax.barh(0, n, left=left, height=0.8, color=RATING_COLOURS[k])
        if n / total > 0.04:
            ax.text(left + n / 2, 0, str(n), ha="center", va="center", color=RATING_TEXT[k],
                    fontsize=FONT_PT["label"] + 1, fontweight="bold")
        left += n
    ax.set_xlim(0, total)
    ax.set_ylim(-0.5, 0.5)
    ax.set_yticks([])
    ax.set_xlabel("patch × angle configurations")
    ax.set_title(title, loc="left")
    ax.grid(False)
    fig.legend([Patch(color=col) for col in RATING_COLOURS],
               [f"{lab}: {n}" for lab, n in zip(labels, counts, strict=True)],
               loc="outside lower center", ncol=2, frameon=False)
    return fig


@styled
def fig_nrmse_by_angle(c: ComparisonResult) -> Any:
    """NRMSE [%] per sample angle: median over the patches with the full range."""
    fig = new_figure(6.0, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    pct = 100.0 * c.nrmse
    ax.fill_between(c.angle_deg, np.nanmin(pct, 0), np.nanmax(pct, 0), color="#56B4E9",
                    alpha=0.35, lw=0, label="range over patches")
    ax.plot(c.angle_deg, np.nanmedian(pct, 0), "o-", color="#0072B2", ms=4, label="median")
    ax.plot(c.angle_deg, np.nanmean(pct, 0), "s--", color="#D55E00", ms=3.5, label="mean")
    ax.set_xticks(c.angle_deg[::2])
    ax.set_xlabel("sample angle [°]")
    ax.set_ylabel("NRMSE [%]")
    ax.set_ylim(bottom=0)
    ax.legend(loc="upper left")
    return fig


@styled
def fig_error_model(em: ErrorModelResult, nrmse: np.ndarray | None) -> Any:
    """Stacked simulated error contributions per angle against the observed NRMSE [%]."""
    fig = new_figure(8.0, 3.8)
    ax = fig.add_subplot(1, 1, 1)
    x = np.asarray(em.angle_deg, dtype=float)
    cd = 100.0 * np.nanmean(em.contribution_d, axis=0)
    ci = 100.0 * np.nanmean(em.contribution_i, axis=0)
    width = 0.7 * (x[1] - x[0]) if x.size > 1 else 1.0
    ax.bar(x, cd, width, color="#0072B2", label="d·err_d (patch fit)")
    ax.bar(x, ci, width, bottom=cd, color="#E69F00", label="(1 − d)·err_i (wall fit)")
    ax.plot(x, 100.0 * np.nanmean(em.simulated_nrmse, axis=0), "^-", color="#000000", ms=5,
            label="simulated (RMS)")
    obs = em.observed_nrmse if em.observed_nrmse is not None else nrmse
    if obs is not None:
        ax.plot(x, 100.0 * np.nanmean(np.atleast_2d(obs), axis=0), "o--", color="#D55E00",
                ms=5, label="observed NRMSE")
    ax.set_xticks(x[::2] if x.size > 7 else x)
    ax.set_xlabel("sample angle [°]")
    ax.set_ylabel("error, mean over patches [%]")
    ax.legend(loc="upper left", ncol=2)
    return fig


@styled
def fig_nse(c: ComparisonResult, patch: int) -> Any:
    """NSE [%] spectra of one patch in the paper's sign, (reference − prediction)/reference
    (paper Fig. 13), one panel per sample angle, shared axes."""
    n_a = c.angle_deg.size
    ncol = 4
    nrow = int(np.ceil(n_a / ncol))
    height_in = 1.7 * nrow + 1.2
    fig = new_figure(MAX_WIDTH_IN, height_in, layout=None)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.55 / height_in, top=1 - 0.6 / height_in,
                        wspace=0.12, hspace=0.35)
    axes = fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False)
    pct = 100.0 * nse_paper_sign(c.nse[patch])
    lim = float(np.nanmax(np.abs(pct))) if np.isfinite(pct).any() else 1.0
    for k in range(nrow * ncol):
        ax = axes.flat[k]
        if k >= n_a:
            ax.set_visible(False)
            continue
        ax.axhline(0.0, color="0.5", lw=0.7)
        ax.plot(c.wavelength_nm, pct[k], lw=1.1, color="#0072B2")
        ax.set_ylim(-1.05 * lim - 1e-12, 1.05 * lim + 1e-12)
        ax.set_title(f"{c.angle_deg[k]:g}°", pad=2)
        ax.set_xticks([400, 550, 700])
    fig.supxlabel("wavelength [nm]")
    fig.supylabel("NSE [%]")
    fig.suptitle(f"NSE = {NSE_PAPER_SIGN}, in percent", fontsize=FONT_PT["label"])
    return fig


@styled
def fig_nse_fit(c: ComparisonResult, d: ReportData) -> tuple[Any, list[list[Any]]] | None:
    """Paper Fig. 14, NSE in the paper's sign: (a) some patches at the smallest angle vs their
    fit error at the direct geometry; (b) one patch (the paper: 21) at the largest angle vs the
    wall's fit error at a grazing geometry."""
    from normbox_lab.analyze.compare import direct_light_geometry

    names = list(d.patch_fit_names) if d.patch_fit_names is not None else list(c.patch_names)
    pairs = [(p, names[p]) for p in d.nse_fit_patches
             if p < len(names) and names[p] in d.fits and names[p] in d.brdf_data]
    have_wall = d.wall_name in d.fits and d.wall_name in d.brdf_data
    if not pairs and not have_wall:
        return None
    fig = new_figure(MAX_WIDTH_IN, 7.0)
    axes = fig.subplots(2, 2, sharex=True)
    (ax1, ax2), (ax3, ax4) = axes
    rows: list[list[Any]] = []
    ti, to = direct_light_geometry(c.angle_deg[0])
    for k, (p, name) in enumerate(pairs):
        ax1.plot(c.wavelength_nm, 100.0 * nse_paper_sign(c.nse[p, 0]), color=f"C{k}", lw=1.1,
                 label=f"patch {c.patch_names[p]}")
        err = fit_error_at(d.fits[name], d.brdf_data[name], float(ti), float(to))
        ax3.plot(d.brdf_data[name].wavelength_nm, 100.0 * err, color=f"C{k}", lw=1.1,
                 label=f"patch {c.patch_names[p]}")
        rows.append([c.patch_names[p], f"{c.angle_deg[0]:g}°",
                     100.0 * float(np.sqrt(np.nanmean(c.nse[p, 0] ** 2))),
                     f"patch fit at θi = {_deg(ti)}, θo = {_deg(to)}",
                     100.0 * float(np.sqrt(np.nanmean(err ** 2)))])
    ax1.set_title(f"(a) NSE at {c.angle_deg[0]:g}°\n(direct light dominates)")
    ax3.set_title(f"patch fitting error\nat θi = {_deg(ti)}, θo = {_deg(to)}")
    pb = min(max(int(d.nse_fit_patch_b), 0), len(c.patch_names) - 1)
    nse_b = nse_paper_sign(c.nse[pb, -1])
    ax2.plot(c.wavelength_nm, 100.0 * nse_b, lw=1.1, color="C0",
             label=f"patch {c.patch_names[pb]}")
    ax2.set_title(f"(b) NSE of patch {_short_patch(c.patch_names[pb])}\nat "
                  f"{c.angle_deg[-1]:g}° (indirect light)")
    if have_wall:
        wti, wto = d.wall_geometry_deg
        werr = fit_error_at(d.fits[d.wall_name], d.brdf_data[d.wall_name], wti, wto)
        ax4.plot(d.brdf_data[d.wall_name].wavelength_nm, 100.0 * werr, color="C5", lw=1.1)
        ax4.set_title(f"wall fitting error\nat θi = {_deg(wti)}, θo = {_deg(wto)}")
        rows.append([c.patch_names[pb], f"{c.angle_deg[-1]:g}°",
                     100.0 * float(np.sqrt(np.nanmean(nse_b ** 2))),
                     f"wall fit at θi = {_deg(wti)}, θo = {_deg(wto)}",
                     100.0 * float(np.sqrt(np.nanmean(werr ** 2)))])
    for ax in (ax1, ax2):
        ax.axhline(0.0, color="0.5", lw=0.7)
        ax.set_ylabel("NSE [%]\n(ref − pred)/ref")
    for ax in (ax3, ax4):
        ax.axhline(0.0, color="0.5", lw=0.7)
        ax.set_ylabel("fit error [%]\n(fit − meas.)/meas.")
        ax.set_xlabel("wavelength [nm]")
    for ax in (ax1, ax3):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best")
        elif not pairs:             # (the quick demo fits none of the paper's patches)
            wanted = ", ".join(str(p + 1) for p in d.nse_fit_patches)
            ax.text(0.5, 0.5, f"no fit of patch {wanted}\nin this campaign",
                    transform=ax.transAxes, ha="center", va="center", color="0.35")
    return fig, rows


@styled
def fig_images(f: ImageFigure) -> Any:
    """The panels side by side at their pixel aspect; scalar maps with a labelled colour bar."""
    n = len(f.panels)
    h, w = np.asarray(f.panels[0].data).shape[:2]
    width_in = min(4.0 * n, MAX_WIDTH_IN)
    fig = new_figure(width_in, width_in / n * h / w + 0.9)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, p in zip(axes, f.panels, strict=True):
        data = np.asarray(p.data)
        if data.ndim == 3:
            ax.imshow(data if data.dtype == np.uint8 else np.clip(data, 0.0, 1.0))
        else:
            finite = data[np.isfinite(data)]
            vmax = p.vmax if p.vmax is not None else (
                float(np.percentile(finite, 99)) if finite.size else 1.0)
            if p.vmax is not None:
                # panels that share a scale keep sharing it, up to the largest of their maxima:
                # the colour bar covers every value the caption may name
                vmax = max([vmax, *(float(np.nanmax(q.data)) for q in f.panels
                                    if q.vmax == p.vmax and np.asarray(q.data).ndim == 2
                                    and np.isfinite(q.data).any())])
            im = ax.imshow(data, cmap=SEQUENTIAL_CMAP, vmin=0.0, vmax=max(vmax, 1e-12))
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, shrink=0.9)
            if p.unit:
                cb.set_label(p.unit)
        ax.set_title(p.label)
        ax.set_axis_off()
    return fig


@styled
def fig_polar(data: Any, fit: Any, wavelength_nm: float) -> Any:
    """Paper Figs. 10/11 in the report's style: one polar panel per incident angle θi, the
    measured in-plane BRDF (points) and the fit (line) at one wavelength, θo on the polar axis
    (0° = normal, up), a dotted ray towards the light.  7.5 in wide, so that at 800 px its
    text keeps its 9 pt; one legend below the panels."""
    from matplotlib.lines import Line2D

    tis = (np.unique(data.theta_i_deg) if data is not None else np.arange(-80.0, 1.0, 10.0))
    tis = sorted(np.asarray(tis, dtype=float), key=abs)
    ncol = 3 if len(tis) > 4 else len(tis)
    nrow = int(np.ceil(len(tis) / ncol))
    fig = new_figure(7.5, 1.95 * nrow + 0.5)
    th_fine = np.linspace(-89.0, 89.0, 357)
    for k, ti in enumerate(tis):
        ax = half_polar_axes(fig, nrow, ncol, k)
        rmax = 0.0
        if data is not None:
            li = int(np.argmin(np.abs(data.wavelength_nm - wavelength_nm)))
            sel = np.isclose(data.theta_i_deg, ti)
            y = data.brdf_per_sr[sel, li]
            ok = np.isfinite(y)
            ax.plot(np.deg2rad(data.theta_o_deg[sel][ok]), y[ok], "o", ms=2.5, color="#000000")
            rmax = max(rmax, float(np.nanmax(y)) if ok.any() else 0.0)
        f = fit.brdf_inplane(np.full_like(th_fine, ti), th_fine)
        fl = np.array([np.interp(wavelength_nm, fit.wavelength_nm, row) for row in f])
        ax.plot(np.deg2rad(th_fine), np.maximum(fl, 0.0), "-", lw=1.2, color="#0072B2")
        rmax = max(rmax, float(np.max(fl))) or 1.0
        ax.plot([np.deg2rad(ti)] * 2, [0, rmax * 1.05], ":", color="0.5", lw=0.8)
        ax.set_rmax(rmax * 1.05)
        ax.set_yticklabels([])
        ax.set_thetagrids([-60, -30, 0, 30, 60], ["−60°", "−30°", "0°", "30°", "60°"])
        ax.tick_params(axis="x", pad=1)
        ax.set_title(f"θi = {signed(ti, 0, plus=False)}°, max {fmt_max(rmax)} sr⁻¹",
                     fontsize=FONT_PT["tick"], pad=2)
    fig.legend([Line2D([], [], ls="", marker="o", ms=4, color="#000000"),
                Line2D([], [], color="#0072B2", lw=1.2),
                Line2D([], [], color="0.5", ls=":", lw=0.8)],
               ["measured", f"fit (w = {fit.w:g})", "light direction θi"],
               loc="outside lower center", ncol=3, frameon=False)
    return fig


def fmt_max(v: float) -> str:
    """A radius maximum with three significant digits ("0.0812", "1.25")."""
    return f"{float(f'{v:.3g}'):g}" if abs(v) >= 1e-4 else f"{v:.2e}"


@styled
def in_style(plot: Callable[[], Any]) -> Any:
    """A figure made elsewhere (`analyze.fit.polar_plot`) in the
    report's rcParams."""
    return plot()


# --- the error budget (`normbox-lab budget`'s stored "error-budget" artifact) -------------------

@styled
def fig_budget(arrays: dict[str, np.ndarray], sources: Sequence[str]) -> Any:
    """Stacked budget per angle (the paper's Fig. 12 generalised to every source): each source's
    share of the total NRMSE² stacked to the total, mean over patches, against the observed
    NRMSE with its mean 95 % interval.  `arrays`: the stored "error-budget" artifact's."""
    import matplotlib

    ang = np.asarray(arrays["angle_deg"])
    c2 = np.mean(np.asarray(arrays["nrmse"]) ** 2, axis=1)            # [source, angle]
    total = np.sqrt(np.mean(np.asarray(arrays["total_nrmse"]) ** 2, axis=0))
    parts = 100 * total * c2 / np.maximum(c2.sum(axis=0, keepdims=True), 1e-300)
    fig = new_figure(7.5, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(ang.size)
    bottom = np.zeros(ang.size)
    cmap = matplotlib.colormaps["tab20"]
    for k, s in enumerate(sources):
        ax.bar(x, parts[k], bottom=bottom, color=cmap(k % 20), label=s)
        bottom += parts[k]
    obs = 100 * np.mean(arrays["observed_nrmse"], axis=0)
    ci = 100 * np.mean(arrays["observed_nrmse_ci"], axis=1)
    ax.errorbar(x, obs, yerr=[obs - ci[0], ci[1] - obs], fmt="ko--", ms=4, capsize=2,
                label="observed NRMSE (95 %)")
    ax.set_xticks(x, [f"{v:g}" for v in ang])
    ax.set_xlabel("sample angle [°]")
    ax.set_ylabel("NRMSE [%] (mean over patches)")
    ax.legend(ncol=3)
    return fig


def budget_rows(arrays: dict[str, np.ndarray], sources: Sequence[str]
                ) -> tuple[list, list, list, list]:
    """Two tables of the budget, each narrow enough for 800 px: (header, rows) of the sources'
    NRMSE contributions (%, RMS over patches) and their total, one row per source, one column
    per angle; and (header, rows) per angle of the total, the observed NRMSE with its
    interval, the significant configurations and the estimated angle offset."""
    ang = np.asarray(arrays["angle_deg"])
    by = 100 * np.sqrt(np.mean(np.asarray(arrays["nrmse"]) ** 2, axis=1))
    tot = 100 * np.sqrt(np.mean(np.asarray(arrays["total_nrmse"]) ** 2, axis=0))
    obs = 100 * np.mean(arrays["observed_nrmse"], axis=0)
    ci = 100 * np.mean(arrays["observed_nrmse_ci"], axis=1)
    sig = np.sum(arrays["significant_nrmse"], axis=0)
    off = arrays.get("angle_offset_deg")
    off_ci = arrays.get("angle_offset_ci95_deg")
    header = ["source", *[f"{a:g}°" for a in ang]]
    rows = [[s, *map(float, by[k])] for k, s in enumerate(sources)]
    rows.append(["total", *map(float, tot)])
    header2 = ["angle", "total [%]", "observed [%]", "95 % interval [%]", "significant",
               "angle offset [°]"]
    rows2 = []
    for a in range(ang.size):
        rows2.append([f"{ang[a]:g}°", float(tot[a]), float(obs[a]),
                      f"{ci[0, a]:.2f}–{ci[1, a]:.2f}", int(sig[a]),
                      "—" if off is None else f"{signed(off[a], 2)} ± {off_ci[a]:.2f}"])
    return header, rows, header2, rows2
