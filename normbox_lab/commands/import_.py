"""`normbox-lab import brdf-json FILE [--material NAME] [--tilt-deg 4] [--store FILE]`."""

from __future__ import annotations

import argparse

from normbox_lab.commands.common import add_store_argument


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
    b.add_argument("--tilt-deg", type=float, default=0.0,
                   help="out-of-plane tilt of the arms during that measurement")
    add_store_argument(b)
    b.set_defaults(handler=_import_brdf)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _import_brdf(args: argparse.Namespace) -> int:
    from normbox_lab.acquire.importers import load_brdf_json, store_brdf
    from normbox_lab.acquire.store import Store

    data = load_brdf_json(args.file, args.material)
    with Store(args.store) as store:
        run_id = store_brdf(store, data, tilt_deg=args.tilt_deg)
    print(f"imported {len(data.theta_i_deg)} geometries × {len(data.wavelength_nm)} wavelengths "
          f"of {data.material!r} as run {run_id}")
    return 0
