"""`normbox-lab image …`: spectral images — the virtual camera (the paper's Fig. 1), the MIST
cross-check and metamers, the Wilkie–Weidlich white balance, spectral OpenEXR files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from normbox_lab.acquire.params import SEED, Number, option
from normbox_lab.commands.common import add_store_argument, require_store

#: the kinds of the image commands' numeric options (normbox_lab.acquire.params)
PATCH = Number(1, 24, whole=True)
ANGLE = Number(-180, 180, unit="°")
SPP = Number(1, 1 << 20, whole=True)


def _size(text: str) -> tuple[int, int]:
    from normbox_lab.acquire.params import ParameterError, parse_number

    parts = text.lower().split("x")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT (e.g. 320x240), "
                                         f"got {text[:24]!r}")
    try:
        w, h = (parse_number(v, "size", whole=True) for v in parts)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT (e.g. 320x240): "
                                         f"{str(exc).removeprefix('size: ')}") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"size {w}x{h} out of range (8…4096 per side)")
    return int(w), int(h)


def _w(text: str) -> float:
    from normbox_lab.acquire.params import ParameterError, parse_number
    from normbox_lab.images.whitebalance import check_w

    try:
        return check_w(float(parse_number(text, "w")))
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("w: ")) from None
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("image", help="spectral images: virtual camera, Fig. 1, MIST, W&W, EXR",
                       description="Spectral images of the virtual Normbox and the tools of the "
                                   "MIST and Wilkie & Weidlich papers (docs/images.md).")
    s = p.add_subparsers(dest="image_command", metavar="SUBCOMMAND", required=True)
    _add_camera(s)
    _add_figure1(s)
    _add_metamer(s)
    _add_triplet(s)
    _add_whitebalance(s)
    _add_exr_info(s)


def _add_camera(s: argparse._SubParsersAction) -> None:
    """`image camera`: the box interior from the open side, as EXR and PNG."""
    c = s.add_parser("camera", help="render the box interior from the open side",
                     description="Render the virtual Normbox seen from its open side with the "
                                 "truth materials of the virtual world (or the fits of a store) "
                                 "and write a multilayer spectral OpenEXR (radiance, diffuse, "
                                 "specular, indirect, depth, normal, preview) and a "
                                 "white-balanced sRGB PNG.")
    c.add_argument("--patch", type=option(PATCH, "--patch"),
                   default=7, help="ColorChecker patch 1…24 (default 7)")
    c.add_argument("--angle", type=option(ANGLE, "--angle"),
                   default=45.0, help="sample angle in degrees "
                   "(0 = facing the light, 90 = facing the radiometer; default 45)")
    c.add_argument("--materials", choices=("truth", "fitted"), default="truth",
                   help="truth (the virtual world's) or fitted (latest fits in --store)")
    c.add_argument("--truth", choices=("default", "model"), default="default",
                   help="which truth materials (default: measured-like; model: the fit model)")
    _render_args(c)
    c.add_argument("--white-balance", choices=("ww", "gray-world", "none"), default="ww",
                   help="preview white balance: Wilkie & Weidlich (default), plain gray world, "
                        "or none (the lamp's colour shows)")
    c.add_argument("--no-exr", action="store_true", help="write the PNG only")
    add_store_argument(c)
    c.set_defaults(handler=_camera)


def _add_figure1(s: argparse._SubParsersAction) -> None:
    """`image figure1`: the paper's Fig. 1, virtually, into the store."""
    f = s.add_parser("figure1", help="truth vs prediction images and the ΔE00 map into the store",
                     description="The paper's Fig. 1, virtually: the box with the truth materials "
                                 "and with the latest fits, the per-pixel ΔE00 map and the W&W "
                                 "white balance; stored as image figures of the reference run "
                                 "(the report and the TUI's Images tab show them) and written "
                                 "as PNGs (+ the truth image as spectral EXR).")
    f.add_argument("run", metavar="REFERENCE_RUN_ID", nargs="?",
                   help="reference sweep (default: the latest)")
    f.add_argument("--patch", type=option(PATCH, "--patch"),
                   default=7, help="patch on the holder (default 7)")
    f.add_argument("--angle", type=option(ANGLE, "--angle"),
                   default=45.0, help="sample angle (default 45°)")
    f.add_argument("--truth", choices=("default", "model"), default="default")
    f.add_argument("--light-map", metavar="RUN_ID",
                   help="take the lamp luminance from this light-map run")
    f.add_argument("--no-exr", action="store_true", help="skip the spectral EXR")
    _render_args(f)
    add_store_argument(f)
    f.set_defaults(handler=_figure1)


def _add_metamer(s: argparse._SubParsersAction) -> None:
    """`image metamer`: reflectance spectra for sRGB colours (MIST)."""
    m = s.add_parser("metamer", help="reflectance spectra for sRGB colours (MIST)",
                     description="A physical reflectance spectrum (380–780 nm, 5 nm) whose "
                                 "colour under D65 is the given sRGB colour: MIST's KD-tree "
                                 "nearest in xy over colour-science's reflectance sets, or "
                                 "(default) an exact-XYZ blend of database spectra.")
    m.add_argument("colours", nargs="+", metavar="COLOUR",
                   help="sRGB as #rrggbb, rrggbb or r,g,b (0–255)")
    m.add_argument("--nearest", action="store_true", help="MIST's plain nearest match")
    m.add_argument("--csv", metavar="PATH", help="write wavelength_nm + one column per colour")
    m.set_defaults(handler=_metamer)


def _add_triplet(s: argparse._SubParsersAction) -> None:
    """`image triplet`: the MIST wavelength-triplet cross-check."""
    t = s.add_parser("triplet", help="MIST wavelength-triplet cross-check of the renderer",
                     description="Render the radiometer's view with three wavelengths per "
                                 "render in Mitsuba's RGB variant and compare with the spectral "
                                 "renderer band by band (z-scores of the difference).")
    t.add_argument("--patch", type=option(PATCH, "--patch"),
                   default=15, help="patch (model-family truth; default 15)")
    t.add_argument("--angle", type=option(ANGLE, "--angle"),
                   default=30.0, help="sample angle (default 30°)")
    t.add_argument("--every", type=option(Number(1, 81, whole=True), "--every"),
                   default=3, help="every N-th 5 nm band (default 3)")
    t.add_argument("--spp", type=option(SPP, "--spp"),
                   default=64, help="samples per pixel per batch")
    t.add_argument("--batches", type=option(Number(2, 10_000, whole=True), "--batches"),
                   default=10, help="independent batches (default 10)")
    t.add_argument("--reference-spp", type=option(SPP, "--reference-spp"), default=1024,
                   help="stock spectral reference: samples per pixel per batch (10 batches)")
    t.add_argument("--false-alarm", type=option(Number(0, 0.5, above=True), "--false-alarm"),
                   default=0.001,
                   help="chance that the check fails when both renderers agree (default 0.001)")
    t.add_argument("--seed", type=option(SEED, "--seed"), default=0)
    t.set_defaults(handler=_triplet)


def _add_whitebalance(s: argparse._SubParsersAction) -> None:
    """`image whitebalance`: Wilkie & Weidlich against gray world."""
    wb = s.add_parser("whitebalance", help="Wilkie & Weidlich vs gray world on a coloured room",
                      description="Render the Cornell-like test room lit by a Planckian lamp of "
                                  "--lamp-k kelvin, estimate the illuminant by Wilkie & Weidlich "
                                  "(CWNI/NWCI images, 1−Chroma weights) and by plain gray world, "
                                  "and compare both with the light on the white cube's lit face.")
    wb.add_argument("--lamp-k", type=option(Number(500, 50_000, unit="K"), "--lamp-k"),
                    default=1800.0, help="lamp temperature (default 1800)")
    wb.add_argument("--room", choices=("coloured", "cornell"), default="coloured",
                    help="coloured: green/teal walls (the acceptance test's room); cornell: "
                         "red/green/grey walls")
    wb.add_argument("--w", type=_w, default=2.0, help="1−Chroma exponent w, 1…4 (default 2)")
    wb.add_argument("--size", type=_size, default=(96, 72), help="WIDTHxHEIGHT (default 96x72)")
    wb.add_argument("--spp", type=option(SPP, "--spp"), default=64)
    wb.add_argument("--seed", type=option(SEED, "--seed"), default=1)
    wb.add_argument("-o", "--out", metavar="DIR", help="also write raw and balanced PNGs here")
    wb.set_defaults(handler=_whitebalance)


def _add_exr_info(s: argparse._SubParsersAction) -> None:
    """`image exr-info`: the layers of a spectral OpenEXR file."""
    e = s.add_parser("exr-info", help="list the layers of a spectral OpenEXR file")
    e.add_argument("path")
    e.set_defaults(handler=_exr_info)


def _render_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=_size, default=(320, 240), help="WIDTHxHEIGHT (default 320x240)")
    p.add_argument("--spp", type=option(SPP, "--spp"), default=None,
                   help="samples per pixel (default 96)")
    p.add_argument("--seed", type=option(SEED, "--seed"), default=1)
    p.add_argument("--w", type=_w, default=2.0, help="W&W 1−Chroma exponent, 1…4 (default 2)")
    p.add_argument("-o", "--out", metavar="DIR", default="images",
                   help="output folder (default ./images)")


def _open_store(args: argparse.Namespace):
    from normbox_lab.acquire.store import Store

    require_store(args.store)
    return Store(args.store)


def _camera(args: argparse.Namespace) -> int:
    import numpy as np

    from normbox_lab.images import normbox_view, whitebalance
    from normbox_lab.images.color import XYZ_to_srgb, write_png
    from normbox_lab.predict.materials import holder_material, truth_patch, truth_wall

    if args.materials == "fitted":
        from normbox_lab.acquire.queries import fit_key, latest_fits
        from normbox_lab.predict.materials import Material

        with _open_store(args) as store:
            fits = latest_fits(store)
        missing = [k for k in (fit_key(args.patch), "wall") if k not in fits]
        if missing:
            from normbox_lab.core.errors import StoreError

            raise StoreError(f"no fits for {', '.join(missing)} in {args.store}")
        patch = Material.from_fit(fits[fit_key(args.patch)])
        wall = Material.from_fit(fits["wall"])
    else:
        patch, wall = truth_patch(args.patch, args.truth), truth_wall(args.truth)
    width, height = args.size
    spp = args.spp if args.spp is not None else normbox_view.NORMBOX_DEFAULT_SPP
    print(f"rendering {width}×{height} px, {spp} spp, patch {args.patch} at {args.angle:g}° "
          f"({args.materials})…", file=sys.stderr, flush=True)
    img = normbox_view.render_normbox_camera(patch, wall, args.angle, holder=holder_material(),
                                       width=width, height=height, spp=spp, seed=args.seed)
    XYZ = img.XYZ()
    if args.white_balance == "ww":
        illuminant = whitebalance.estimate_illuminant(img.cwni, img.nwci, args.w,
                                                      wavelength_nm=img.wavelength_nm)
        XYZ = whitebalance.adapt_to_display(XYZ, illuminant.illuminant_XYZ)
    elif args.white_balance == "gray-world":
        XYZ = whitebalance.adapt_to_display(XYZ, whitebalance.gray_world(XYZ))
    out = Path(args.out)
    stem = f"camera-p{args.patch:02d}-{args.angle:g}deg-{args.materials}"
    # display white: the white patch at 30° seen by the radiometer in the same box (as figure1)
    white = normbox_view.white_reference_XYZ(wall, holder=holder_material(), seed=args.seed)
    png = write_png(out / f"{stem}.png", XYZ_to_srgb(XYZ, float(white[1])))
    print(f"render: {img.time_s:.1f} s; luminance median relative SE "
          f"{100 * img.info.get('median_rel_se_luminance', float('nan')):.1f} %")
    print(f"png: {png}")
    if not args.no_exr:
        from normbox_lab.core.exr import write_spectral_exr

        path = write_spectral_exr(out / f"{stem}.exr", img,
                                  extra_spectral={"emission": img.emission},
                                  attributes={"normbox.materials": args.materials})
        print(f"exr: {path} ({path.stat().st_size / 1e6:.0f} MB)")
    return 0 if np.all(np.isfinite(img.radiance)) else 1


def _figure1(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.queries import lamp_from_light_map
    from normbox_lab.analyze.pipeline import camera_figures_run

    with _open_store(args) as store:
        ref = args.run
        if ref is None:
            refs = [r for r in store.runs() if r.protocol == "reference-sweep"]
            if not refs:
                from normbox_lab.core.errors import StoreError

                raise StoreError(f"no reference sweep in {args.store}")
            ref = refs[-1].id
        width, height = args.size
        print(f"rendering truth and prediction, {width}×{height} px…", file=sys.stderr,
              flush=True)
        r = camera_figures_run(store, ref, patch=args.patch, angle_deg=args.angle,
                               truth=args.truth, lamp=lamp_from_light_map(store, args.light_map),
                               width=width, height=height, spp=args.spp, seed=args.seed,
                               w=args.w, out_dir=args.out, exr=not args.no_exr)
    d = r.delta_e00
    print(f"render: {r.render_s:.1f} s")
    print(f"ΔE00 over the box (block means, as the report): mean {d['converged_mean']:.2f}, "
          f"p95 {d['converged_p95']:.2f}, max {d['converged_max']:.2f}; noise floor median "
          f"{d['converged_noise_median']:.2f}; region means: patch "
          f"{d.get('patch_region', float('nan')):.2f}, wall {d.get('wall_region', float('nan')):.2f}")
    print(f"illuminant xy: W&W ({r.ww_xy[0]:.4f}, {r.ww_xy[1]:.4f}), gray world "
          f"({r.gray_world_xy[0]:.4f}, {r.gray_world_xy[1]:.4f})")
    for name, path in r.files.items():
        print(f"{name}: {path}")
    print(f"stored image figures (artifacts {', '.join(map(str, r.artifact_ids))}) on run {ref}; "
          f"`normbox-lab report {ref}` shows them")
    return 0


def _parse_colour(text: str) -> tuple[int, int, int]:
    """#rrggbb, rrggbb or r,g,b (0–255): the numbers through the one parser (digits 0-9
    only, length checked first); a refusal is a `ParameterError` (one line, exit 2)."""
    from normbox_lab.acquire.params import Number, ParameterError, parse_items, read

    t = text.strip().lstrip("#")
    field = f"colour {text[:24]!r}"
    if "," in t:
        items = parse_items(t, field)
        if len(items) != 3:
            raise ParameterError(f"{field}: three values 0–255")
        channel = Number(0, 255, whole=True)
        return tuple(int(read(v, channel, field)) for v in items)  # type: ignore[return-value]
    if len(t) == 6 and all(c in "0123456789abcdefABCDEF" for c in t):
        return tuple(int(t[i:i + 2], 16) for i in (0, 2, 4))  # type: ignore[return-value]
    raise ParameterError(f"{field}: use #rrggbb, rrggbb or r,g,b (0–255)")


def _metamer(args: argparse.Namespace) -> int:
    import numpy as np

    from normbox_lab.analyze.compare import XYZ_to_Lab_D65, delta_e00
    from normbox_lab.images.color import reflectance_to_XYZ
    from normbox_lab.images.metamer import linear_srgb_to_XYZ, metamer_for_srgb, srgb_decode

    method = "nearest" if args.nearest else "blend"
    columns = []
    wl = None
    for text in args.colours:
        rgb = _parse_colour(text)
        wl, refl = metamer_for_srgb(rgb, method=method)
        want = linear_srgb_to_XYZ(srgb_decode(np.asarray(rgb) / 255.0))
        got = reflectance_to_XYZ(wl, refl)
        de = float(delta_e00(XYZ_to_Lab_D65(want), XYZ_to_Lab_D65(got)))
        print(f"{text}: ΔE00 {de:.3f} under D65, reflectance {refl.min():.3f}…{refl.max():.3f}, "
              f"at 450/550/650 nm: {np.interp(450, wl, refl):.3f} {np.interp(550, wl, refl):.3f} "
              f"{np.interp(650, wl, refl):.3f}")
        columns.append(refl)
    if args.csv:
        header = "wavelength_nm," + ",".join(c.replace(",", " ") for c in args.colours)
        np.savetxt(args.csv, np.column_stack([wl, *columns]), delimiter=",", header=header,
                   comments="", fmt="%.6g")
        print(f"csv: {args.csv}")
    return 0


def _triplet(args: argparse.Namespace) -> int:
    from types import SimpleNamespace

    import numpy as np

    from normbox_lab.images.triplet import render_triplets
    from normbox_lab.predict.materials import truth_patch, truth_wall
    from normbox_lab.predict.render import BAND_CENTRES_NM, Quality, render_view

    patch, wall = truth_patch(args.patch, "model"), truth_wall("model")
    bands = np.asarray(BAND_CENTRES_NM)[::max(1, args.every)]
    n = len(bands) - len(bands) % 3
    bands = bands[:n]
    print(f"triplets: {n} wavelengths in {n // 3} RGB renders × {args.batches} batches…",
          file=sys.stderr, flush=True)
    tri = render_triplets(patch, wall, args.angle, wavelengths_nm=bands, spp=args.spp,
                          batches=args.batches, seed=args.seed)
    ref_batches = 10
    ref = render_view(patch=patch, wall=wall, angle_deg=args.angle, cache=False, seed=args.seed,
                      quality=Quality("triplet-check", spp=args.reference_spp,
                                      batches=ref_batches))
    on = np.isin(np.asarray(ref.wavelength_nm), bands)
    other = SimpleNamespace(wavelength_nm=np.asarray(ref.wavelength_nm)[on],
                            radiance=ref.radiance[on], std_error=ref.std_error[on])
    z = tri.z_scores(other)
    limit = triplet_z_limit(tri.std_error, other.std_error, args.batches, ref_batches,
                            args.false_alarm)
    print(f"triplet render {tri.render_time_s:.1f} s ({tri.variant}); spectral {ref.render_time_s:.1f} s "
          f"({ref.variant})")
    print(f"max |z| {np.max(np.abs(z)):.2f}, mean z² {np.mean(z ** 2):.2f} over {z.size} bands "
          f"(agreement within Monte-Carlo error: mean z² ≈ 1, every |z| below its band's limit "
          f"{np.min(limit):.2f}–{np.max(limit):.2f}: Student t, Welch degrees of freedom, "
          f"Šidák over the bands, false alarm {args.false_alarm:g})")
    # the band-summed radiance of each batch: its spread holds the bands' correlations
    sum_t = np.asarray(tri.batches, dtype=np.float64).sum(axis=1)
    sum_r = np.asarray(ref.batches, dtype=np.float64)[:, on].sum(axis=1)
    ratio = sum_t.mean() / sum_r.mean()
    rel = np.hypot(sum_t.std(ddof=1) / np.sqrt(sum_t.size) / sum_t.mean(),
                   sum_r.std(ddof=1) / np.sqrt(sum_r.size) / sum_r.mean())
    print(f"band-summed radiance triplet / spectral: {ratio:.5f} ± {ratio * rel:.5f}")
    return 0 if np.all(np.abs(z) < limit) else 1


def triplet_z_limit(se_a: Any, se_b: Any, batches_a: int, batches_b: int,
                    false_alarm: float) -> Any:
    """Per band, the |z| that a difference of two batch means exceeds by chance with
    probability 1 − (1 − false_alarm)^(1/bands) (Šidák: the whole check fails by chance with
    probability `false_alarm` when the bands are independent).  Each SE comes from its batches'
    spread, so z follows Student's t with the Welch–Satterthwaite degrees of freedom, not a
    normal law (with 10 batches, |z| ≥ 4 happens 1 time in 300 per band)."""
    import numpy as np
    from scipy.stats import t as student_t

    a2 = np.asarray(se_a, dtype=np.float64) ** 2
    b2 = np.asarray(se_b, dtype=np.float64) ** 2
    dof = (a2 + b2) ** 2 / np.maximum(a2 ** 2 / (batches_a - 1) + b2 ** 2 / (batches_b - 1),
                                      1e-300)
    per_band = 1.0 - (1.0 - float(false_alarm)) ** (1.0 / a2.size)
    return student_t.isf(per_band / 2.0, np.maximum(dof, 1.0))


def _whitebalance(args: argparse.Namespace) -> int:
    import numpy as np

    from normbox_lab.images import cornell, whitebalance
    from normbox_lab.images.color import XYZ_to_srgb, write_png
    from normbox_lab.predict.render import planck_W_sr_m2_nm

    mats = whitebalance.coloured_room_materials() if args.room == "coloured" else None
    lamp_nm = np.arange(360.0, 831.0, 5.0)
    lamp = planck_W_sr_m2_nm(lamp_nm, args.lamp_k)
    lamp = lamp / lamp.max() * 10.0
    width, height = args.size
    img = cornell.render_cornell(mats, lamp_nm, lamp, width, height, args.spp, args.seed)
    XYZ = img.XYZ()
    lit = img.mask("box") & (img.normal[..., 2] > 0.9)      # the cube's face under the lamp
    target = whitebalance.gray_world_xy(XYZ[lit])
    est = whitebalance.estimate_illuminant(img.XYZ("cwni"), img.XYZ("nwci"), args.w)
    gw = whitebalance.gray_world_xy(XYZ)
    err_ww = float(np.hypot(*(est.illuminant_xy - target)))
    err_gw = float(np.hypot(*(gw - target)))
    print(f"light on the white cube's lit face: xy ({target[0]:.4f}, {target[1]:.4f})")
    print(f"Wilkie & Weidlich (w = {args.w:g}): ({est.illuminant_xy[0]:.4f}, "
          f"{est.illuminant_xy[1]:.4f}), off by {err_ww:.4f}")
    print(f"gray world on the raw image:  ({gw[0]:.4f}, {gw[1]:.4f}), off by {err_gw:.4f}")
    if args.out:
        out = Path(args.out)
        white_Y = float(np.percentile(XYZ[..., 1], 99))
        print(f"png: {write_png(out / 'whitebalance-raw.png', XYZ_to_srgb(XYZ, white_Y))}")
        balanced = whitebalance.adapt_to_display(XYZ, est.illuminant_XYZ)
        print(f"png: {write_png(out / 'whitebalance-ww.png', XYZ_to_srgb(balanced, white_Y))}")
        grey = whitebalance.adapt_to_display(XYZ, whitebalance.gray_world(XYZ))
        print(f"png: {write_png(out / 'whitebalance-grayworld.png', XYZ_to_srgb(grey, white_Y))}")
    return 0


def _exr_info(args: argparse.Namespace) -> int:
    from normbox_lab.commands.common import input_path
    from normbox_lab.core.errors import BadPath
    from normbox_lab.core.exr import read_spectral_exr

    path = input_path(args.path, "PATH")
    if not path.isascii():
        try:
            path.encode("utf-8")
        except UnicodeEncodeError:           # bytes of another encoding in the name
            raise BadPath(f"{path}: not a UTF-8 file name (Mitsuba opens EXR files by "
                          "UTF-8 name)") from None
    try:
        d = read_spectral_exr(path)
    except RuntimeError as exc:              # Mitsuba's Bitmap: not an EXR, or damaged
        raise BadPath(f"{path}: not an EXR image ({exc})") from None
    wl = d["wavelength_nm"]
    if wl is not None and len(wl):
        print(f"wavelengths: {len(wl)} from {wl[0]:g} to {wl[-1]:g} nm")
    for key in ("radiance", "diffuse", "specular", "indirect", "depth_m", "normal",
                "preview_rgb"):
        v = d.get(key)
        if v is not None:
            print(f"{key}: {'×'.join(map(str, v.shape))} float32")
    for key, v in (d.get("other") or {}).items():
        print(f"{key}: {'×'.join(map(str, getattr(v, 'shape', ())))}")
    for key, v in (d.get("attributes") or {}).items():
        print(f"attribute {key} = {v}")
    return 0
