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
from report_fixtures import synthetic_report_data

from normbox_lab.analyze.report_style import MIN_FONT_PT, REPORT_COLUMN_PX

FONT_SIZE = re.compile(r"font-size:\s*([0-9.]+)px")


def svg_text_sizes_pt(html: str) -> dict[str, tuple[float, float]]:
    """figure id → (smallest text size in pt at the report's width, its size at its own
    size), from every `<figure>`'s inline SVG."""
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
        shown_px = min(float(width_px), REPORT_COLUMN_PX)
        pt_at_width = min(sizes) * (shown_px * 72.0 / 96.0) / view_w
        out[fid] = (pt_at_width, min(sizes))
    return out


def drawn_boxes(fig: Any) -> tuple[list[tuple[str, Any]], list[tuple[str, Any, Any]]]:
    """(texts, legends) as drawn by Agg: [(text, Bbox)], [(legend, Bbox, its texts)]."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg

    texts: list[tuple[Any, Any]] = []
    original = RendererAgg.draw_text

    def record(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
        if mtext is not None and s.strip():
            texts.append((mtext, mtext.get_window_extent(self)))
        return original(self, gc, x, y, s, prop, angle, ismath, mtext)

    FigureCanvasAgg(fig)
    RendererAgg.draw_text = record
    try:
        fig.canvas.draw()
    finally:
        RendererAgg.draw_text = original
    renderer = fig.canvas.get_renderer()
    legends = [leg for leg in [*fig.legends, *(ax.get_legend() for ax in fig.axes)]
               if leg is not None and leg.get_visible()]
    legend_boxes = [(leg, leg.get_window_extent(renderer), set(leg.get_texts())) for leg in legends]
    return [(t.get_text(), b) for t, b in texts], legend_boxes


def _overlap(a: Any, b: Any, tol_px: float = 0.5) -> bool:
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > tol_px
            and min(a.y1, b.y1) - max(a.y0, b.y0) > tol_px)


def overlaps(fig: Any) -> list[str]:
    """Every pair of drawn texts whose boxes intersect, and every text that touches a legend
    box it does not belong to."""
    texts, legends = drawn_boxes(fig)
    found = []
    for i in range(len(texts)):
        for j in range(i + 1, len(texts)):
            if _overlap(texts[i][1], texts[j][1]):
                found.append(f"{texts[i][0]!r} / {texts[j][0]!r}")
    for leg, box, own in legends:
        own_text = {t.get_text() for t in own}
        title = leg.get_title().get_text()
        for text, b in texts:
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
        html, fids, _ = build_html(data)
    finally:
        report_style.svg_data_uri = original
    return html, dict(zip(fids, figures.values(), strict=True))


def test_every_figure_text_is_at_least_9_pt_at_the_reports_width(report_figures):
    html, figs = report_figures
    sizes = svg_text_sizes_pt(html)
    assert set(sizes) == set(figs) and len(sizes) >= 12
    small = {fid: round(pt, 2) for fid, (pt, _own) in sizes.items() if pt < MIN_FONT_PT - 1e-6}
    assert small == {}, f"text below {MIN_FONT_PT} pt at the report's width: {small}"


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
    assert svg_text_sizes_pt("".join(doc.parts))["fig-bad"] == (6.0, 6.0)
    found = overlaps(fig)
    assert "'one label' / 'another label'" in found
    assert any(f.startswith("legend") and "a note" in f for f in found), found
    # a figure wider than the column is measured at the column's width
    wide = new_figure(14.0, 2.0, layout=None)
    wide.set_size_inches(16.0, 2.0)
    wide.text(0.5, 0.5, "wide", fontsize=10)
    doc.figure("fig-wide", "wide", wide, "")
    pt, own = svg_text_sizes_pt("".join(doc.parts))["fig-wide"]
    assert own == 10.0 and pt == pytest.approx(10.0 * REPORT_COLUMN_PX / (16.0 * 96.0))
