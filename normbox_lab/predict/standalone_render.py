#!/usr/bin/env python3
"""Render every configuration of a Normbox scene package with stock Mitsuba 3.

Shipped as ``render_mitsuba.py`` in every scene package (`normbox-lab scene export`); it needs
Mitsuba 3, NumPy and the package's ``normbox_bsdf.py``, nothing of normbox-lab.

    python render_mitsuba.py [--variant llvm_ad_spectral] [--spp 256] [--batches 16]
                             [--out predictions.csv] [--only p19_s30,p13_s45] [--seed 0]

Spectral variants render each configuration's scene with its 81-band `specfilm` (triangular
hats, half-width 5 nm, 380…780 nm) in `--batches` independent batches of `--spp` samples per
pixel; a band's value is the mean over the 10 × 10 pixels divided by 5 nm (the band-averaged
radiance, W·sr⁻¹·m⁻²·nm⁻¹) and its standard error the batches' standard error of the mean.

RGB variants (e.g. ``llvm_ad_rgb``) render the same scenes with an RGB film: Mitsuba turns
every spectrum into RGB, as a triplet renderer does.  The linear-sRGB result is handed back
as a spectrum, upsampled the way Mitsuba upsamples an RGB emitter in a spectral variant (its
sRGB spectral model times its D65 illuminant, whose sRGB is the RGB it came from), sampled at
the band centres; the standard error is the change of that spectrum for a one-standard-error
change of the RGB.  The RGB triplets go to ``<out>.rgb.csv`` as well.

Output CSV: ``patch,angle_deg,wavelength_nm,radiance_W_sr_m2_nm,std_error`` with ``#`` comment
lines naming the renderer, its version and the settings (what `normbox-lab import prediction`
reads).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

BAND_WIDTH_NM = 5.0


def _load_bsdf(path: Path):
    spec = importlib.util.spec_from_file_location("normbox_bsdf", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _configurations(package: Path) -> list[tuple[int, float, str]]:
    with open(package / "configurations.csv", encoding="utf-8") as f:
        rows = csv.DictReader(line for line in f if not line.startswith("#"))
        return [(int(r["patch"]), float(r["angle_deg"]), r["scene"]) for r in rows]


def _band_centres(package: Path) -> np.ndarray:
    text = (package / "scenes" / "common" / "sensor_spectral.xml").read_text(encoding="utf-8")
    centres = []
    for line in text.splitlines():
        if 'name="b' in line and "value=" in line:
            pairs = line.split('value="')[1].split('"')[0].split(",")
            centres.append(float(pairs[1].split(":")[0]))
    return np.array(centres)


def upsample_rgb(rgb: np.ndarray, wavelength_nm: np.ndarray) -> np.ndarray:
    """Spectra (n, n_λ) for linear-sRGB radiance triplets (n, 3): Mitsuba's emitter upsampling
    (`d65` texture with an sRGB colour) evaluated at `wavelength_nm` (scalar_spectral)."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("scalar_spectral")
    out = np.zeros((len(rgb), len(wavelength_nm)))
    si = dr.zeros(mi.SurfaceInteraction3f)
    for i, c in enumerate(rgb):
        c = np.maximum(np.asarray(c, dtype=np.float64), 0.0)
        tex = mi.load_dict({"type": "d65",
                            "color": {"type": "rgb", "value": [float(x) for x in c]}})
        for j in range(0, len(wavelength_nm), 4):
            chunk = list(wavelength_nm[j:j + 4]) + [float(wavelength_nm[-1])] * 4
            si.wavelengths = mi.UnpolarizedSpectrum(*chunk[:4])
            v = tex.eval(si)
            for k in range(min(4, len(wavelength_nm) - j)):
                out[i, j + k] = float(v[k])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--spp", type=int, default=256, help="samples per pixel per batch")
    ap.add_argument("--batches", type=int, default=16,
                    help="independent batches per configuration (for the standard error)")
    ap.add_argument("--out", default="predictions.csv")
    ap.add_argument("--only", default="", help="comma-separated configurations, e.g. p19_s30")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--package", default=str(Path(__file__).resolve().parent),
                    help="the scene package (default: this file's directory)")
    args = ap.parse_args(argv)
    package = Path(args.package)
    import mitsuba as mi

    mi.set_variant(args.variant)
    bsdf = _load_bsdf(package / "normbox_bsdf.py")
    bsdf.register()
    rgb = "rgb" in args.variant
    if not rgb and "spectral" not in args.variant:
        print(f"render_mitsuba.py: a spectral or rgb variant please, not {args.variant}",
              file=sys.stderr)
        return 2
    configs = _configurations(package)
    if args.only:
        wanted = set(args.only.split(","))
        configs = [c for c in configs if Path(c[2]).stem in wanted]
        unknown = wanted - {Path(c[2]).stem for c in configs}
        if unknown:
            print(f"render_mitsuba.py: no configuration {', '.join(sorted(unknown))}",
                  file=sys.stderr)
            return 2
    centres = _band_centres(package)
    sensor = "sensor_rgb" if rgb else "sensor_spectral"
    results = []
    t0 = time.perf_counter()
    for n, (patch, angle, scene_file) in enumerate(configs):
        scene = mi.load_file(str(package / scene_file), sensor=sensor)
        batches = []
        for b in range(args.batches):
            img = np.asarray(mi.render(scene, spp=args.spp,
                                       seed=(args.seed * 1_000_003 + n) * 1009 + b),
                             dtype=np.float64)
            batches.append(img.reshape(-1, img.shape[-1]).mean(axis=0))
        arr = np.array(batches)
        mean = arr.mean(axis=0)
        se = arr.std(axis=0, ddof=1) / np.sqrt(len(arr)) if len(arr) > 1 \
            else np.full_like(mean, np.nan)
        results.append((patch, angle, mean, se))
        print(f"\r{n + 1}/{len(configs)} {Path(scene_file).stem} "
              f"{time.perf_counter() - t0:.1f} s", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    out = Path(args.out)
    if rgb:
        with open(out.with_suffix(".rgb.csv"), "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["patch", "angle_deg", "r", "g", "b", "se_r", "se_g", "se_b"])
            for patch, angle, mean, se in results:
                w.writerow([patch, f"{angle:g}", *[f"{x:.9g}" for x in (*mean[:3], *se[:3])]])
        means = np.array([r[2][:3] for r in results])
        ses = np.nan_to_num(np.array([r[3][:3] for r in results]))
        spectra = upsample_rgb(means, centres)
        shifted = upsample_rgb(means + ses, centres)
        results = [(p, a, spectra[i], np.abs(shifted[i] - spectra[i]))
                   for i, (p, a, _, _) in enumerate(results)]
    else:
        results = [(p, a, m / BAND_WIDTH_NM, s / BAND_WIDTH_NM) for p, a, m, s in results]
    with open(out, "w", newline="", encoding="utf-8") as f:
        f.write(f"# renderer: mitsuba {args.variant}\n")
        f.write(f"# renderer_version: mitsuba {mi.__version__} {args.variant}\n")
        f.write(f"# spp_per_batch: {args.spp}; batches: {args.batches}; seed: {args.seed}; "
                f"render_s: {time.perf_counter() - t0:.1f}\n")
        w = csv.writer(f)
        w.writerow(["patch", "angle_deg", "wavelength_nm", "radiance_W_sr_m2_nm", "std_error"])
        for patch, angle, mean, se in results:
            for lam, v, e in zip(centres, mean, se):
                w.writerow([patch, f"{angle:g}", f"{lam:g}", f"{v:.9g}", f"{e:.9g}"])
    print(f"{len(results)} configurations → {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
