"""Any renderer against the Normbox: the scene package out, another renderer's spectra in.

The round trip runs from the package alone: `render_mitsuba.py` is started as a subprocess in
the exported directory with stock Mitsuba (nothing of normbox-lab on its path), its CSV is
imported through the command line and compared with our own prediction.  Both renderers are
unbiased estimators of one scene, so (stock − ours) / √(SE_stock² + SE_ours²) is a z score with
mean ≈ 0 and sd ≈ 1 (16 batches: the SE estimate's t distribution with 15 degrees of freedom
has sd 1.07).
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.acquire.store import Store
from normbox_lab.cli import main
from normbox_lab.predict.renderers import artifact_name

PATCHES = (19, 13)
ANGLES = (30.0, 60.0)


def _campaign(tmp_path: Path, patches=PATCHES, angles=ANGLES) -> tuple[Path, int, int]:
    """A small stored campaign (truth = the fit model, no instrument): gonio run, fits,
    reference run, our prediction (the fast renderer, as the demo)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "analyze"))
    import test_pipeline as tp

    from normbox_lab.analyze.pipeline import fit_run, predict_run

    saved = tp.PATCHES, tp.ANGLES
    tp.PATCHES, tp.ANGLES = patches, angles
    try:
        world, render = tp._world("model")
        path = tmp_path / "s.sqlite"
        with Store(path) as store:
            brdf = tp._gonio_run(store, "model")
            ref = tp._reference_run(store, world)
            fit_run(store, brdf)
            predict_run(store, ref, quality="quick", render=render)
    finally:
        tp.PATCHES, tp.ANGLES = saved
    return path, ref, brdf


def _render(pkg: Path, out: Path, variant: str, spp: int, batches: int,
            only: str = "") -> None:
    # normbox_lab shadowed by a package that refuses to import: the package renders with
    # stock Mitsuba alone (render_mitsuba.py finds normbox_bsdf.py by its own path)
    blocker = out.parent / "no-normbox-lab"
    (blocker / "normbox_lab").mkdir(parents=True, exist_ok=True)
    (blocker / "normbox_lab" / "__init__.py").write_text(
        'raise ImportError("a scene package must render without normbox-lab")\n')
    env = {**os.environ, "PYTHONPATH": str(blocker)}
    cmd = [sys.executable, str(pkg / "render_mitsuba.py"), "--variant", variant, "--spp",
           str(spp), "--batches", str(batches), "--out", str(out)]
    if only:
        cmd += ["--only", only]
    res = subprocess.run(cmd, cwd=out.parent, env=env, capture_output=True, text=True,
                         timeout=900, check=False)
    assert res.returncode == 0, res.stderr[-3000:]


def _z(store: Store, ref: int, renderer: str) -> np.ndarray:
    ours = store.latest_artifact("prediction", artifact_name(ref)).arrays
    theirs = store.latest_artifact("prediction", artifact_name(ref, renderer)).arrays
    # compare on the renderers' own 5 nm bands (the stored spectra are on the reference's
    # 1 nm grid, linear between band centres)
    wl = ours["wavelength_nm"]
    band = (np.abs((wl - 380.0) / 5.0 - np.round((wl - 380.0) / 5.0)) < 1e-9)
    d = theirs["radiance"][..., band] - ours["radiance"][..., band]
    se = np.hypot(theirs["std_error"][..., band], ours["std_error"][..., band])
    return d / se


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pkg")
    store, ref, brdf = _campaign(tmp)
    pkg = tmp / "package"
    assert main(["scene", "export", str(ref), "--out", str(pkg), "--store", str(store)]) == 0
    return store, ref, brdf, pkg


def test_package_holds_everything_a_renderer_needs(exported):
    store, _ref, _, pkg = exported
    names = {p.relative_to(pkg).as_posix() for p in pkg.rglob("*") if p.is_file()}
    for a in ANGLES:
        assert f"geometry/normbox_s{a:g}.obj" in names
        for p in PATCHES:
            assert f"scenes/p{p:02d}_s{a:g}.xml" in names
    for f in ("README.md", "render_mitsuba.py", "normbox_bsdf.py", "light/spectrum.csv",
              "light/panel_map.csv", "radiometer.json", "materials/wall.json",
              "materials/p19.json", "configurations.csv", "manifest.json"):
        assert f in names, f
    # the stand-alone files import nothing of the project
    for f in ("render_mitsuba.py", "normbox_bsdf.py"):
        assert "normbox_lab" not in (pkg / f).read_text().split('"""', 2)[2], f
    with open(pkg / "light" / "spectrum.csv") as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))]
    assert rows[0][:2] == ["wavelength_nm", "radiance_W_sr_m2_nm"]
    assert float(rows[1][0]) == 360.0 and float(rows[-1][0]) == 830.0
    m = json.loads((pkg / "materials" / "p19.json").read_text())
    assert "GGX" in m["formula"] and "Fresnel" in m["formula"] and m["units"]["c"] == "sr⁻¹"
    with Store(store) as s:
        from normbox_lab.acquire.queries import latest_fits

        fit = latest_fits(s)["p19"]
    assert m["alpha"] == pytest.approx(fit.alpha) and m["eta"] == pytest.approx(fit.eta)
    assert np.interp(550.0, m["wavelength_nm"], m["kd"]) == pytest.approx(
        np.interp(550.0, fit.wavelength_nm, fit.kd))
    view = json.loads((pkg / "radiometer.json").read_text())
    assert view["field_of_view_deg"] == 1.0 and view["pixels"] == [10, 10]
    assert view["direction"] == pytest.approx([0.0, 1.0, 0.0])
    # the OBJ: the patch at 30° has the normal (0, −sin 30°, cos 30°)
    obj = (pkg / "geometry" / "normbox_s30.obj").read_text().split("\no ")
    patch = next(b for b in obj if b.startswith("patch\n"))
    v = np.array([[float(x) for x in line.split()[1:]] for line in patch.splitlines()
                  if line.startswith("v ")])
    n = np.cross(v[1] - v[0], v[2] - v[0])
    assert n / np.linalg.norm(n) == pytest.approx([0.0, -0.5, np.sqrt(3) / 2], abs=1e-6)


def test_stock_mitsuba_renders_the_package_and_agrees_with_our_prediction(exported, tmp_path,
                                                                          capsys):
    """Stock Mitsuba (llvm_ad_spectral) on the exported XML + stand-alone BSDF vs our fast
    renderer on the same fits.  Measured: z mean −0.06, sd 1.05 over 4 × 81 bands
    (16 batches × 16 spp × 100 px per configuration, 6 s)."""
    store, ref, _, pkg = exported
    out = tmp_path / "stock.csv"
    _render(pkg, out, "llvm_ad_spectral", spp=64, batches=16)
    assert main(["import", "prediction", str(out), "--ref-run", str(ref), "--renderer",
                 "mitsuba-spectral", "--store", str(store)]) == 0
    with Store(store) as s:
        z = _z(s, ref, "mitsuba-spectral")
        imp = [r for r in s.runs() if r.protocol == "import-prediction"][-1]
    print(f"stock Mitsuba vs ours: z mean {z.mean():+.3f}, sd {z.std():.3f}, n {z.size}")
    assert abs(z.mean()) < 0.35 and 0.8 < z.std() < 1.3, (z.mean(), z.std())
    assert imp.parameters["renderer"] == "mitsuba-spectral"
    assert imp.parameters["renderer_version"].startswith("mitsuba 3.")
    capsys.readouterr()
    assert main(["compare", str(ref), "--renderer", "mitsuba-spectral", "--store",
                 str(store)]) == 0
    printed = capsys.readouterr().out
    de_mean = float(printed.split("ΔE00 mean ")[1].split(",")[0])
    assert de_mean < 0.3, printed
    with Store(store) as s:
        c = s.latest_artifact("comparison", f"ref-run-{ref}@mitsuba-spectral")
    assert c.metadata["renderer"] == "mitsuba-spectral"


def test_rgb_renderer_through_the_same_package(exported, tmp_path):
    """Mitsuba's llvm_ad_rgb variant renders the package as a triplet renderer: spectra to RGB,
    and back (Mitsuba's upsampling) for the comparison.  Its colour error against ours is the
    spectral-vs-RGB rendering error."""
    from normbox_lab.analyze.pipeline import compare_run

    store, ref, brdf, pkg = exported
    out = tmp_path / "rgb.csv"
    _render(pkg, out, "llvm_ad_rgb", spp=16, batches=8)
    assert out.with_suffix(".rgb.csv").exists()
    assert main(["import", "prediction", str(out), "--ref-run", str(ref), "--renderer",
                 "mitsuba-rgb", "--store", str(store)]) == 0
    with Store(store) as s:
        ours = compare_run(s, ref, brdf)
        rgb = compare_run(s, ref, brdf, renderer="mitsuba-rgb")
    # truth = model: our prediction reproduces the reference; the RGB renderer does not
    assert np.nanmax(ours.delta_e00) < 0.3
    assert np.nanmean(rgb.delta_e00) > 0.3, rgb.delta_e00
    assert np.nanmax(rgb.delta_e00) < 10.0, rgb.delta_e00


BROKEN = {
    "missing": (lambda rows: [r for r in rows if not r.startswith("13,60,")],
                "1 configuration of run {ref} missing: patch 13 at 60°"),
    "extra": (lambda rows: rows + [r.replace("19,30,", "5,30,", 1) for r in rows
                                   if r.startswith("19,30,")],
              "1 configuration not in run {ref}: patch 5 at 30°"),
    "micrometres": (lambda rows: [_scale_wl(r, 1e-3) for r in rows],
                    ("wavelength_nm 0.38–0.78 does not cover the reference's 380–780 nm "
                    "(µm? wavelengths must be in nm)")),
    "short-range": (lambda rows: [r for r in rows if float(r.split(",")[2]) >= 400],
                    "wavelength_nm 400–780 does not cover the reference's 380–780 nm"),
    "negative": (lambda rows: [_set(r, "19,30,400,", "-1e-06") for r in rows],
                 "negative radiance -1e-06 W·sr⁻¹·m⁻²·nm⁻¹ for patch 19 at 30° at 400 nm"),
    "nan": (lambda rows: [_set(r, "13,60,500,", "nan") for r in rows],
            "radiance not finite (nan) for patch 13 at 60° at 500 nm"),
}


def _scale_wl(row: str, factor: float) -> str:
    p, a, w, *rest = row.split(",")
    return ",".join([p, a, f"{float(w) * factor:g}", *rest])


def _set(row: str, prefix: str, value: str) -> str:
    if not row.startswith(prefix):
        return row
    parts = row.split(",")
    parts[3] = value
    return ",".join(parts)


def _synthetic_csv(store_path: Path, ref: int) -> list[str]:
    with Store(store_path) as s:
        a = s.latest_artifact("prediction", artifact_name(ref)).arrays
    rows = []
    for pi, p in enumerate(a["patches"].astype(int)):
        for ai, ang in enumerate(a["angle_deg"]):
            for w in range(380, 781, 5):
                k = int(np.argmin(np.abs(a["wavelength_nm"] - w)))
                rows.append(f"{p},{ang:g},{w},{a['radiance'][pi, ai, k]:.9g},"
                            f"{a['std_error'][pi, ai, k]:.9g}")
    return rows


@pytest.mark.parametrize("fault", sorted(BROKEN))
def test_broken_prediction_files_are_refused_with_one_line_and_nothing_stored(
        exported, tmp_path, capsys, fault):
    store, ref, _, _ = exported
    edit, expected = BROKEN[fault]
    rows = edit(_synthetic_csv(store, ref))
    f = tmp_path / f"{fault}.csv"
    f.write_text("# renderer_version: test 1\npatch,angle_deg,wavelength_nm,"
                 "radiance_W_sr_m2_nm,std_error\n" + "\n".join(rows) + "\n")
    with Store(store) as s:
        before = (len(s.runs()), len(s.artifacts("prediction")))
    capsys.readouterr()
    assert main(["import", "prediction", str(f), "--ref-run", str(ref), "--renderer",
                 "broken", "--store", str(store)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert expected.format(ref=ref) in err[0], err
    with Store(store) as s:
        assert (len(s.runs()), len(s.artifacts("prediction"))) == before


def test_exr_directory_is_read_as_pixel_means(exported, tmp_path):
    from normbox_lab.core.exr import write_spectral_exr
    from normbox_lab.predict.renderers import read_prediction

    _store, _ref, _, _ = exported
    wl = np.arange(380.0, 781.0, 5.0)
    img = np.ones((2, 3, wl.size)) * np.linspace(1, 2, wl.size) * 1e-3
    img[0, 0] *= 3.0                          # one pixel brighter: the mean counts it
    write_spectral_exr(tmp_path / "p19_s30.exr", wavelength_nm=wl, radiance=img)
    pf = read_prediction(tmp_path)
    w, rad, se = pf.spectra[(19, 30.0)]
    assert se is None
    np.testing.assert_allclose(w, wl)
    np.testing.assert_allclose(rad, np.linspace(1, 2, wl.size) * 1e-3 * (5 + 3) / 6, rtol=1e-6)


@pytest.mark.slow
def test_full_campaign_round_trip_through_stock_mitsuba(tmp_path):
    """All 24 patches × 13 angles of a reference sweep through the package and stock Mitsuba.
    Measured: z mean +0.006, sd 1.047 over 25 272 bands (12.4 min on 2 loaded cores)."""
    angles = tuple(float(a) for a in range(30, 91, 5))
    store, ref, _ = _campaign(tmp_path, patches=tuple(range(1, 25)), angles=angles)
    pkg = tmp_path / "package"
    assert main(["scene", "export", str(ref), "--out", str(pkg), "--store", str(store)]) == 0
    out = tmp_path / "stock.csv"
    _render(pkg, out, "llvm_ad_spectral", spp=32, batches=16)
    assert main(["import", "prediction", str(out), "--ref-run", str(ref), "--renderer",
                 "mitsuba-spectral", "--store", str(store)]) == 0
    with Store(store) as s:
        z = _z(s, ref, "mitsuba-spectral")
    assert abs(z.mean()) < 0.2 and 0.85 < z.std() < 1.2, (z.mean(), z.std())


@pytest.mark.slow
def test_the_demos_reference_run_renders_from_its_package(tmp_path):
    """`normbox-lab demo --quick` (default truth, instrument noise on): its reference run's
    package through stock Mitsuba agrees with the demo's own prediction within Monte-Carlo
    error, and with the measurement as well as ours does.  Measured: z mean +0.10, sd 1.12
    over 12 × 81 bands; ΔE00 mean 0.64 (stock) vs 0.63 (ours)."""
    from normbox_lab.analyze.pipeline import compare_run
    from normbox_lab.demo import DemoOptions, run_demo

    result = run_demo(DemoOptions(quick=True, out_dir=str(tmp_path / "demo")),
                      log=lambda line: None)
    ref = result.runs["reference-sweep"]
    pkg = tmp_path / "package"
    assert main(["scene", "export", str(ref), "--out", str(pkg), "--store",
                 str(result.store)]) == 0
    out = tmp_path / "stock.csv"
    _render(pkg, out, "llvm_ad_spectral", spp=64, batches=16)
    assert main(["import", "prediction", str(out), "--ref-run", str(ref), "--renderer",
                 "mitsuba-spectral", "--store", str(result.store)]) == 0
    with Store(result.store) as s:
        z = _z(s, ref, "mitsuba-spectral")
        ours = compare_run(s, ref)
        stock = compare_run(s, ref, renderer="mitsuba-spectral")
    assert abs(z.mean()) < 0.35 and 0.8 < z.std() < 1.3, (z.mean(), z.std())
    assert abs(np.nanmean(stock.delta_e00) - np.nanmean(ours.delta_e00)) < 0.15


def test_budget_and_report_work_on_an_imported_prediction(exported, tmp_path, capsys):
    """A renderer that returns exactly our spectra: compare, budget and report treat it as
    ours (same observed NRMSE), under its own artifact names."""
    store, ref, brdf, _ = exported
    f = tmp_path / "copy.csv"
    f.write_text("# renderer_version: copy 1\npatch,angle_deg,wavelength_nm,"
                 "radiance_W_sr_m2_nm,std_error\n"
                 + "\n".join(_synthetic_csv(store, ref)) + "\n")
    assert main(["import", "prediction", str(f), "--ref-run", str(ref), "--renderer", "copy",
                 "--store", str(store)]) == 0
    assert main(["compare", str(ref), "--brdf-run", str(brdf), "--store", str(store)]) == 0
    assert main(["compare", str(ref), "--brdf-run", str(brdf), "--renderer", "copy",
                 "--store", str(store)]) == 0
    for renderer in (None, "copy"):
        args = ["budget", str(ref), "--paths", "1024", "--draws", "8", "--store", str(store)]
        assert main(args + (["--renderer", renderer] if renderer else [])) == 0
    with Store(store) as s:
        ours = s.latest_artifact("error-budget", artifact_name(ref)).arrays
        copy = s.latest_artifact("error-budget", artifact_name(ref, "copy")).arrays
        assert s.latest_artifact("error-model", artifact_name(ref, "copy"))
    # the CSV holds the 5 nm band values, ours the 1 nm grid: equal at the band centres
    np.testing.assert_allclose(copy["observed_nrmse"], ours["observed_nrmse"], rtol=0.05)
    out = tmp_path / "r.html"
    assert main(["report", str(ref), "--renderer", "copy", "--brdf-run", str(brdf), "-o",
                 str(out), "--store", str(store)]) == 0
    html = out.read_text()
    assert "renderer copy" in html and "<th>copy</th>" in html
