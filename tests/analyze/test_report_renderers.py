"""The report's renderer rows, the paper column, the simulated verdict and its number format."""

from __future__ import annotations

import re

import numpy as np
from report_fixtures import synthetic_report_data

from normbox_lab.analyze.report import build_html, fmt_number
from normbox_lab.analyze.report_renderers import RendererRow, RenderingError


def test_one_number_format():
    assert [fmt_number(v) for v in (1, 1.6, 2.02e-5, 0.0747, 1.0004, 0.99949, 123456.0, 0.18,
                                    0.9996)] == [
        "1.00", "1.60", "2.02×10⁻⁵", "0.0747", "1.00", "0.999", "1.23×10⁵", "0.180", "1.00"]
    assert fmt_number(float("nan")) == "—"
    # negative numbers with the typographic minus, never the ASCII hyphen
    assert [fmt_number(v) for v in (-0.0971, -2.02e-5)] == ["\u22120.0971", "\u22122.02×10⁻⁵"]


def test_renderer_rows_paper_column_and_simulated_verdict():
    d = synthetic_report_data()
    c = d.comparison
    n_a = c.angle_deg.size
    d.simulated = True
    d.runs = [{"id": 2, "protocol": "reference-sweep", "readings": "312/312",
               "date": "2026-11-25"}]
    d.renderers = [RendererRow("normbox-lab", "normbox-lab 0.1 (default)", 0.41, 1.9,
                               [3.0] * n_a, [300, 10, 2, 0], 1),
                   RendererRow("mitsuba-rgb", "mitsuba 3.9.1 llvm_ad_rgb", 1.34, 2.71,
                               [39.7] * n_a, [150, 100, 62, 0], 2)]
    de = np.full(c.delta_e00.shape, 0.5)
    de[0, 0] = 1.0004                 # printed "1.00": rated like 1.0, below the JND
    d.rendering_errors = [RenderingError("normbox-lab", "mitsuba-rgb", list(c.patch_names),
                                         c.angle_deg, de, {"normbox-lab": de, "mitsuba-rgb": de})]
    d.paper = [("r(radiance, RMSE) 30–60° / 65–90°", "0.84 / 0.62", "0.80 / 0.55")]
    html, _figs, tabs = build_html(d)
    verdict = re.search(r"<p class='verdict'>(.*?)</p>", html).group(1)
    assert verdict.startswith("Simulated campaign"), verdict
    assert "tab-renderers" in tabs and "tab-paper" in tabs and "tab-rgb-mitsuba-rgb" in tabs
    table = html[html.index('id="tab-renderers"'):]
    table = table[:table.index("</table>")]
    assert table.count("<tr>") == 3           # header + one row per renderer
    assert "<th>mitsuba-rgb</th><td class=\"text\">mitsuba 3.9.1 llvm_ad_rgb</td>" \
        "<td class=\"num\">1.34</td>" \
        in table
    # the paper table: every cell reads from the left, the paper's place beside its figure
    assert ('<td class="text">0.84 / 0.62</td><td class="text">Sec. 6.1, Fig. 5(b)/(c)</td>'
            '<td class="text">0.80 / 0.55</td>') in html
    rgb = html[html.index('id="tab-rgb-mitsuba-rgb"'):]
    assert '<td class="r0 num">1.00</td>' in rgb
    assert html.count("Campaign") == 1        # the campaign line once (the page's subtitle)
    assert "e-0" not in re.sub(r"data:[^\"']+", "", html)    # no "2.02e-05" anywhere
