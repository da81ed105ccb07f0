"""The HTML report read in a real browser (headless Chromium) at 1400 and 800 px: every figure
decodes, nothing overflows horizontally, no table needs a scroll bar (every table fits 800 px),
body text is at least 12 px, and each section is photographed at both widths.

The report is the synthetic campaign's (tests/report_fixtures.py) unless NORMBOX_REPORT_HTML
names one (e.g. the demo's `demo-out/report.html`); screenshots go to NORMBOX_SCREENSHOT_DIR
(default: the test's temporary directory).  The report itself carries no script: the test
checks a copy with one measuring script added, and reads the result from the DOM that
Chromium dumps.  Chromium is Debian's `chromium` (`make setup` installs it when run as root).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

WIDTHS_PX = (1400, 800)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--virtual-time-budget=10000"]

# measures the page after load and writes the result into <body data-check="...">
CHECK_JS = """
window.addEventListener('load', () => {
  const W = window.innerWidth;
  const imgs = [...document.images];
  const broken = imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt);
  // a figure the browser shows narrower than its own width: its text below its points
  const scaled = imgs.filter(i => i.getAttribute('width')
      && i.getBoundingClientRect().width < parseFloat(i.getAttribute('width')) - 1)
    .map(i => i.alt.slice(0, 40) + ' ' + Math.round(i.getBoundingClientRect().width) + '/'
         + i.getAttribute('width'));
  const sticking = [];
  for (const el of document.body.querySelectorAll('*')) {
    if (el.closest('.scroll') && !el.classList.contains('scroll')) continue;
    const r = el.getBoundingClientRect();
    if (r.width > 0 && r.right > W + 0.5) sticking.push(el.tagName + '#' + (el.id || ''));
  }
  const scrolling = [...document.querySelectorAll('.scroll')]
    .filter(s => s.scrollWidth > s.clientWidth + 1)
    .map(s => s.parentElement.id);
  let minFont = 1e9, minWhere = '';
  for (const el of document.body.querySelectorAll('*')) {
    const own = [...el.childNodes].some(n => n.nodeType === 3 && n.textContent.trim());
    if (!own) continue;
    const fs = parseFloat(getComputedStyle(el).fontSize);
    if (fs < minFont) { minFont = fs; minWhere = el.tagName + ':' + el.textContent.slice(0, 30); }
  }
  const sections = [...document.querySelectorAll('section')].map(s => {
    const r = s.getBoundingClientRect();
    return {id: s.id, height: r.height};
  });
  document.body.setAttribute('data-check', JSON.stringify({
    width: W, scrollWidth: document.documentElement.scrollWidth, images: imgs.length,
    broken, scaled, sticking: sticking.slice(0, 10), scrolling, minFont, minWhere,
    sections}));
});
"""


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("headless Chromium not installed (Debian: apt-get install chromium; "
                "`make setup` installs it when run as root)")


def _run(browser: str, profile: Path, *args: str) -> subprocess.CompletedProcess[str]:
    profile.mkdir(parents=True, exist_ok=True)
    return subprocess.run([browser, *FLAGS, f"--user-data-dir={profile}", *args],
                          capture_output=True, text=True, timeout=180, check=False)


@pytest.fixture(scope="module")
def report_html(tmp_path_factory) -> Path:
    given = os.environ.get("NORMBOX_REPORT_HTML")
    if given:
        return Path(given)
    from report_fixtures import synthetic_budget, synthetic_report_data

    from normbox_lab.analyze.report import ImageFigure, ImagePanel, write_report
    from normbox_lab.analyze.report_renderers import RendererRow
    from normbox_lab.core.spectral import patch_name

    data = synthetic_report_data(step_nm=20.0, seed=1)
    data.polar_materials = ["patch08"]
    data.budget = synthetic_budget(data)
    # the store's patch names ("23 neutral 3.5 (1.05 D)"): the widest first column
    data.comparison.patch_names = [f"{k} {patch_name(k)}" for k in range(1, 25)]
    n_a = data.comparison.angle_deg.size
    data.renderers = [RendererRow("normbox-lab", "normbox-lab 0.1 (default)", 0.41, 1.9,
                                  [3.0] * n_a, [300, 10, 2, 0], 1),
                      RendererRow("mitsuba-rgb", "mitsuba 3.9.1 llvm_ad_rgb", 1.34, 2.71,
                                  [39.7] * n_a, [150, 100, 62, 0], 2)]
    rng = np.random.default_rng(0)
    data.images = [ImageFigure("fig-camera", "Virtual camera (synthetic panels)",
                               "Random panels: the layout of an image figure.",
                               [ImagePanel("truth", rng.uniform(size=(60, 80, 3))),
                                ImagePanel("prediction", rng.uniform(size=(60, 80, 3))),
                                ImagePanel("ΔE00", rng.uniform(0, 2, (60, 80)), 2.0, "ΔE00"),
                                ImagePanel("noise floor", rng.uniform(0, 0.3, (60, 80)), 2.0,
                                           "ΔE00")])]
    data.paper = _paper_rows(data, tmp_path_factory.mktemp("paper-store"))
    data.runs = [{"id": 2, "protocol": "reference-sweep", "status": "done",
                  "readings": "312/312", "date": "2026-11-25", "started": "2026-11-25 09:00 UTC",
                  "finished": "2026-11-25 10:10 UTC", "seeds": "noise=2, world=1"}]
    data.instruments = [{"role": "radiometer", "model": "CS-1000A (emulated)",
                         "serial": "not reported by the device", "firmware": "—",
                         "calibration": "none recorded in the store", "runs": "2"}]
    data.methods = {"software: normbox-lab": "0.1", "prediction: render quality": "default"}
    return write_report(tmp_path_factory.mktemp("browser") / "report.html", data)


def _paper_rows(data, tmp: Path) -> list[tuple[str, str, str]]:
    """The paper-scenario rows of the synthetic campaign, as the store gives them."""
    import dataclasses

    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze.budget_store import paper_observations

    with Store(tmp / "s.sqlite") as store:
        run = store.create_run("reference-sweep", status="done")
        data.comparison.store(store, f"ref-run-{run.id}", run_ref=run.id)
        for k in range(1, 25):
            dataclasses.replace(data.fits[f"patch{k:02d}"], name=f"p{k:02d}").store(store)
        dataclasses.replace(data.fits["wall"], name="wall").store(store)
        return paper_observations(store, run.id)


@pytest.mark.parametrize("width_px", WIDTHS_PX)
def test_report_reads_well_in_headless_chromium(report_html: Path, tmp_path: Path,
                                                width_px: int) -> None:
    browser = _chromium()
    text = report_html.read_text(encoding="utf-8")
    assert "<script" not in text
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("</body>", f"<script>{CHECK_JS}</script></body>"),
                     encoding="utf-8")
    done = _run(browser, tmp_path / "profile", f"--window-size={width_px},1000",
                "--dump-dom", probe.as_uri())
    m = re.search(r'data-check="([^"]*)"', done.stdout)
    assert m, f"no measurement in the dumped DOM; chromium said: {done.stderr[-2000:]}"
    check = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert check["width"] == width_px
    figures = text.count("<figure id=")
    assert check["images"] == figures > 5
    assert check["broken"] == [], f"figures that do not decode: {check['broken']}"
    assert check["scaled"] == [], f"figures shown below their own size: {check['scaled']}"
    assert check["scrollWidth"] <= width_px, check["sticking"]
    assert check["sticking"] == [], check["sticking"]
    assert check["scrolling"] == [], f"tables wider than the page: {check['scrolling']}"
    assert check["minFont"] >= 12.0, check["minWhere"]

    # one screenshot per section: a copy that shows only that section, as tall as it is
    out = Path(os.environ.get("NORMBOX_SCREENSHOT_DIR", tmp_path / "screens"))
    out.mkdir(parents=True, exist_ok=True)
    for k, sec in enumerate(check["sections"]):
        sid = sec["id"]
        keep = "nav{display:none}" if k == 0 else "header,nav{display:none}"
        page = tmp_path / f"section-{sid}.html"
        page.write_text(text.replace(
            "</style>", f"section:not(#{sid}){{display:none}}{keep}</style>"), encoding="utf-8")
        height = int(min(max(sec["height"] + (420 if k == 0 else 80), 400), 6000))
        prefix = "report" if width_px == WIDTHS_PX[0] else f"report-{width_px}"
        shot = out / f"{prefix}-{k + 1:02d}-{sid}.png"
        _run(browser, tmp_path / "profile", f"--window-size={width_px},{height}",
             f"--screenshot={shot}", page.as_uri())
        assert shot.exists() and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", sid
