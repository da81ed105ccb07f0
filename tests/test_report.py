"""The HTML report: self-contained, every figure and table present, numbers from the data."""

import base64
import re

import numpy as np
from report_fixtures import synthetic_report_data

from normbox_lab.analyze.report import ReportData, build_html, write_report

FIGURES = ["fig-reference", "fig-prediction", "fig-rmse", "fig-nrmse", "fig-deltae", "fig-nse",
           "fig-polar-patch08", "fig-errormodel", "fig-nse-fit"]
TABLES = ["tab-rmse", "tab-nrmse", "tab-correlations", "tab-deltae", "tab-rating", "tab-fits",
          "tab-errormodel", "tab-nse-fit"]


def test_report_is_self_contained_and_complete(tmp_path):
    data = synthetic_report_data(step_nm=20.0, seed=1)
    data.polar_materials = ["patch08"]
    path = write_report(tmp_path / "sub" / "report.html", data)
    assert path.exists()
    text = path.read_text(encoding="utf-8")
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", text)
    assert refs
    for ref in refs:
        assert ref.startswith(("data:image/png;base64,", "#")), ref
    assert "<link" not in text and "<script" not in text and "url(" not in text
    for fid in FIGURES:
        m = re.search(rf'<figure id="{fid}">.*?base64,([^"]+)"', text, re.DOTALL)
        assert m, fid
        assert base64.b64decode(m.group(1))[:8] == b"\x89PNG\r\n\x1a\n"
    for tid in TABLES:
        assert f'id="{tid}"' in text, tid
    # the ΔE00 table carries the comparison's numbers, 24 patch rows
    table = re.search(r'id="tab-deltae">.*?</table>', text, re.DOTALL).group(0)
    assert table.count("<tr>") == 25
    assert f"{data.comparison.delta_e00[3, 4]:.4g}" in table
    fits = re.search(r'id="tab-fits">.*?</table>', text, re.DOTALL).group(0)
    assert f"{data.fits['wall'].alpha:.4g}" in fits


def test_report_with_comparison_only():
    data = synthetic_report_data(step_nm=20.0, seed=2)
    only = ReportData(comparison=data.comparison)
    _html, figs, tabs = build_html(only)
    assert "fig-deltae" in figs and "tab-deltae" in tabs
    assert not any(f.startswith("fig-polar") for f in figs)
    assert "fig-errormodel" not in figs
    assert np.isfinite(data.comparison.delta_e00).all()


def test_image_figures_survive_the_store_and_appear_in_the_report(tmp_path):
    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze.report import ImageFigure, ImagePanel

    rng = np.random.default_rng(2)
    rgb = rng.integers(0, 256, size=(6, 8, 3), dtype=np.uint8)
    de = rng.uniform(0, 3, size=(6, 8))
    fig = ImageFigure("fig-camera", "Truth, prediction, ΔE00", "caption text",
                      [ImagePanel("truth", rgb), ImagePanel("ΔE00", de, vmax=5.0, unit="ΔE00")])
    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("reference-sweep")
        fig.store(store, run_ref=run.id)
        back = ImageFigure.from_artifact(store.artifacts("image-figure", run_ref=run.id)[-1])
    assert back.fid == "fig-camera" and back.caption == "caption text"
    np.testing.assert_allclose(back.panels[0].data * 255.0, rgb, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.panels[1].data, de)
    assert back.panels[1].vmax == 5.0 and back.panels[1].unit == "ΔE00"
    text, figs, _ = build_html(ReportData(images=[back]))
    assert figs == ["fig-camera"]
    m = re.search(r'<figure id="fig-camera">.*?base64,([^"]+)"', text, re.DOTALL)
    assert m and base64.b64decode(m.group(1))[:8] == b"\x89PNG\r\n\x1a\n"
    assert "caption text" in text
