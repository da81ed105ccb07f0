"""`normbox-lab import brdf-json FILE [--material NAME] [--tilt-deg 4] [--store FILE]`,
`normbox-lab import prediction FILE --ref-run N --renderer NAME [--store FILE]`."""

from __future__ import annotations

import argparse

from normbox_lab.acquire.params import Number, option
from normbox_lab.commands.common import add_store_argument, input_path, require_store


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="import measured data into the store")
    isub = p.add_subparsers(dest="import_kind", metavar="KIND")
    b = isub.add_parser(
        "brdf-json", help="in-plane spectral BRDF in the JSON array layout",
        description="Import a JSON array: element 0 {'wavelengths': [...]}, then one object per "
                    "geometry with thetaIn, phiIn, thetaOut, phiOut (deg) and spectrum (sr^-1). "
                    "Stored as a run of protocol import-brdf-json.")
    b.add_argument("file", metavar="FILE")
    b.add_argument("--material", help="material name (default: the file name)")
    b.add_argument("--tilt-deg", type=option(Number(-45, 45, unit="°"), "--tilt-deg"), default=0.0,
                   help="out-of-plane tilt of the arms during that measurement")
    add_store_argument(b)
    b.set_defaults(handler=_import_brdf)
    _register_prediction(isub)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _import_brdf(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.importers import load_brdf_json, store_brdf
    from normbox_lab.acquire.store import Store
    from normbox_lab.core.errors import BadInputFile, DataError

    try:
        data = load_brdf_json(input_path(args.file, "FILE"), args.material)
    except DataError as exc:        # the file named is no BRDF JSON: a refusal, exit 2
        raise BadInputFile(exc.file, exc.location, exc.message) from None
    with Store(args.store) as store:
        run_id = store_brdf(store, data, tilt_deg=args.tilt_deg)
    print(f"imported {len(data.theta_i_deg)} geometries × {len(data.wavelength_nm)} wavelengths "
          f"of {data.material!r} as run {run_id}")
    return 0


def _register_prediction(isub: argparse._SubParsersAction) -> None:
    p = isub.add_parser(
        "prediction", help="another renderer's predicted spectra of a reference run",
        description="CSV with patch,angle_deg,wavelength_nm,radiance_W_sr_m2_nm[,std_error] "
                    "(what a scene package's render_mitsuba.py writes), or a directory of "
                    "spectral EXRs pNN_s<angle>.exr. Checked against the reference run first "
                    "(configurations, wavelength grid in nm, finite non-negative radiance): "
                    "every problem in one line, nothing stored, exit 2. Then `normbox-lab compare "
                    "REF_RUN --renderer NAME`.")
    p.add_argument("file", metavar="FILE")
    p.add_argument("--ref-run", required=True, metavar="N")
    p.add_argument("--renderer", required=True, metavar="NAME")
    p.add_argument("--renderer-version", metavar="VERSION",
                   help="default: the file's '# renderer_version:' line")
    add_store_argument(p)
    p.set_defaults(handler=_import_prediction)


def _import_prediction(args: argparse.Namespace) -> int:
    import sys

    from normbox_lab.acquire.importers import import_prediction
    from normbox_lab.acquire.store import Store
    from normbox_lab.core.errors import one_line
    from normbox_lab.predict.renderers import PredictionFileError

    require_store(args.store)
    with Store(args.store) as store:
        input_path(args.file, "FILE", directory=True)      # after the store's own checks
        try:
            run_id, aid = import_prediction(store, args.file, args.ref_run, args.renderer,
                                            renderer_version=args.renderer_version)
        except PredictionFileError as exc:
            # every problem, in the one line of the refusal
            print(one_line(f"normbox-lab: {args.file}: {'; '.join(exc.problems)} (nothing "
                           "stored)"), file=sys.stderr)
            return exc.exit_code
    print(f"prediction of {args.renderer!r} for run {args.ref_run} stored as run {run_id} "
          f"(artifact {aid}); compare with `normbox-lab compare {args.ref_run} --renderer "
          f"{args.renderer}`")
    return 0
