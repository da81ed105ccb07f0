"""Self-contained HTML validation report: inline SVG figures, no scripts, no external files.

`write_report(path, ReportData(...))` renders, from plain arrays / fits / comparison results
(the pipeline fills them from the store: `analyze.report_store`), in this order:

    section          content                                                     paper
    summary          verdict, ΔE00 of white at 30°, mean ΔE00 in both colour
                     conventions, NRMSE by angle, rating counts, worst configurations
    qa               quality flags of the runs (or "no QA data")
    reference        fig-reference, fig-prediction: spectra per patch × angle      Figs. 5–7 data
    physical         fig-rmse / fig-nrmse (+ tables): per patch × angle, scatter
                     against radiance with Pearson r                              Figs. 5, 6
    perceptual       fig-deltae: ΔE00 heat maps on the rating scale, both colour
                     conventions; tab-deltae, tab-rating                          Fig. 7
    nse              fig-nse: NSE per sample angle for one patch                  Fig. 13
    images           virtual-camera figures (truth | prediction | ΔE00 | noise)   Fig. 1
    fits             tab-fits, fig-polar-*: BRDF fits vs measured data            Figs. 10/11
    errormodel       fig-errormodel: d·err_d + (1−d)·err_i vs NRMSE per angle     Fig. 12
    nsefit           fig-nse-fit: NSE vs BRDF fitting error                       Fig. 14
    methods          instruments (serials, calibration dates), software, seeds, render
                     quality and Monte-Carlo error
    appendix         per-configuration metrics as a CSV (data: link)
    renderers        one row per renderer (ours and every imported one), the paper's
                     published figures beside this run's, spectral-vs-RGB ΔE00

Units: radiance and RMSE in W·sr⁻¹·m⁻²·nm⁻¹; NRMSE, NSE and fit errors in percent; ΔE00
(CIE 2000, kL = kC = kH = 1) in two conventions (see `delta_e00_adapted`).  Sections appear only
when their inputs are given.  matplotlib is imported lazily (figures: `report_figures`, style:
`report_style`).
"""

from __future__ import annotations

import base64
import csv
import html
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.analyze import paper_figures as pf
from normbox_lab.analyze.compare import (
    RATING_SCALE,
    ComparisonResult,
    ErrorModelResult,
    delta_e00_adapted,
    rate_delta_e,
    rating_class_range,
    rating_index,
)
from normbox_lab.analyze.report_data import (
    Headline,
    ImageFigure,
    ImagePanel,
    ReportData,
    headline,
)
from normbox_lab.analyze.report_style import RADIANCE_UNIT, RATING_COLOURS, RATING_TEXT

#: the report's data types live in `report_data`, the adapted ΔE00 in `compare`; these names
#: stay importable from here
__all__ = ["Headline", "ImageFigure", "ImagePanel", "ReportData", "build_html",
           "delta_e00_adapted", "headline", "metrics_csv", "write_report"]


def metrics_csv(c: ComparisonResult, adapted: np.ndarray) -> str:
    """The per-configuration metrics as CSV text (the report's data appendix)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["patch", "angle_deg", "mean_radiance_W_sr_m2_nm", "rmse_W_sr_m2_nm",
                "nrmse_pct", "nrmse_range_pct", "delta_e00_paper", "delta_e00_adapted",
                "rating_paper"])
    for p, name in enumerate(c.patch_names):
        for a, ang in enumerate(c.angle_deg):
            w.writerow([name, f"{ang:g}", repr(float(c.radiance_mean[p, a])),
                        repr(float(c.rmse[p, a])), repr(100.0 * float(c.nrmse[p, a])),
                        repr(100.0 * float(c.nrmse_range[p, a])),
                        repr(float(c.delta_e00[p, a])), repr(float(adapted[p, a])),
                        rate_delta_e(float(c.delta_e00[p, a]))])
    return buf.getvalue()


# -- HTML pieces ---------------------------------------------------------------------------------

def _esc(x: Any) -> str:
    return html.escape(str(x))


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
#: the report's one number format: significant digits of every table number
SIGNIFICANT_DIGITS = 3


def fmt_number(v: float, digits: int = SIGNIFICANT_DIGITS) -> str:
    """A number with exactly `digits` significant digits, trailing zeros kept ("1.00",
    "1.60", "0.0747"); below 10⁻³ or from 10⁵ on as "2.02×10⁻⁵" (no "e" notation); a
    negative number with the typographic minus ("−0.0971", U+2212)."""
    v = float(v)
    if np.isnan(v):
        return "—"
    if np.isinf(v):
        return "∞" if v > 0 else "−∞"
    if v == 0.0:
        return "0"
    mantissa, exponent = f"{v:.{digits - 1}e}".split("e")
    e = int(exponent)                  # of the rounded value: 0.9996 → 1.00e+00
    if -3 <= e < 5:
        text = f"{float(f'{mantissa}e{e}'):.{max(digits - 1 - e, 0)}f}"
    else:
        text = f"{mantissa}×10{str(int(exponent)).translate(_SUPERSCRIPT)}"
    return text.replace("-", "\u2212", 1) if text.startswith("-") else text


def _fmt(v: Any, digits: int = SIGNIFICANT_DIGITS) -> str:
    """Table text of a value: floats through `fmt_number`; no "inf"/"nan"."""
    if isinstance(v, float | np.floating):
        return fmt_number(float(v), digits)
    return str(v)


class _Doc:
    """Collects sections, figures and tables with their human titles (for the contents).

    A figure's SVG (most of a report's time: matplotlib lays it out and draws it) is made
    when the page is assembled (`body`), by this process and `children` child processes
    (`offload`), which start on the figures already collected while the rest are built; an
    SVG is the same bytes wherever it is drawn."""

    def __init__(self, children: int = 0) -> None:
        self._children = children
        self._offload: Any = None
        #: index in `parts` → (figure id, title, caption, width px, height px), SVG to come
        self._figures: dict[int, tuple[str, str, str, float, float]] = {}
        self.parts: list[str] = []
        self.sections: list[tuple[str, str, list[tuple[str, str]]]] = []
        self.figs: list[str] = []
        self.tabs: list[str] = []

    def section(self, sid: str, title: str, intro: str = "") -> None:
        if self.sections:
            self.parts.append("</section>")
        self.sections.append((sid, title, []))
        self.parts.append(f'<section id="{sid}"><h2>{_esc(title)}</h2>'
                          + (f"<p>{intro}</p>" if intro else ""))

    def html(self, text: str) -> None:
        self.parts.append(text)

    def figure(self, fid: str, title: str, fig: Any, caption: str) -> None:
        from normbox_lab.analyze.offload import Offload

        if self._offload is None:
            self._offload = Offload("normbox_lab.analyze.report_style:svg_job",
                                    self._children)
        w_in, h_in = fig.get_size_inches()
        self._figures[len(self.parts)] = (fid, title, caption, float(w_in) * 96.0,
                                          float(h_in) * 96.0)
        self._offload.submit(len(self.parts), (fig, np.get_printoptions()))
        self.parts.append("")                 # the figure's HTML, when its SVG is drawn
        self.figs.append(fid)
        self.sections[-1][2].append((fid, title))

    def _draw_figures(self) -> None:
        """Every collected figure's SVG, into its place."""
        from normbox_lab.analyze.report_style import svg_job

        if self._offload is None:
            return
        uris = self._offload.finish_here(svg_job)
        for at, (fid, title, caption, w_px, h_px) in self._figures.items():
            self.parts[at] = (
                f'<figure id="{fid}"><h3>{_esc(title)}</h3>'
                f'<img alt="{_esc(title)}" width="{w_px:.0f}" height="{h_px:.0f}" '
                f'src="{uris[at]}"><figcaption>{_esc(caption)}</figcaption></figure>')
        self._offload, self._figures = None, {}

    def close(self) -> None:
        """End the children, if any (a report that failed while being built)."""
        if self._offload is not None:
            self._offload.close()
            self._offload = None

    def table(self, tid: str, title: str, header: Sequence[str], rows: Sequence[Sequence[Any]],
              cell_class: Any = None, caption: str = "", digits: int = SIGNIFICANT_DIGITS
              ) -> None:
        """A table; every float cell through `fmt_number` (`digits` is kept for callers and
        ignored: one number format in the whole report)."""
        out = [f'<div class="table" id="{tid}"><h3>{_esc(title)}</h3>']
        if caption:
            out.append(f'<p class="caption">{_esc(caption)}</p>')
        out.append("<div class='scroll'><table><thead><tr>")
        out += [f"<th>{_esc(h)}</th>" for h in header]
        out.append("</tr></thead><tbody>")
        # prose reads from the left: a column with a long text cell is left-aligned in every
        # row (one alignment per column)
        prose = {j for row in rows for j, v in enumerate(row)
                 if j > 0 and isinstance(v, str) and len(v) > 16}
        for i, row in enumerate(rows):
            out.append("<tr>")
            for j, v in enumerate(row):
                cls = cell_class(i, j, v) if cell_class else ""
                if j > 0 and isinstance(v, float | np.floating):
                    cls = f"{cls} num".strip()       # a number never breaks ("2.02×10⁻⁵")
                elif j in prose and isinstance(v, str) and "text" not in cls:
                    cls = f"{cls} text".strip()
                attr = f' class="{cls}"' if cls else ""
                tag = "th" if j == 0 else "td"
                out.append(f"<{tag}{attr}>{_esc(_fmt(v))}</{tag}>")
            out.append("</tr>")
        out.append("</tbody></table></div></div>")
        self.parts.append("".join(out))
        self.tabs.append(tid)
        self.sections[-1][2].append((tid, title))

    def contents(self) -> str:
        out = ["<nav id='contents'><h2>Contents</h2><ol>"]
        for sid, title, items in self.sections:
            out.append(f"<li><a href='#{sid}'>{_esc(title)}</a>")
            if items:
                out.append("<ul>" + "".join(f"<li><a href='#{i}'>{_esc(t)}</a></li>"
                                            for i, t in items) + "</ul>")
            out.append("</li>")
        out.append("</ol></nav>")
        return "".join(out)

    def body(self) -> str:
        self._draw_figures()
        return "".join(self.parts) + ("</section>" if self.sections else "")


def _rating_class(_i: int, j: int, v: Any) -> str:
    """The rating colour of a ΔE00 cell, from the value as printed (a "1.00" is ≤ 1)."""
    if j == 0 or not isinstance(v, float | np.floating) or not np.isfinite(v):
        return ""
    shown = float(fmt_number(float(v)).replace("×10", "e").translate(
        str.maketrans("−⁻⁰¹²³⁴⁵⁶⁷⁸⁹", "--0123456789")))
    return f"r{int(rating_index(shown))}"


_CSS = """
:root{--ink:#1a1a1a;--muted:#4a4a4a;--rule:#c8c8c8}
html{font-size:16px}
body{font-family:system-ui,"DejaVu Sans",Arial,sans-serif;line-height:1.45;max-width:1200px;
margin:0 auto;padding:1rem 1.5rem;color:var(--ink)}
h1{font-size:1.7rem;margin:.2rem 0} h2{font-size:1.35rem;border-bottom:2px solid var(--rule);
margin-top:2rem;padding-bottom:.2rem} h3{font-size:1.05rem;margin:.8rem 0 .3rem}
p,li{max-width:75ch}
.subtitle{color:var(--muted);margin:.2rem 0 1rem}
.verdict{font-size:1.1rem;border-left:5px solid #0072B2;background:#eef5fb;padding:.6rem .9rem;
max-width:none}
.cards{display:grid;grid-template-columns:repeat(auto-fit,minmax(220px,1fr));gap:.7rem;
margin:.8rem 0}
.card{border:1px solid var(--rule);border-radius:6px;padding:.5rem .7rem}
.card .k{font-size:.85rem;color:var(--muted)} .card .v{font-size:1.45rem;font-weight:600}
.card .s{font-size:.8rem;color:var(--muted)}
.two{display:grid;grid-template-columns:repeat(auto-fit,minmax(480px,1fr));gap:1rem;
align-items:start}
figure{margin:1rem 0} figure img{max-width:100%;height:auto;display:block}
figcaption,.caption{font-size:.9rem;color:var(--muted);max-width:none}
.scroll{overflow-x:auto}
table{border-collapse:collapse;font-size:.8rem;font-variant-numeric:tabular-nums}
td,th{border:1px solid var(--rule);padding:.15rem .4rem;text-align:right}
td.num{white-space:nowrap} td.text{text-align:left}
thead th{background:#eeeeee;text-align:center} tbody th{text-align:left;background:#f7f7f7;
font-weight:600}
.r0{background:RC0;color:RT0} .r1{background:RC1;color:RT1} .r2{background:RC2;color:RT2}
.r3{background:RC3;color:RT3}
.sev-error{color:#b00020;font-weight:600} .sev-warning{color:#8a5a00}
.note{font-size:.9rem;color:var(--muted)}
nav#contents ol{columns:2;column-gap:2rem} nav#contents ul{font-size:.9rem}
a{color:#0060a0}
@media (max-width:900px){body{padding:1rem .75rem} table{font-size:.75rem}
 td,th{padding:.1rem .22rem}}
@page{size:A4;margin:14mm}
@media print{
 html{font-size:10pt} body{max-width:none;padding:0}
 section{break-before:page} section#summary{break-before:auto}
 figure,.table,.card,.verdict{break-inside:avoid} h2,h3{break-after:avoid}
 .scroll{overflow:visible} a{color:inherit;text-decoration:none}
 nav#contents{break-after:page}
}
"""


def _css() -> str:
    out = _CSS
    for k in range(4):
        out = out.replace(f"RC{k}", RATING_COLOURS[k]).replace(f"RT{k}", RATING_TEXT[k])
    return out


def _card(key: str, value: str, sub: str = "") -> str:
    return (f"<div class='card'><div class='k'>{_esc(key)}</div><div class='v'>{_esc(value)}"
            f"</div>" + (f"<div class='s'>{_esc(sub)}</div>" if sub else "") + "</div>")


def _campaign_line(d: ReportData) -> str:
    if not d.runs:
        return ""
    dates = sorted({str(r.get("date", "")) for r in d.runs if r.get("date")})
    span = (dates[0] if len(dates) == 1 else f"{dates[0]} – {dates[-1]}") if dates else ""
    runs = ", ".join(f"{r['protocol']} (run {r['id']}, {r.get('readings', '?')} readings)"
                     for r in d.runs)
    inst = ", ".join(f"{i.get('model', i.get('role', '?'))}" for i in d.instruments)
    return (f"Campaign{': ' + span if span else ''} — {runs}."
            + (f" Instruments: {inst}." if inst else ""))


# -- the report ----------------------------------------------------------------------------------

def build_html(d: ReportData, *, children: int | None = None
               ) -> tuple[str, list[str], list[str]]:
    """(html, figure ids, table ids).  The adapted-convention ΔE00 is the comparison's own
    (`ComparisonResult.delta_e00_adapted`, computed once by `compare`), not recomputed here.
    `children`: child processes that draw figures (default `offload.idle_children()`; the
    page is the same bytes with any number)."""
    from normbox_lab.analyze.offload import idle_children

    doc = _Doc(idle_children() if children is None else children)
    try:
        return _build(doc, d)
    finally:
        doc.close()


def _build(doc: _Doc, d: ReportData) -> tuple[str, list[str], list[str]]:
    c = d.comparison
    adapted = _adapted(c)
    hl = headline(c, adapted) if c is not None and adapted is not None else None
    _summary_section(doc, d, c, hl)
    _qa_section(doc, d.flags)
    if c is not None and adapted is not None:
        _comparison_sections(doc, d, c, adapted, hl)
    if d.images:
        _images_section(doc, d.images)
    if d.fits:
        _fits_section(doc, d)
    if d.error_model is not None:
        _error_model_section(doc, d.error_model, c)
    if d.budget is not None:
        _budget_section(doc, *d.budget)
    if c is not None and d.fits:
        _nse_fit_section(doc, c, d)
    if d.instruments or d.methods or d.runs or d.metadata:
        _methods_section(doc, d)
    if c is not None and adapted is not None:
        _appendix_section(doc, c, adapted)
    # last, so that the sections before keep their numbers (report-NN-*.png screenshots)
    if d.renderers or d.paper:
        _renderers_section(doc, d, c)
    return _assemble(doc, d), doc.figs, doc.tabs


def _adapted(c: ComparisonResult | None) -> np.ndarray | None:
    """The comparison's adapted-convention ΔE00; NaN ("—") for one stored without it."""
    if c is None:
        return None
    if c.delta_e00_adapted is None:
        return np.full(c.delta_e00.shape, np.nan)
    return np.asarray(c.delta_e00_adapted, dtype=float)


def _summary_section(doc: _Doc, d: ReportData, c: ComparisonResult | None,
                     hl: Headline | None) -> None:
    from normbox_lab.analyze import report_figures as rf

    doc.section("summary", "Summary")
    doc.html(f'<p class="qa-summary">{_esc(_qa_line(d.flags))}</p>')
    if hl is not None and c is not None:
        n_cfg = int(np.isfinite(c.delta_e00).sum())
        verdict = (f"Simulated campaign (virtual Normbox, emulated instruments): {hl.verdict}"
                   if d.simulated else hl.verdict)
        doc.html(f"<p class='verdict'>{_esc(verdict)}</p>")
        white_name = c.patch_names[c.white_patch]
        qa_txt, qa_sub = _qa_card(d.flags)
        doc.html("<div class='cards'>"
                 + _card(f"ΔE00 of white (patch {white_name}) at {c.white_angle_deg:g}°",
                         f"{hl.white_delta_e00:.2f}",
                         f"adapted convention: {hl.white_delta_e00_adapted:.2f}")
                 + _card("mean ΔE00 (paper convention)", f"{hl.mean_delta_e00:.2f}",
                         f"adapted convention: {hl.mean_delta_e00_adapted:.2f}")
                 + _card("largest ΔE00 (paper convention)", f"{hl.max_delta_e00:.2f}",
                         f"patch {hl.max_at[0]} at {hl.max_at[1]:g}°; adapted convention: "
                         f"{hl.max_delta_e00_adapted:.2f} (patch {hl.max_adapted_at[0]} at "
                         f"{hl.max_adapted_at[1]:g}°)")
                 + _card("mean NRMSE", f"{hl.nrmse_mean_pct:.1f} %",
                         "RMSE / mean reference radiance, in percent")
                 + _card("configurations", f"{n_cfg}",
                         f"{len(c.patch_names)} patches × {c.angle_deg.size} sample angles")
                 + _card("quality flags", qa_txt, qa_sub)
                 + "</div>")
        doc.html("<div class='two'>")
        doc.figure("fig-summary-rating", "ΔE00 on the rating scale",
                   rf.fig_rating_counts(hl.rating_counts, [lab for _, lab in RATING_SCALE],
                                        "paper convention (D65 white)"),
                   "How many patch × angle configurations fall in each class of the rating "
                   "scale (ΔE00 ≤ 1 below the just-noticeable difference; ≤ 2 not discernible "
                   "side by side; ≤ 5 discernible side by side; > 5 easily perceived). "
                   f"Adapted convention: {', '.join(map(str, hl.rating_counts_adapted))}.")
        doc.figure("fig-summary-nrmse", "NRMSE by sample angle", rf.fig_nrmse_by_angle(c),
                   "NRMSE in percent per sample angle: median and mean over the patches, "
                   "band = the range. At small angles direct light dominates (patch fit "
                   "error), at large angles indirect light (wall fit error).")
        doc.html("</div>")
        doc.table("tab-nrmse-angle", "NRMSE by sample angle [%] (mean over patches)",
                  ["sample angle", *[f"{a:g}°" for a in c.angle_deg]],
                  [["NRMSE [%]", *map(float, hl.nrmse_by_angle_pct)]], digits=3)
        doc.table("tab-worst", "Worst configurations (largest ΔE00)",
                  ["patch", "sample angle", "ΔE00 (paper)", "ΔE00 (adapted)", "NRMSE [%]"],
                  [[p, f"{a:g}°", de, dea, nr] for p, a, de, dea, nr in hl.worst],
                  cell_class=lambda i, j, v: _rating_class(i, j, v) if j in (2, 3) else "",
                  digits=3)
    else:
        doc.html("<p>No comparison in this report: the summary needs a comparison of "
                 "predictions with reference readings.</p>")
    for n in d.notes:
        doc.html(f"<p class='note'>{_esc(n)}</p>")


def _renderers_section(doc: _Doc, d: ReportData, c: ComparisonResult | None) -> None:
    """Renderers side by side, the paper's published figures beside this run's, and the
    spectral-vs-RGB rendering error."""
    from normbox_lab.analyze.compare import RATING_SCALE

    doc.section("renderers", "Renderers and the paper side by side")
    if d.renderers:
        angles = [] if c is None else [f"{a:g}°" for a in c.angle_deg]
        scale = ", ".join(f"{rating_class_range(k)} {lab}"
                          for k, (_, lab) in enumerate(RATING_SCALE))
        doc.table("tab-renderers", "Every renderer against the measurement (one row each): "
                  "ΔE00 and ratings",
                  ["renderer", "version", "ΔE00 mean", "ΔE00 max",
                   "ratings " + " / ".join(rating_class_range(k)
                                           for k in range(len(RATING_SCALE)))],
                  [[r.renderer, r.version, float(r.delta_e00_mean), float(r.delta_e00_max),
                    " / ".join(str(n) for n in r.rating_counts)] for r in d.renderers],
                  caption="The same reference run, the same comparison (paper convention "
                  f"ΔE00; ratings: configurations per class, {scale}) for our prediction and "
                  "each imported renderer (normbox-lab import prediction).")
        if angles:
            rows = []
            for r in d.renderers:
                nr = list(r.nrmse_by_angle_pct) + [float("nan")] * (
                    len(angles) - len(r.nrmse_by_angle_pct))
                rows.append([r.renderer, *map(float, nr[:len(angles)])])
            doc.table("tab-renderers-nrmse", "Every renderer: NRMSE [%] per sample angle",
                      ["renderer", *angles], rows,
                      caption="NRMSE = RMSE / mean reference radiance, in percent, mean over "
                      "the patches at each sample angle.")
    if d.paper:
        doc.table("tab-paper", "The paper's published figures beside this run",
                  ["observation", "paper (published)", "where in the paper", "this run"],
                  [[obs, paper, _where(obs), ours] for obs, paper, ours in d.paper],
                  cell_class=lambda i, j, v: "text" if j > 0 else "",
                  caption=f"Where the Normbox paper ({pf.PAPER}) gives a figure, this run's "
                  f"value beside it. NSE in the paper's sign, {pf.NSE_PAPER_SIGN}; "
                  "percentages with one decimal, correlations, ΔE00 and angles with two.")
    for e in d.rendering_errors:
        hdr = ["patch", *[f"{a:g}°" for a in e.angle_deg], "mean"]
        mean_col = len(hdr) - 1                  # the mean column: not a rating colour
        doc.table(f"tab-rgb-{e.rgb}", f"Spectral vs RGB rendering: ΔE00 between {e.rgb} and "
                  f"{e.spectral}, per patch and sample angle",
                  hdr, [[n, *map(float, e.delta_e00[p]), float(np.nanmean(e.delta_e00[p]))]
                        for p, n in enumerate(e.patch_names)],
                  cell_class=lambda i, j, v, last=mean_col:
                  _rating_class(i, j, v) if j < last else "",
                  caption="The colour error an RGB (triplet) rendering of the same scene "
                  "adds: ΔE00 between the two renderers' predictions (XYZ normalised by the "
                  "spectral renderer's white at the white angle, Lab D65). Against the "
                  "measurement: mean ΔE00 " + ", ".join(
                      f"{k} {fmt_number(float(np.nanmean(v)))}"
                      for k, v in e.delta_e00_vs_reference.items()) + ".")


def _qa_section(doc: _Doc, flags: Sequence[Any] | None) -> None:
    doc.section("qa", "Quality flags")
    if flags is None:
        doc.html("<p>No QA data: nothing recorded whether the readings, calibrations or fits "
                 "of these runs passed the quality gates.</p>")
        return
    if not flags:
        doc.html("<p>No quality flags: every quality gate passed on the runs of this "
                 "report.</p>")
        return
    max_rows = 200
    ordered = sorted(flags, key=lambda f: (f.severity != "error", f.run_id or 0, f.key))
    doc.table("tab-qa", "Quality flags (errors first)",
              ["severity", "run", "reading / artifact", "gate", "value", "limit", "message"],
              [[f.severity, str(f.run_id or ""), f.key or "(run)", f.gate,
                "" if f.value is None else float(f.value),
                "" if f.limit is None else float(f.limit), f.message]
               for f in ordered[:max_rows]],
              cell_class=lambda i, j, v: f"sev-{v}" if j == 0 else "")
    if len(ordered) > max_rows:
        doc.html(f"<p>… and {len(ordered) - max_rows} more: <code>normbox-lab qa "
                 "RUN_ID</code> lists them all.</p>")


def _comparison_sections(doc: _Doc, d: ReportData, c: ComparisonResult, adapted: np.ndarray,
                         hl: Headline | None) -> None:
    """reference, physical, perceptual and nse."""
    from normbox_lab.analyze import report_figures as rf

    ang_hdr = ["patch", *[f"{v:g}°" for v in c.angle_deg]]
    doc.section("reference", "Reference and prediction spectra")
    doc.figure("fig-reference", "Reference spectra of every patch", rf.fig_reference(c),
               "Measured spectral radiance of each ColorChecker patch at each sample angle "
               "(colour bar). Look at how the level falls as the sample turns from the "
               "light (30°) towards the radiometer (90°).")
    doc.figure("fig-prediction", "Prediction vs reference",
               rf.fig_prediction(c, d.prediction_patches),
               "Solid: reference; dashed: prediction; colour: sample angle. Where the "
               "dashed line leaves the solid one, the BRDF fit or the wall misses light.")
    doc.section("physical", "Physical comparison: RMSE and NRMSE")
    doc.figure("fig-rmse", "RMSE per patch and its correlation with radiance (paper Fig. 5)",
               rf.fig_metric(c, c.rmse, f"RMSE [{RADIANCE_UNIT}]", "radiance_rmse_small",
                             "radiance_rmse_large"),
               "Top: RMSE over wavelengths per patch and sample angle. Bottom: mean "
               "reference radiance against RMSE at small and large sample angles with "
               "Pearson r: a strong correlation means the absolute error scales with "
               "the light.")
    doc.figure("fig-nrmse", "NRMSE per patch and its correlation with radiance (paper Fig. 6)",
               rf.fig_metric(c, 100.0 * c.nrmse, "NRMSE [%]", "radiance_nrmse_small",
                             "radiance_nrmse_large"),
               "NRMSE = RMSE / mean reference spectrum, in percent. Dark patches have "
               "large relative errors on little light.")
    rmse, rmse_label = rf.scaled_for_axis(c.rmse, f"RMSE [{RADIANCE_UNIT}]")
    doc.table("tab-rmse", rmse_label, ang_hdr,
              [[n, *map(float, rmse[p])] for p, n in enumerate(c.patch_names)], digits=3)
    doc.table("tab-nrmse", "NRMSE [%]", ang_hdr,
              [[n, *map(float, 100.0 * c.nrmse[p])] for p, n in enumerate(c.patch_names)],
              digits=3)
    doc.table("tab-correlations", "Correlation of radiance with RMSE / NRMSE",
              ["pair", "Pearson r"],
              [[_corr_label(k), float(v)] for k, v in c.correlations.items()], digits=3)
    _perceptual_section(doc, c, adapted, hl)
    nse_patch = min(d.nse_patch, len(c.patch_names) - 1)
    doc.section("nse", "Spectral error per angle (NSE)")
    doc.figure("fig-nse", f"NSE per sample angle of patch {c.patch_names[nse_patch]} "
               f"(paper {pf.where('fig13_patch').split(', ')[-1]})", rf.fig_nse(c, nse_patch),
               f"Normalised spectral error in the paper's sign, {pf.NSE_PAPER_SIGN}, in "
               "percent (paper Sec. 4.5.1): above zero the prediction is too dark. One panel "
               "per sample angle. A tilt across the spectrum points to a colour error; an "
               "offset to a level error. The paper shows patch "
               f"{pf.patch_number('fig13_patch')}.")


def _perceptual_section(doc: _Doc, c: ComparisonResult, adapted: np.ndarray,
                        hl: Headline | None) -> None:
    from normbox_lab.analyze import report_figures as rf

    ang_hdr = ["patch", *[f"{v:g}°" for v in c.angle_deg]]
    doc.section("perceptual", "Perceptual comparison: ΔE00", _esc(_convention_text(c, hl)))
    doc.figure("fig-deltae", "ΔE00 per patch and angle on the rating scale (paper Fig. 7)",
               rf.fig_deltae(c, adapted),
               "Each cell is one patch at one sample angle, coloured by the class on the "
               "rating scale of the value printed in it (two decimals: a 1.00 is below the "
               "JND). Top: the paper's convention; bottom: adapted to the measured white. "
               "Compare the columns: differences grow where indirect light dominates.")
    doc.table("tab-deltae", "ΔE00, paper convention (D65 white)", ang_hdr,
              [[n, *map(float, c.delta_e00[p])] for p, n in enumerate(c.patch_names)],
              cell_class=_rating_class, digits=3)
    doc.table("tab-deltae-adapted", "ΔE00, adapted convention (CAT02 to D65)", ang_hdr,
              [[n, *map(float, adapted[p])] for p, n in enumerate(c.patch_names)],
              cell_class=_rating_class, digits=3)
    doc.table("tab-rating", "Rating scale: configurations per class",
              ["class", "ΔE00", "count (paper)", "count (adapted)"],
              [[lab, rating_class_range(k), hl.rating_counts[k] if hl else 0,
                hl.rating_counts_adapted[k] if hl else 0]
               for k, (_, lab) in enumerate(RATING_SCALE)],
              cell_class=lambda i, j, v: f"r{i}" if j == 0 else "")
    doc.table("tab-deltae-means", "Mean ΔE00 per sample angle",
              ["convention", *[f"{v:g}°" for v in c.angle_deg], "all"],
              [["paper", *map(float, np.nanmean(c.delta_e00, 0)),
                float(np.nanmean(c.delta_e00))],
               ["adapted", *map(float, np.nanmean(adapted, 0)),
                float(np.nanmean(adapted))]], digits=3,
              caption="paper: Lab with the D65 white; adapted: CAT02 to D65 first.")


def _images_section(doc: _Doc, images: Sequence[ImageFigure]) -> None:
    from normbox_lab.analyze import report_figures as rf

    doc.section("images", "Images (virtual camera)")
    for f in images:
        doc.figure(f.fid, f.title, rf.fig_images(f), f.caption)


def _fits_section(doc: _Doc, d: ReportData) -> None:
    from normbox_lab.analyze import report_figures as rf
    doc.section("fits", "BRDF fits")
    ws = sorted({float(f.w) for f in d.fits.values()})
    doc.table("tab-fits", "Fitted parameters", ["material", "α (roughness)", "η",
                                               "c [sr⁻¹]", "w", "fit error [%]",
                                               "cost E (Eq. 9)"],
              [[n, f.alpha, f.eta, _c_text(f.c), f"{f.w:g}", f.fit_error_pct, f.cost]
               for n, f in d.fits.items()], digits=3,
              caption="Cook–Torrance/GGX fit per material (paper Sec. 4.3). α: roughness; "
              "η: one refractive index; c: the constant subtracted from the model (paper "
              "Eq. 6), \"0 (unused)\" where the fit set it to zero, as the paper found for "
              "some materials; w: the exponent of the weight cos^w θi in the cost; fit error: "
              "relative RMS difference of fit and measurement; cost E: the fit's cost at its "
              "optimum, the sum of squared differences of ln(1 + cos^w θi · BRDF) over the "
              "measured geometries and wavelengths (Löw et al.'s log cost, paper Eqs. 7–9), "
              "comparable only between fits of one material at one w. The paper: "
              f"{pf.cite('fit_weight_w')}. This run fits every material with w = "
              f"{', '.join(f'{w:g}' for w in ws)}: the paper publishes w for two patches "
              "only, and one w keeps all fits comparable; normbox-lab fit RUN "
              "--weight-exponent 4 refits every material with patch 18's w = 4.")
    names = list(d.polar_materials) if d.polar_materials is not None else (
        [n for n in ("patch08", "patch18") if n in d.fits]
        or [n for n in d.fits if n != d.wall_name][:1])
    names += [d.wall_name] if d.polar_materials is None and d.wall_name in d.fits else []
    for n in names:
        if n not in d.fits:
            continue
        fig = rf.fig_polar(d.brdf_data.get(n), d.fits[n], d.polar_wavelength_nm)
        doc.figure(f"fig-polar-{n}", f"BRDF of {n} at {d.polar_wavelength_nm:g} nm "
                   f"(paper {pf.where('polar_wavelength').split(', ')[-1]})", fig,
                   "Points: measured in-plane BRDF [sr⁻¹]; line: the fit (tilted geometry); "
                   "one panel per incident angle θi, θo on the polar axis (0° = the normal), "
                   "dotted ray = light direction; each panel to its own radius (its maximum "
                   "in the title). Look for points the line misses near grazing angles (the "
                   "Fresnel reflection) and near the light (backscatter).")


def _error_model_section(doc: _Doc, em: ErrorModelResult, c: ComparisonResult | None) -> None:
    from normbox_lab.analyze import report_figures as rf

    doc.section("errormodel", "Error model")
    doc.figure("fig-errormodel", "Error model vs NRMSE (paper Fig. 12)",
               rf.fig_error_model(em, c.nrmse if c is not None else None),
               "Bars: the simulated error from the direct-light share d per angle times "
               "the patch fit error err_d, plus (1 − d) times the wall fit error err_i; "
               "lines: simulated and observed NRMSE. Where the lines agree, the fit errors "
               "explain the prediction error. Each bar is one term's RMS over wavelengths, the "
               "simulated line the RMS of the two terms' sum: an RMS does not add, the RMS of "
               "a sum is at most the sum of the RMSs (equal only for spectra of one shape and "
               "sign). So where both terms count (large angles) and their spectra differ, the "
               "stacked bars stand above the simulated line.")
    obs = em.observed_nrmse if em.observed_nrmse is not None else (
        c.nrmse if c is not None else None)
    rows = []
    for a, ang in enumerate(em.angle_deg):
        rows.append([f"{ang:g}°", float(np.nanmean(em.direct_share[:, a])),
                     100.0 * float(np.nanmean(em.contribution_d[:, a])),
                     100.0 * float(np.nanmean(em.contribution_i[:, a])),
                     100.0 * float(np.nanmean(em.simulated_nrmse[:, a])),
                     100.0 * float(np.nanmean(np.atleast_2d(obs)[:, a])) if obs is not None
                     else float("nan")])
    doc.table("tab-errormodel", "Error model per angle (means over patches)",
              ["angle", "direct share d", "d·err_d [%]", "(1−d)·err_i [%]",
               "simulated [%]", "observed NRMSE [%]"], rows, digits=3)


def _budget_section(doc: _Doc, arrays: dict[str, Any], sources: list[str]) -> None:
    from normbox_lab.analyze import report_figures as rf

    doc.section("budget", "Error budget")
    doc.figure("fig-budget", "Error budget per angle (paper Fig. 12, every source)",
               rf.fig_budget(arrays, sources),
               "Each source's share of the total NRMSE (stacked), propagated from its "
               "distribution (normbox-lab budget), against the observed NRMSE with its "
               "95 % interval.")
    header, rows, header2, rows2 = rf.budget_rows(arrays, sources)
    doc.table("tab-budget", "Error budget: each source's NRMSE contribution [%] per sample "
              "angle (RMS over patches)", header, rows, digits=3)
    doc.table("tab-budget-observed", "Error budget per angle: total, observed NRMSE, "
              "significant configurations, estimated sample-angle offset", header2, rows2,
              digits=3)


def _nse_fit_section(doc: _Doc, c: ComparisonResult, d: ReportData) -> None:
    from normbox_lab.analyze import report_figures as rf

    got = rf.fig_nse_fit(c, d)
    if got is None:
        return
    fig, rows = got
    doc.section("nsefit", "NSE vs BRDF fitting error")
    doc.figure("fig-nse-fit", "NSE vs fitting error (paper Fig. 14)", fig,
               f"Top: NSE in the paper's sign, {pf.NSE_PAPER_SIGN}, (a) of patches "
               f"{', '.join(c.patch_names[p] for p in d.nse_fit_patches if p < len(c.patch_names))} "
               f"at the smallest and (b) of patch {c.patch_names[min(d.nse_fit_patch_b, len(c.patch_names) - 1)]} "
               "at the largest sample angle (the paper: "
               f"{pf.quote('fig14a')}; {pf.quote('fig14b')}). Bottom: the relative BRDF "
               "fitting error, (fit − measured)/measured, at the matching geometry (patch: "
               "direct light; wall: grazing); the paper does not state its fitting error's "
               "sign. A fit that is too bright makes the prediction too bright, which the "
               "paper's NSE shows below zero: the same cause gives mirrored shapes.")
    doc.table("tab-nse-fit", "NSE vs fitting error (RMS over wavelengths)",
              ["patch", "angle", "RMS NSE [%]", "fit error at", "RMS fit error [%]"],
              rows, digits=3)


def _methods_section(doc: _Doc, d: ReportData) -> None:
    doc.section("methods", "Methods")
    if d.runs:
        doc.table("tab-runs", "Runs", ["run", "protocol", "status", "readings", "started",
                                      "finished", "seeds"],
                  [[r["id"], r["protocol"], r.get("status", ""), r.get("readings", ""),
                    r.get("started", ""), r.get("finished", ""), r.get("seeds", "")]
                   for r in d.runs])
    if d.instruments:
        doc.table("tab-instruments", "Instruments",
                  ["role", "model", "serial", "firmware", "calibration", "runs"],
                  [[i.get("role", ""), i.get("model", ""), i.get("serial", ""),
                    i.get("firmware", ""), i.get("calibration", ""), i.get("runs", "")]
                   for i in d.instruments])
    _calibrations_table(doc, d)
    rows = [[k, v] for k, v in d.methods.items()] + [[str(k), str(v)]
                                                    for k, v in d.metadata.items()]
    if rows:
        doc.table("tab-methods", "Software, seeds, rendering", ["item", "value"], rows)


def _calibrations_table(doc: _Doc, d: ReportData) -> None:
    """The calibrations in force that the runs recorded with their instruments (lab config
    `[instruments.ROLE.calibration]`), and any run that was made after one had expired."""
    cals = [(i.get("role", ""), i["calibration_record"]) for i in d.instruments
            if i.get("calibration_record")]
    if not cals:
        return
    rows = []
    for role, c in cals:
        expired = c.get("expired_in_runs") or []
        uncertainty = f"±{c.get('uncertainty_percent', '')} % (k={c.get('coverage_k', 2)})"
        responsivity = (f"{c['responsivity_file']} (sha256 "
                        f"{c.get('responsivity_sha256', '')[:12]})"
                        if c.get("responsivity_file") else "—")
        rows.append([role, c.get("certificate", ""), c.get("laboratory", ""), c.get("date", ""),
                     c.get("due", ""), uncertainty, responsivity,
                     f"EXPIRED in run {', '.join(expired)}" if expired else "in force"])
    doc.table("tab-calibrations", "Calibrations", ["role", "certificate", "laboratory", "date",
                                                   "due", "stated uncertainty",
                                                   "responsivity correction", "status"], rows)


def _appendix_section(doc: _Doc, c: ComparisonResult, adapted: np.ndarray) -> None:
    doc.section("appendix", "Data appendix")
    text = metrics_csv(c, adapted)
    uri = "data:text/csv;base64," + base64.b64encode(text.encode("utf-8")).decode("ascii")
    doc.html(f"<p id='data-csv'><a download='normbox-metrics.csv' href='{uri}'>"
             f"Download the per-configuration metrics (CSV, {len(c.patch_names)} × "
             f"{c.angle_deg.size} rows)</a>: patch, sample angle, mean radiance and RMSE "
             f"[{RADIANCE_UNIT}], NRMSE and NRMSE by range [%], ΔE00 in both conventions, "
             "rating class. Numbers at full double precision.</p>")


def _assemble(doc: _Doc, d: ReportData) -> str:
    """The page: head, the summary first, then the contents, then the rest."""
    head = (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{_esc(d.title)}</title><style>{_css()}</style></head><body>"
            f"<header><h1>{_esc(d.title)}</h1>")
    sub = _campaign_line(d)
    head += (f"<p class='subtitle'>{_esc(sub)}</p>" if sub else "") + "</header>"
    body = doc.body()
    first, rest = (body.split("</section>", 1) + [""])[:2]
    return head + first + "</section>" + doc.contents() + rest + "</body></html>"


def _qa_line(flags: Sequence[Any] | None) -> str:
    """The count line of `normbox-lab qa`: "N flags: E errors, W warnings"."""
    if flags is None:
        return "No QA data for these runs."
    errors = sum(f.severity == "error" for f in flags)
    return f"{len(flags)} flags: {errors} errors, {len(flags) - errors} warnings"


def _qa_card(flags: Sequence[Any] | None) -> tuple[str, str]:
    if flags is None:
        return "no QA data", "nothing recorded for these runs"
    errors = sum(f.severity == "error" for f in flags)
    if not flags:
        return "none", "every quality gate passed"
    return f"{len(flags)}", f"{errors} errors, {len(flags) - errors} warnings (see Quality flags)"


def _c_text(c: float) -> str | float:
    """The BRDF correction c as printed: "0 (unused)" at zero (paper Eq. 6)."""
    return "0 (unused)" if float(c) == 0.0 else float(c)


def _where(observation: str) -> str:
    key = pf.OBSERVATIONS.get(observation)
    return pf.where(key) if key else "—"


def _corr_label(key: str) -> str:
    metric = "NRMSE" if "nrmse" in key else "RMSE"
    rng = "30–60°" if key.endswith("small") else "65–90°"
    return f"mean radiance vs {metric}, sample angles {rng}"


def _convention_text(c: ComparisonResult, hl: Headline | None) -> str:
    means = (f" Mean ΔE00: {hl.mean_delta_e00:.2f} (paper) and {hl.mean_delta_e00_adapted:.2f} "
             "(adapted)." if hl is not None else "")
    return ("Two colour conventions, both with XYZ (CIE 1931 2°) divided by the Y of the "
            f"reference white patch ({c.patch_names[c.white_patch]}) at "
            f"{c.white_angle_deg:g}° and CIE 2000 with kL = kC = kH = 1. Paper convention "
            "(comparable with the published figures): Lab with the D65 white. Adapted "
            "convention: the colours first adapted from the measured white to D65 (CAT02 von "
            "Kries), as an observer adapted to the box's light would see them. They differ "
            "because the lamp is about 3100 K, not D65: without adaptation every colour sits "
            "on the warm side of Lab, where the same spectral error maps to a different "
            "ΔE00." + means)


def write_report(path: str | Path, data: ReportData) -> Path:
    """Write the self-contained HTML report and return its path."""
    out = Path(path)
    text, _figs, _tabs = build_html(data)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    return out
