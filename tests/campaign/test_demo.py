"""The whole virtual campaign closes on itself: with the fit model as the truth and instrument
noise off, what the instruments measured and what the pipeline predicts from its own fits agree
within the Monte-Carlo noise of the quick renders: truth and prediction draw independent random
numbers, each to the quick target (worst band 2 %), so the acceptance is NRMSE ≤ 0.5 % + 3 ×
their combined standard error (the truth's taken equal to the prediction's: same target)."""

from pathlib import Path

import numpy as np

from normbox_lab.acquire.store import Store
from normbox_lab.demo import QUICK_ANGLES, QUICK_PATCHES, DemoOptions, run_demo


def test_quick_demo_closes_through_the_instruments(tmp_path, capsys):
    lines: list[str] = []
    result = run_demo(DemoOptions(quick=True, truth="model", noise=False,
                                  out_dir=str(tmp_path / "demo")), log=lines.append)
    s = result.summary
    # measured (one run, quick renders, independent noise): NRMSE mean 0.51 %, max 1.98 %;
    # ΔE00 max 0.16
    with Store(result.store) as store:
        run_id = result.runs["reference-sweep"]
        pred = store.latest_artifact("prediction", f"ref-run-{run_id}").arrays
        comp = store.latest_artifact("comparison", f"ref-run-{run_id}").arrays
    sigma = (np.sqrt(2.0 * np.mean(pred["std_error"] ** 2, axis=-1))
             / np.mean(comp["reference"], axis=-1))
    nrmse = comp["nrmse"]
    assert np.all(nrmse <= 0.005 + 3.0 * sigma), (nrmse, sigma)
    assert np.median(nrmse / sigma) > 0.2            # the noise is not shared: it shows
    assert s["delta_e00_max"] < 0.2, s
    assert set(s["nrmse_by_angle_pct"]) == {f"{a:g}" for a in QUICK_ANGLES}
    assert result.report.exists() and result.report.stat().st_size > 10_000
    html = result.report.read_text()
    assert "fig-deltae" in html and "tab-fits" in html
    assert "fig-camera" in html and "fig-whitebalance" in html     # the virtual camera
    for path in s["camera_files"].values():
        head = Path(path).read_bytes()[:8]
        assert head in (b"\x89PNG\r\n\x1a\n", b"v/1\x01\x02\x00\x00\x00"), path
    # truth = model and (in the camera view) the same random numbers: only the fit differs
    assert s["camera_delta_e00"]["patch_region"] < 0.5, s["camera_delta_e00"]
    with Store(result.store) as store:
        ref = store.get_run(result.runs["reference-sweep"])
        assert ref.status == "done"
        n = len(list(store.readings(ref.id)))
    assert n == len(QUICK_PATCHES) * len(QUICK_ANGLES)
    # the truth's render noise as achieved, stored with the sweep for the budget's render term:
    # every configuration, its worst band at the world's quick target (2 %) or below
    from normbox_lab.acquire.queries import reference_data
    from normbox_lab.analyze.budget_store import truth_se_of_run

    ref_run = result.runs["reference-sweep"]
    with Store(result.store) as store:
        ref_data = reference_data(store, ref_run)
        truth_se = truth_se_of_run(store, ref_run, list(ref_data.patches), ref_data.angle_deg,
                                   ref_data.radiance, ref_data.wavelength_nm)
    assert truth_se is not None
    worst = np.max(truth_se / ref_data.radiance, axis=-1)
    assert np.all((worst > 0) & (worst <= 0.021)), worst
    assert [line.split(":")[0] for line in lines] == [
        "set-up", "brdf-inplane", "fit", "light-map", "reference-sweep", "predict", "compare",
        "images", "report"]
    assert np.isfinite(list(s["nrmse_by_angle_pct"].values())).all()
    # the same figures from the command line, on the demo's store
    from normbox_lab.cli import main

    out_dir = tmp_path / "fig"
    assert main(["image", "figure1", "--store", str(result.store), "--size", "32x24", "--spp",
                 "4", "--no-exr", "-o", str(out_dir)]) == 0
    printed = capsys.readouterr().out
    assert "ΔE00 over the box (block means, as the report)" in printed \
        and "illuminant xy: W&W" in printed
    assert (out_dir / "figure1-p07-45deg-delta-e00.png").exists()
    with Store(result.store) as store:
        figs = store.artifacts("image-figure", run_ref=result.runs["reference-sweep"])
    assert [a.name for a in figs][-2:] == ["fig-camera", "fig-whitebalance"]
    assert figs[-2].arrays["p0"].shape == (24, 32, 3)
