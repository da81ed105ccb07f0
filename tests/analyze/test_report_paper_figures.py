"""Every quotation of the paper's figures, read against the one table of them
(`normbox_lab.analyze.paper_figures`): the table itself, the budget's paper magnitudes, the
paper-scenario rows of the budget and the report, the report's figures of the paper (sign,
patches), and the docs (every table with a "paper" column, and every paragraph that quotes a
figure of the paper)."""

from __future__ import annotations

import base64
import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from report_fixtures import synthetic_report_data

from normbox_lab.analyze import paper_figures as pf

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
NUMBER = re.compile(r"[−-]?\d+(?:\.\d+)?")

#: misquotes once printed; none may come back, anywhere in the docs or the report's code
MISQUOTES = ("mostly < 1", "Left: the paper's convention", "Left: paper")
#: a paragraph that mentions the paper and one of these quotes that figure: it must carry the
#: table's quote verbatim
FINGERPRINTS = {
    r"\b0\.84\b": "r_radiance_rmse",
    r"\b10, 13, 19,? (?:and )?24\b": "delta_e00",
    r"patch 18 (?:≈ |of )?18 ?%": "fit_errors",
    r"\b5–10 %": "fit_errors",
}


def _numbers(text: str) -> set[float]:
    text = re.sub(r"Figs?\. \d+(?:\(\w\))?(?:/\d+)?", "", text)       # figure numbers
    text = re.sub(r"Sec\. [\d.]+", "", text)
    return {float(n.replace("−", "-")) for n in NUMBER.findall(text)}


def test_every_entry_says_where_its_unit_and_sign_and_quotes_only_its_numbers():
    assert len(pf.PAPER_FIGURES) >= 25
    for key, e in pf.PAPER_FIGURES.items():
        assert e.key == key
        assert re.fullmatch(r"Sec\. \d(\.\d)*(, (Sec\. \d(\.\d)*|Figs?\. [\d(a-c)/]+))*",
                            e.where), (key, e.where)
        assert e.sign and e.says and e.quote, key
        assert e.unit in {"%", "ΔE00", "ΔE76", "°", "nm", "mm", "Pearson r", ""}, key
        # every number the quote prints is one the paper gives for this entry
        assert _numbers(e.quote) <= set(map(float, e.values)) | {0.0}, (key, e.quote)
    assert pf.cite("r_radiance_rmse") == "0.84 / 0.62 (Sec. 6.1, Fig. 5(b)/(c))"
    # the paper's NSE is (reference − predicted)/reference; ours the negative
    assert pf.PAPER_FIGURES["fig13_patch"].sign == pf.NSE_PAPER_SIGN
    assert pf.NSE_PAPER_SIGN == "(reference − prediction)/reference"
    np.testing.assert_array_equal(pf.nse_paper_sign(np.array([0.1, -0.2])), [-0.1, 0.2])
    assert [pf.signed(v, 2) for v in (-0.354, 0.354, 0.0, -0.001)] == [
        "−0.35", "+0.35", "0.00", "0.00"]


def test_the_budgets_paper_magnitudes_are_the_tables():
    """`core.error_sources.PAPER_FIGURES` (what `budget` assumes without a spec) against the
    table: fractions against percent, SNR, degrees, millimetres."""
    from normbox_lab.core.error_sources import PAPER_FIGURES as SPEC

    spec = dict(item.split("=") for item in SPEC.split(","))
    for name, text in spec.items():
        key = pf.SOURCES[name]
        e = pf.PAPER_FIGURES[key]
        paper = e.values[0] / (100.0 if e.unit == "%" else 1.0)
        assert float(text) == pytest.approx(paper), (name, text, e.quote)


@pytest.fixture(scope="module")
def stored_campaign(tmp_path_factory):
    from normbox_lab.acquire.store import Store

    data = synthetic_report_data(step_nm=20.0, seed=1)
    store = Store(tmp_path_factory.mktemp("paper") / "s.sqlite")
    run = store.create_run("reference-sweep", status="done")
    data.comparison.store(store, f"ref-run-{run.id}", run_ref=run.id)
    for k in range(1, 25):
        dataclasses.replace(data.fits[f"patch{k:02d}"], name=f"p{k:02d}").store(store)
    dataclasses.replace(data.fits["wall"], name="wall").store(store)
    yield data, store, run.id
    store.close()


def test_the_paper_column_of_the_budget_and_the_report_reads_the_table(stored_campaign):
    from normbox_lab.analyze.budget_store import paper_observations
    from normbox_lab.analyze.report import ReportData, build_html

    data, store, run = stored_campaign
    rows = paper_observations(store, run)
    assert len(rows) >= 6
    for label, paper, ours in rows:
        assert paper == pf.quote(pf.OBSERVATIONS[label]), label
        assert "-" not in re.sub(r"[A-Za-z]-[A-Za-z]", "", ours), (label, ours)   # U+2212
    by = {label: ours for label, _, ours in rows}
    de = data.comparison.delta_e00
    assert by["ΔE00"].startswith(f"{100 * np.mean(de < 2):.0f} % < 2 (")
    html, _, tabs = build_html(ReportData(paper=rows))
    assert "tab-paper" in tabs
    table = html[html.index('id="tab-paper"'):]
    table = table[:table.index("</table>")]
    for label, _paper, _ours in rows:
        e = pf.PAPER_FIGURES[pf.OBSERVATIONS[label]]
        assert (f'<td class="text">{_html(e.quote)}</td><td class="text">{e.where}</td>'
                in table), label


def _html(text: str) -> str:
    import html

    return html.escape(text)


def test_the_reports_figures_of_the_paper_use_its_sign_and_patches():
    """Fig. 13 and Fig. 14 plot (reference − prediction)/reference; Fig. 14(b) is patch 21
    (not a mean over the patches); the NSE panel patch is the paper's 22."""
    from normbox_lab.analyze import report_figures as rf
    from normbox_lab.analyze.report import ReportData

    d = synthetic_report_data(step_nm=20.0, seed=1)
    c = d.comparison
    assert (d.nse_patch, d.nse_fit_patch_b) == (21, 20)
    assert tuple(d.nse_fit_patches) == (18, 22, 23)
    fig = rf.fig_nse(c, d.nse_patch)
    line = fig.axes[0].get_lines()[-1]
    np.testing.assert_allclose(line.get_ydata(), -100.0 * c.nse[21, 0])
    assert pf.NSE_PAPER_SIGN in fig.get_children()[-1].get_text() or any(
        pf.NSE_PAPER_SIGN in t.get_text() for t in fig.texts)
    got = rf.fig_nse_fit(c, ReportData(**{f.name: getattr(d, f.name)
                                          for f in dataclasses.fields(d)}))
    fig14, rows = got
    (ax_a, ax_b), _ = fig14.axes[:2], fig14.axes[2:]
    np.testing.assert_allclose(ax_b.get_lines()[0].get_ydata(), -100.0 * c.nse[20, -1])
    assert "patch 21" in ax_b.get_title()
    np.testing.assert_allclose(ax_a.get_lines()[0].get_ydata(), -100.0 * c.nse[18, 0])
    assert rows[-1][0] == c.patch_names[20]


def test_fig_7_colours_every_cell_by_its_printed_value():
    """Cells that print 1.00 are below the JND in colour and text; 1.01 is just noticeable."""
    from normbox_lab.analyze import report_figures as rf
    from normbox_lab.analyze.compare import rating_index
    from normbox_lab.analyze.report_style import RATING_TEXT

    c = synthetic_report_data(step_nm=20.0, seed=1).comparison
    de = c.delta_e00.copy()
    de[0, :4] = [0.994, 1.0, 1.004, 1.006]
    de[1, :3] = [1.996, 2.004, 5.2]
    c = dataclasses.replace(c, delta_e00=de)
    fig = rf.fig_deltae(c, de + 0.5)
    for ax in fig.axes[:2]:
        classes = np.asarray(ax.images[0].get_array())
        for t in ax.texts:
            x, y = (round(v) for v in t.get_position())
            k = int(rating_index(float(t.get_text())))
            assert classes[y, x] == k, (t.get_text(), classes[y, x])
            assert t.get_color() == RATING_TEXT[k]
    top = {(round(t.get_position()[1]), round(t.get_position()[0])): t.get_text()
           for t in fig.axes[0].texts}
    assert [top[(0, a)] for a in range(4)] == ["0.99", "1.00", "1.00", "1.01"]
    assert np.asarray(fig.axes[0].images[0].get_array())[0, :4].tolist() == [0, 0, 0, 1]


def _paragraphs(path: Path) -> list[str]:
    return [" ".join(p.split()) for p in re.split(r"\n\s*\n", path.read_text("utf-8"))]


def _cells(row: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]]


def _tables(path: Path) -> list[tuple[list[str], list[list[str]]]]:
    lines = path.read_text("utf-8").splitlines()
    out = []
    for i in range(len(lines) - 1):
        if lines[i].startswith("|") and re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", lines[i + 1]):
            body = []
            for row in lines[i + 2:]:
                if not row.startswith("|"):
                    break
                body.append(_cells(row))
            out.append((_cells(lines[i]), body))
    return out


def test_the_docs_quote_the_table():
    checked = 0
    for path in DOCS:
        text = path.read_text("utf-8")
        for bad in MISQUOTES:
            assert bad not in text, (path.name, bad)
        for header, body in _tables(path):
            cols = [j for j, h in enumerate(header) if h.lower().startswith("paper")]
            for j in cols:
                for row in body:
                    if row[j] in ("—", ""):          # the paper gives nothing for this row
                        continue
                    name = row[0].strip("`")
                    key = pf.OBSERVATIONS.get(name) or pf.SOURCES.get(name)
                    assert key, f"{path.name}: a paper quotation of an unknown row {name!r}"
                    e = pf.PAPER_FIGURES[key]
                    assert row[j] == e.quote or row[j].startswith(e.quote + " ("), (
                        path.name, name, row[j], e.quote)
                    checked += 1
        for para in _paragraphs(path):
            if "paper" not in para.lower():
                continue
            for pattern, key in FINGERPRINTS.items():
                if re.search(pattern, para):
                    assert pf.quote(key) in para, (path.name, pf.quote(key), para[:300])
                    checked += 1
    assert checked >= 20


def test_the_reports_code_carries_no_misquote():
    for path in sorted((ROOT / "normbox_lab" / "analyze").glob("report*.py")) + sorted(
            (ROOT / "normbox_lab" / "analyze").glob("budget*.py")):
        text = path.read_text("utf-8")
        for bad in MISQUOTES:
            assert bad not in text, (path.name, bad)
        # the paper's NSE sign is never printed the other way round
        assert "NSE (prediction − reference)" not in text, path.name


def test_the_report_html_names_the_papers_figures_from_the_table(stored_campaign):
    from normbox_lab.analyze.budget_store import paper_observations
    from normbox_lab.analyze.report import build_html

    data, store, run = stored_campaign
    data = dataclasses.replace(data, polar_materials=["patch08"],
                               paper=paper_observations(store, run))
    html, _, _ = build_html(data)
    assert _html("Top: the paper's convention; bottom: adapted") in html
    assert _html(f"in the paper's sign, {pf.NSE_PAPER_SIGN}") in html
    assert _html(pf.cite("fit_weight_w")) in html
    m = re.search(r'<figure id="fig-nse">.*?base64,([^"]+)"', html, re.DOTALL)
    assert "(reference − prediction)/reference" in base64.b64decode(m.group(1)).decode()
    # the page's text: every negative number with the typographic minus (U+2212)
    text = re.sub(r"<[^>]+>", " ", re.sub(r"<style>.*?</style>|data:[^\"']+", "", html,
                                          flags=re.DOTALL))
    assert re.findall(r"(?<![\w-])-\d[^ ]*", text) == []
    assert re.search(r"−\d", text)            # there are negative numbers to check
    # and the figures' texts (matplotlib's own tick labels carry U+2212; titles ours)
    svg_texts = [t for b64 in re.findall(r"data:image/svg\+xml;base64,([^\"']+)", html)
                 for t in re.findall(r"<text[^>]*>([^<]*)</text>",
                                     base64.b64decode(b64).decode("utf-8"))]
    assert len(svg_texts) > 500
    assert [t for t in svg_texts if re.search(r"(?<![\w-])-\d", t)] == []
