"""The HTML report: self-contained, every figure and table present, numbers from the data, the
summary first, both colour conventions, the data appendix."""

import base64
import re

import numpy as np
import pytest
from report_fixtures import synthetic_report_data

from normbox_lab.analyze.report import ReportData, build_html, fmt_number, write_report

FIGURES = ["fig-reference", "fig-prediction", "fig-rmse", "fig-nrmse", "fig-deltae", "fig-nse",
           "fig-polar-patch08", "fig-errormodel", "fig-nse-fit"]
TABLES = ["tab-rmse", "tab-nrmse", "tab-correlations", "tab-deltae", "tab-rating", "tab-fits",
          "tab-errormodel", "tab-nse-fit"]


@pytest.fixture(scope="module")
def full_report(tmp_path_factory):
    """One complete report (figure building dominates the run time: build it once)."""
    data = synthetic_report_data(step_nm=20.0, seed=1)
    data.polar_materials = ["patch08"]
    path = write_report(tmp_path_factory.mktemp("report") / "sub" / "report.html", data)
    return data, path


@pytest.fixture(scope="module")
def comparison_report():
    """A report of a comparison alone: (comparison, html, figure ids, table ids)."""
    c = synthetic_report_data(step_nm=20.0, seed=2).comparison
    text, figs, tabs = build_html(ReportData(comparison=c))
    return c, text, figs, tabs


def test_report_is_self_contained_and_complete(full_report):
    data, path = full_report
    assert path.exists()
    text = path.read_text(encoding="utf-8")
    refs = re.findall(r"""(?:src|href)\s*=\s*["']([^"']*)["']""", text)
    assert refs
    for ref in refs:
        assert ref.startswith(("data:image/svg+xml;base64,", "data:text/csv;base64,", "#")), ref
    assert "<link" not in text and "<script" not in text and "url(" not in text
    for fid in FIGURES:
        m = re.search(rf'<figure id="{fid}">.*?base64,([^"]+)"', text, re.DOTALL)
        assert m, fid
        svg = base64.b64decode(m.group(1))
        assert svg.startswith(b"<?xml") and b"<svg" in svg, fid
    for tid in TABLES:
        assert f'id="{tid}"' in text, tid
    # the ΔE00 table carries the comparison's numbers, 24 patch rows
    table = re.search(r'id="tab-deltae">.*?</table>', text, re.DOTALL).group(0)
    assert table.count("<tr>") == 25
    assert f">{fmt_number(data.comparison.delta_e00[3, 4])}<" in table
    fits = re.search(r'id="tab-fits">.*?</table>', text, re.DOTALL).group(0)
    assert f">{fmt_number(data.fits['wall'].alpha)}<" in fits


def test_report_with_comparison_only(comparison_report):
    c, _html, figs, tabs = comparison_report
    assert "fig-deltae" in figs and "tab-deltae" in tabs
    assert not any(f.startswith("fig-polar") for f in figs)
    assert "fig-errormodel" not in figs
    assert np.isfinite(c.delta_e00).all()


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
    # the image panels are embedded inside the SVG at their own pixels
    svg = base64.b64decode(m.group(1))
    assert b"<svg" in svg and b"data:image/png;base64," in svg
    assert "caption text" in text


def _section(text: str, sid: str) -> str:
    return re.search(rf'<section id="{sid}">.*?</section>', text, re.DOTALL).group(0)


def test_summary_comes_first_with_the_headline_numbers(comparison_report):
    from normbox_lab.analyze.report import delta_e00_adapted

    c, text, _figs, tabs = comparison_report
    body = text[text.index("<body>"):]
    # the summary is the first section, before the contents
    assert body.index('<section id="summary">') < body.index("<nav id='contents'>")
    assert body.index("<nav id='contents'>") < body.index('<section id="qa">')
    summary = _section(text, "summary")
    adapted = delta_e00_adapted(c)
    assert f"{c.delta_e00[18, 0]:.2f}" in summary                     # white at 30°
    assert f"adapted convention: {adapted[18, 0]:.2f}" in summary
    assert f"{np.nanmean(c.delta_e00):.2f}" in summary
    assert f"adapted convention: {np.nanmean(adapted):.2f}" in summary
    assert f"{100 * np.nanmean(c.nrmse):.1f} %" in summary
    # the largest ΔE00 of each convention, each with its own patch and angle (the card showed
    # the paper convention's maximum beside the adapted mean before)
    pa, aa = np.unravel_index(np.nanargmax(adapted), adapted.shape)
    pp, ap = np.unravel_index(np.nanargmax(c.delta_e00), c.delta_e00.shape)
    assert (f"patch {c.patch_names[pp]} at {c.angle_deg[ap]:g}°; adapted convention: "
            f"{np.nanmax(adapted):.2f} (patch {c.patch_names[pa]} at {c.angle_deg[aa]:g}°)"
            in summary)
    assert f"<div class='v'>{np.nanmax(c.delta_e00):.2f}</div>" in summary
    # NRMSE by angle in percent, the worst configuration, the rating counts
    nrmse_row = re.search(r'id="tab-nrmse-angle">.*?</table>', summary, re.DOTALL).group(0)
    for a in range(c.angle_deg.size):
        assert f">{fmt_number(100 * np.nanmean(c.nrmse[:, a]))}<" in nrmse_row
    p, a = np.unravel_index(np.nanargmax(c.delta_e00), c.delta_e00.shape)
    worst = re.search(r'id="tab-worst">.*?</table>', summary, re.DOTALL).group(0)
    assert re.search(rf"<th>{c.patch_names[p]}</th><td>{c.angle_deg[a]:g}°</td>"
                     rf'<td class="r\d num">{re.escape(fmt_number(c.delta_e00[p, a]))}</td>', worst)
    counts = c.rating_counts()
    assert f"{counts['below JND']}" in summary
    assert "tab-nrmse-angle" in tabs and "tab-worst" in tabs
    # the contents speak in titles, not ids
    nav = re.search(r"<nav id='contents'>.*?</nav>", text, re.DOTALL).group(0)
    for label in re.findall(r"<a href='#[^']+'>([^<]+)</a>", nav):
        assert not re.fullmatch(r"(fig|tab)-[a-z0-9-]+", label), label
    # no "inf" or "nan" anywhere in a table cell
    for cell in re.findall(r"<t[dh][^>]*>([^<]*)</t[dh]>", text):
        assert cell.strip().lower() not in ("inf", "nan", "-inf"), cell
    # a report without flags says so
    assert "No quality flags" in _section(text, "qa")


def test_adapted_convention_is_cat02_to_d65_and_differs_from_the_paper_one(comparison_report):
    import colour

    from normbox_lab.analyze.compare import spectra_to_XYZ
    from normbox_lab.analyze.report import delta_e00_adapted

    c = comparison_report[0]
    got = delta_e00_adapted(c)
    # independent recomputation through colour-science's generic adaptation entry point
    xyz_r = spectra_to_XYZ(c.reference, c.wavelength_nm)
    xyz_p = spectra_to_XYZ(c.prediction, c.wavelength_nm)
    yw = xyz_r[18, 0, 1]
    white = xyz_r[18, 0] / yw
    d65_xy = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    d65 = colour.xy_to_XYZ(d65_xy)

    def lab(x):
        a = colour.chromatic_adaptation(x / yw, white, d65, method="Von Kries", transform="CAT02")
        return colour.XYZ_to_Lab(a, d65_xy)

    expect = colour.delta_E(lab(xyz_r), lab(xyz_p), method="CIE 2000")
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-10)
    # the measured white lands on the D65 white: L* = 100, a* = b* = 0
    np.testing.assert_allclose(lab(xyz_r[18, 0]), [100.0, 0.0, 0.0], atol=1e-9)
    # under the warm lamp the conventions disagree
    assert np.max(np.abs(got - c.delta_e00)) > 1e-3


def test_data_appendix_csv_carries_every_configuration_at_full_precision(comparison_report):
    import csv
    import io

    from normbox_lab.analyze.report import delta_e00_adapted

    c, text, _f, _t = comparison_report
    m = re.search(r"<a download='normbox-metrics.csv' href='data:text/csv;base64,([^']+)'", text)
    assert m
    rows = list(csv.DictReader(io.StringIO(base64.b64decode(m.group(1)).decode("utf-8"))))
    assert len(rows) == len(c.patch_names) * c.angle_deg.size
    adapted = delta_e00_adapted(c)
    for row in rows:
        p = c.patch_names.index(row["patch"])
        a = int(np.flatnonzero(np.isclose(c.angle_deg, float(row["angle_deg"])))[0])
        assert float(row["delta_e00_paper"]) == c.delta_e00[p, a]
        assert float(row["delta_e00_adapted"]) == adapted[p, a]
        assert float(row["rmse_W_sr_m2_nm"]) == c.rmse[p, a]
        assert float(row["nrmse_pct"]) == 100.0 * c.nrmse[p, a]


def test_quality_flags_are_listed_with_their_severity():
    from normbox_lab.analyze.qa import Flag

    flags = [Flag(1, 1, None, "fit p07", "fit-error", "warning", 6.1, 5.0, "fit error high"),
             Flag(2, 3, None, "a30/p07", "saturation", "error", 1.02, 1.0, "detector saturated")]
    text, _f, tabs = build_html(ReportData(flags=flags))
    qa = _section(text, "qa")
    assert "tab-qa" in tabs
    rows = re.findall(r"<tr>(.*?)</tr>", qa)
    assert rows[1].startswith('<th class="sev-error">error</th><td>3</td><td>a30/p07</td>')
    assert "detector saturated" in rows[1] and "fit error high" in rows[2]
    summary = _section(text, "summary")
    assert '<p class="qa-summary">2 flags: 1 errors, 1 warnings</p>' in summary
    assert "No QA data" not in qa
    text, _f, _t = build_html(ReportData(flags=[]))
    assert "No quality flags" in _section(text, "qa")
    text, _f, _t = build_html(ReportData(flags=None))
    assert "No QA data" in _section(text, "qa")


def test_report_store_reads_campaign_instruments_and_flags(tmp_path):
    """report_store: campaign rows, instruments, software versions and flags from the store."""
    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze.report_store import (
        campaign_instruments,
        campaign_runs,
        quality_flags,
        software_versions,
    )

    with Store(tmp_path / "s.sqlite") as store:
        run = store.create_run("reference-sweep", seeds={"noise": 7}, planned=312)
        store.add_instrument(run.id, "radiometer",
                             {"model": "CS-1000A", "serial_number": "", "port": "sim://cs1000a"},
                             {"date": "2026-11-01", "lamp": "NIST-traceable"})
        rows = campaign_runs(store, [run.id])
        inst = campaign_instruments(store, [run.id])
        flags = quality_flags(store, [run.id])
    assert rows[0]["protocol"] == "reference-sweep" and rows[0]["seeds"] == "noise=7"
    assert rows[0]["readings"] == "0/312" and rows[0]["date"][:2] == "20"
    assert inst[0]["model"] == "CS-1000A (emulated)"
    assert inst[0]["serial"] == "not reported by the device"
    assert inst[0]["calibration"] == "date: 2026-11-01; lamp: NIST-traceable"
    assert software_versions()["numpy"] == np.__version__
    assert flags == []
