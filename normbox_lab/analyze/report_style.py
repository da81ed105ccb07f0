"""One style for every figure of the HTML report: sizes, fonts, colour-blind-safe palettes,
units, and the encoding of a matplotlib figure as an inline SVG image.

Figures are vector (SVG, text as text) and embedded as ``data:image/svg+xml;base64`` images whose
CSS width is the figure's width at 96 px per inch, so they stay sharp when zoomed or printed.
Raster content (the virtual camera's images) is embedded inside the SVG at its own pixels.

Palettes: lines and bars use Okabe & Ito's eight colours ("Color Universal Design", 2002);
sample angles use viridis (perceptually ordered, readable in grey and with colour-vision
deficiencies); the four rating classes use four colours from the Okabe–Ito set chosen to differ
in lightness too (blue, sky blue, orange, vermillion), so they stay distinct in greyscale.
"""

from __future__ import annotations

import base64
import io
from typing import Any

#: spectral radiance unit, as printed on axes
RADIANCE_UNIT = "W·sr⁻¹·m⁻²·nm⁻¹"
#: Okabe & Ito (2002) colour-universal-design palette
OKABE_ITO = ("#000000", "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00",
             "#CC79A7")
#: one colour per rating class (below JND, just noticeable, side by side, easily perceived):
#: dark blue, sky blue, orange, vermillion — distinct in hue and in lightness
RATING_COLOURS = ("#0072B2", "#56B4E9", "#E69F00", "#D55E00")
#: text colour that reads on each rating colour
RATING_TEXT = ("#ffffff", "#000000", "#000000", "#ffffff")
#: a sequential map for scalar images (ΔE00 maps, weights)
SEQUENTIAL_CMAP = "magma"
#: figure text sizes in points (a figure is shown at its physical size: 1 pt ≈ 1.33 CSS px)
#: nothing smaller than MIN_FONT_PT at the figure's own size (tests/analyze/test_report_figures.py)
FONT_PT = {"base": 10.0, "tick": 9.0, "label": 10.0, "title": 11.0, "legend": 9.0,
           "annotation": 9.0}
MIN_FONT_PT = 9.0
#: the widest figure, inches: 768 px at 96 px per inch fits the column of an 800 px window
#: (776 px), so no browser scales a figure down and its text keeps its points (12 in figures
#: were scaled to 6 pt there)
MAX_WIDTH_IN = 8.0
#: the report's text column in CSS px (body max-width 1200 px less 2 × 1.5 rem padding): the
#: report's width, at which every figure text is at least MIN_FONT_PT
REPORT_COLUMN_PX = 1152.0

_RC = {
    "font.size": FONT_PT["base"],
    "axes.titlesize": FONT_PT["title"],
    "axes.labelsize": FONT_PT["label"],
    "xtick.labelsize": FONT_PT["tick"],
    "ytick.labelsize": FONT_PT["tick"],
    "legend.fontsize": FONT_PT["legend"],
    "figure.titlesize": FONT_PT["title"],
    "axes.prop_cycle": None,          # set in `rc()` (needs matplotlib's cycler)
    "axes.grid": True,
    "grid.color": "#dddddd",
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "svg.fonttype": "none",           # text stays text: small, selectable, crisp
    "svg.hashsalt": "normbox-report",  # deterministic ids
    "image.interpolation": "none",    # images embedded at their own pixels
}


def rc() -> dict[str, Any]:
    """The matplotlib rcParams of the report style (use with `matplotlib.rc_context`)."""
    from cycler import cycler

    out = dict(_RC)
    out["axes.prop_cycle"] = cycler(color=list(OKABE_ITO[1:]) + [OKABE_ITO[0]])
    return out


def new_figure(width_in: float, height_in: float, layout: str | None = "constrained") -> Any:
    """A matplotlib Figure (no pyplot state) in the report style; constrained layout (default)
    so labels never overlap or fall off the edge; `layout=None` for big grids of small panels
    (placed by hand: constrained layout is slow there)."""
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context(rc()):
        return Figure(figsize=(min(float(width_in), MAX_WIDTH_IN), float(height_in)),
                      layout=layout)


def angle_colours(n: int) -> list[Any]:
    """n colours along viridis (first angle dark, last light)."""
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(0.9 * k / max(n - 1, 1)) for k in range(n)]


def svg_data_uri(fig: Any) -> tuple[str, float, float]:
    """(data URI of the figure as SVG, width px, height px at 96 px per inch)."""
    import matplotlib

    buf = io.BytesIO()
    with matplotlib.rc_context(rc()):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    w_in, h_in = fig.get_size_inches()
    uri = "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
    return uri, float(w_in) * 96.0, float(h_in) * 96.0


def svg_job(payload: tuple[Any, dict[str, Any]]) -> str:
    """``(figure, numpy print options)`` → the figure's SVG data URI (`svg_data_uri`): the
    `offload` job of the report's figures.  The SVG's clip-path ids hash the clip boxes'
    text, which numpy's print options shape (colour-science sets ``legacy="1.13"`` when it is
    imported): a child draws under the options of the process that made the figure, so the
    bytes are the ones that process would write."""
    import numpy as np

    fig, print_options = payload
    with np.printoptions(**print_options):
        return svg_data_uri(fig)[0]
