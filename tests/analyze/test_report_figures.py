"""The report's figures as a reader sees them: every text of every SVG at least 9 pt at the
report's width (the 1152 px column; a wider figure is scaled down to it), and no two labels,
and no label and legend, overlap.

Text size is read from the SVGs in the HTML (matplotlib writes text as text, its font-size in
the SVG's user units, which are points at the figure's own size).  Overlap is measured on the
same matplotlib figures, drawn with Agg: every text that the renderer actually draws, with its
extent on the canvas, and every legend's box.
"""

from __future__ import annotations

import base64
import re
from typing import Any

import numpy as np
import pytest
from report_fixtures import synthetic_budget, synthetic_report_data

from normbox_lab.analyze.report_style import MIN_FONT_PT, REPORT_COLUMN_PX

#: the page's column at 800 px (`report._CSS`: body padding .75 rem below 900 px)
NARROW_COLUMN_PX = 800.0 - 2 * 12.0
FONT_SIZE = re.compile(r"font-size:\s*([0-9.]+)px")


def svg_text_sizes_pt(html: str, column_px: float = REPORT_COLUMN_PX
                      ) -> dict[str, tuple[float, float]]:
    """figure id → (smallest text size in pt in a column of `column_px` CSS px, the report's
    by default, its size at its own size), from every `<figure>`'s inline SVG."""
    out = {}
    for fid, width_px, b64 in re.findall(
            r'<figure id="([^"]+)">.*?<img[^>]*width="([0-9.]+)"[^>]*base64,([^"]+)"', html,
            re.DOTALL):
        svg = base64.b64decode(b64).decode("utf-8")
        view_w = float(re.search(r'viewBox="0 0 ([0-9.]+) ', svg).group(1))
        sizes = [float(s) for s in FONT_SIZE.findall(svg)]
        if not sizes:
            continue
        # user units → CSS px at the figure's own size, then scaled to fit the column
        shown_px = min(float(width_px), column_px)
        pt_at_width = min(sizes) * (shown_px * 72.0 / 96.0) / view_w
        out[fid] = (pt_at_width, min(sizes))
    return out


def drawn_boxes(fig: Any) -> tuple[list[tuple[str, Any, Any]], list[tuple[Any, Any, Any]]]:
    """(texts, legends) as drawn by Agg: [(text, Bbox, its axes)], [(legend, Bbox, its
    texts)]."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    texts: list[tuple[Any, Any]] = []
    original = Text.draw

    def record(self, renderer):
        # every Text the figure draws, multi-line ones included (the renderer's draw_text
        # gets no Text for a label of two lines: those were not measured)
        original(self, renderer)
        if self.get_visible() and self.get_text().strip():
            texts.append((self, self.get_window_extent(renderer)))

    FigureCanvasAgg(fig)
    Text.draw = record
    try:
        fig.canvas.draw()
    finally:
        Text.draw = original
    renderer = fig.canvas.get_renderer()
    legends = [leg for leg in [*fig.legends, *(ax.get_legend() for ax in fig.axes)]
               if leg is not None and leg.get_visible()]
    legend_boxes = [(leg, leg.get_window_extent(renderer), set(leg.get_texts())) for leg in legends]
    # the axes a text belongs to: found in its artist tree (a polar tick label's `.axes` is
    # not set)
    owner = {id(t): ax for ax in fig.axes for t in ax.findobj(lambda a: hasattr(a, "get_text"))}
    return [(t.get_text(), b, owner.get(id(t))) for t, b in texts], legend_boxes


def _overlap(a: Any, b: Any, tol_px: float = 0.5) -> bool:
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > tol_px
            and min(a.y1, b.y1) - max(a.y0, b.y0) > tol_px)


def overlaps(fig: Any) -> list[str]:
    """Every pair of drawn texts whose boxes intersect, every text that touches a legend box
    it does not belong to, every text that reaches into the plot area of an axes it does not
    belong to (a tick label in the neighbouring panel), and every text cut by the figure's
    edge."""
    texts, legends = drawn_boxes(fig)
    renderer = fig.canvas.get_renderer()
    # the plot area as drawn (a polar half-disc: its wedge, not the square around it)
    areas = [(ax, ax.patch.get_window_extent(renderer)) for ax in fig.axes if ax.get_visible()]
    legend_texts = {t.get_text() for _, _, own in legends for t in own}
    found = []
    for i in range(len(texts)):
        for j in range(i + 1, len(texts)):
            if _overlap(texts[i][1], texts[j][1]):
                found.append(f"{texts[i][0]!r} / {texts[j][0]!r}")
    page = fig.bbox
    for text, b, owner in texts:
        if b.x0 < page.x0 - 0.5 or b.x1 > page.x1 + 0.5 or b.y0 < page.y0 - 0.5 \
                or b.y1 > page.y1 + 0.5:
            found.append(f"{text!r} / outside the figure")
        if text in legend_texts:
            continue
        for ax, area in areas:
            if ax is not owner and _overlap(b, area, tol_px=1.0):
                found.append(f"{text!r} / the plot area of {ax.get_title() or ax.get_label()!r}")
    for leg, box, own in legends:
        own_text = {t.get_text() for t in own}
        title = leg.get_title().get_text()
        for text, b, _owner in texts:
            if text in own_text or text == title:
                continue
            if _overlap(box, b, tol_px=-1.0):     # touching counts
                found.append(f"legend {sorted(own_text)[:2]} / {text!r}")
    return found


@pytest.fixture(scope="module")
def report_figures(tmp_path_factory):
    """The report of the synthetic campaign with every section the fixture feeds, and the
    matplotlib figure behind each of its SVGs."""
    from normbox_lab.analyze import report_style
    from normbox_lab.analyze.report import ImageFigure, ImagePanel, build_html

    data = synthetic_report_data(step_nm=20.0, seed=1)
    data.polar_materials = ["patch08", "patch18", "wall"]
    data.budget = synthetic_budget(data)
    rng = np.random.default_rng(0)
    data.images = [ImageFigure("fig-camera", "Virtual camera (synthetic panels)", "Random.",
                               [ImagePanel("truth", rng.uniform(size=(60, 80, 3))),
                                ImagePanel("ΔE00", rng.uniform(0, 1.2, (60, 80)), 1.0, "ΔE00"),
                                ImagePanel("noise floor", rng.uniform(0, .3, (60, 80)), 1.0,
                                           "ΔE00")])]
    figures: dict[str, Any] = {}
    original = report_style.svg_data_uri

    def keep(fig):
        figures[f"#{len(figures)}"] = fig
        return original(fig)

    report_style.svg_data_uri = keep
    try:
        # every figure drawn here (children=0), in the page's order, so `keep` sees each
        html, fids, _ = build_html(data, children=0)
    finally:
        report_style.svg_data_uri = original
    return html, dict(zip(fids, figures.values(), strict=True))


@pytest.mark.parametrize("column_px", [REPORT_COLUMN_PX, NARROW_COLUMN_PX])
def test_every_figure_text_is_at_least_9_pt_at_the_reports_width(report_figures, column_px):
    """At the report's full width (1152 px column) and in an 800 px window (776 px column):
    the wide figures were 12 in and scaled down to 6 pt at 800 px."""
    html, figs = report_figures
    sizes = svg_text_sizes_pt(html, column_px)
    assert set(sizes) == set(figs) and len(sizes) >= 12
    small = {fid: round(pt, 2) for fid, (pt, _own) in sizes.items() if pt < MIN_FONT_PT - 1e-6}
    assert small == {}, f"text below {MIN_FONT_PT} pt in a {column_px:g} px column: {small}"


def test_no_figure_is_scaled_down_at_800_px(report_figures):
    """At 800 px the page's column is 776 px (body padding 12 px): every figure is at most
    that wide, so the browser shows it at its own size (its text at its own points)."""
    html, _figs = report_figures
    widths = dict(re.findall(r'<figure id="([^"]+)">.*?<img[^>]*width="([0-9.]+)"', html,
                             re.DOTALL))
    assert len(widths) >= 12
    assert {f: float(w) for f, w in widths.items() if float(w) > NARROW_COLUMN_PX} == {}


def test_fig_1s_colour_bar_reaches_the_largest_value():
    """Panels that share a scale (ΔE00 map and noise floor, vmax 1.0) with a value of 1.17:
    the colour bar goes to 1.17, and both panels keep one scale."""
    from normbox_lab.analyze import report_figures as rf
    from normbox_lab.analyze.report import ImageFigure, ImagePanel

    de = np.full((6, 8), 0.4)
    de[2, 3] = 1.17
    f = ImageFigure("fig-1", "t", "c", [ImagePanel("ΔE00", de, 1.0, "ΔE00"),
                                        ImagePanel("noise floor", de / 4, 1.0, "ΔE00")])
    fig = rf.fig_images(f)
    clims = [ax.images[0].get_clim() for ax in fig.axes if ax.images]
    assert clims == [(0.0, 1.17), (0.0, 1.17)]


def test_no_labels_overlap_in_any_figure(report_figures):
    _html, figs = report_figures
    bad = {fid: found[:4] for fid, fig in figs.items() if (found := overlaps(fig))}
    assert bad == {}, bad


def test_the_checks_find_small_and_overlapping_text():
    """The two measurements themselves: a 6 pt label and two labels on one spot are found."""
    from normbox_lab.analyze.report import _Doc
    from normbox_lab.analyze.report_style import new_figure

    fig = new_figure(4.0, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.text(0.5, 0.5, "one label", fontsize=6)
    ax.text(0.52, 0.5, "another label")
    ax.plot([0, 1], [0, 1], label="a line")
    ax.legend(loc="upper left")
    ax.text(0.02, 0.98, "a note the legend covers", transform=ax.transAxes, va="top")
    doc = _Doc()
    doc.section("s", "S")
    doc.figure("fig-bad", "bad", fig, "")
    assert svg_text_sizes_pt(doc.body())["fig-bad"] == (6.0, 6.0)
    found = overlaps(fig)
    assert "'one label' / 'another label'" in found
    assert any(f.startswith("legend") and "a note" in f for f in found), found
    # a figure wider than the column is measured at the column's width
    wide = new_figure(14.0, 2.0, layout=None)
    wide.set_size_inches(16.0, 2.0)
    wide.text(0.5, 0.5, "wide", fontsize=10)
    doc.figure("fig-wide", "wide", wide, "")
    pt, own = svg_text_sizes_pt(doc.body())["fig-wide"]
    assert own == 10.0 and pt == pytest.approx(10.0 * REPORT_COLUMN_PX / (16.0 * 96.0))


def test_a_quick_campaigns_figures_keep_their_labels_inside(report_figures):
    """4 patches × 3 angles (the quick demo): one row of spectra panels and of NSE panels, so
    the figures are short; their y labels (two lines) stay inside the figure, nothing
    overlaps, and the text keeps 9 pt in an 800 px window."""
    from dataclasses import fields, replace

    from normbox_lab.analyze import report_figures as rf
    from normbox_lab.analyze.report_style import svg_data_uri

    c = synthetic_report_data(step_nm=20.0, seed=1).comparison
    patches, angles = np.array([6, 12, 18, 23]), np.array([0, 6, 12])
    sliced = {}
    for f in fields(c):
        v = getattr(c, f.name)
        if isinstance(v, np.ndarray) and f.name not in ("angle_deg", "wavelength_nm"):
            sliced[f.name] = v[patches][:, angles]
    small = replace(c, patch_names=[c.patch_names[p] for p in patches],
                    angle_deg=c.angle_deg[angles], white_patch=2, **sliced)
    for fig in (rf.fig_reference(small), rf.fig_nse(small, 3), rf.fig_prediction(small, [0])):
        assert overlaps(fig) == [], overlaps(fig)
        width_px = fig.get_figwidth() * 96.0
        assert width_px <= NARROW_COLUMN_PX
        svg = base64.b64decode(svg_data_uri(fig)[0].split(",", 1)[1]).decode("utf-8")
        assert min(float(s) for s in FONT_SIZE.findall(svg)) >= MIN_FONT_PT
