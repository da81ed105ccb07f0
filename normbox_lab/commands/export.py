"""`normbox-lab export RUN_ID --format netcdf|csv|json [-o PATH] [--store FILE]`."""

from __future__ import annotations

import argparse

from normbox_lab.commands.common import add_store_argument, output_path, require_store


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="export a run to NetCDF, CSV or JSON",
                       description="Export one run (id or uuid prefix). NetCDF through xarray "
                                   "with wavelength coordinates; CSV in long form; JSON with "
                                   "the run's provenance and events.")
    p.add_argument("run", metavar="RUN_ID",
                   help="the run to export: its id or a prefix of its uuid (normbox-lab runs)")
    p.add_argument("--format", required=True, choices=("netcdf", "csv", "json"))
    p.add_argument("-o", "--output", metavar="PATH", help="default: run-ID-PROTOCOL.EXT")
    add_store_argument(p)
    p.set_defaults(handler=_export)


def _export(args: argparse.Namespace) -> int:

    from normbox_lab.acquire.export import export_run
    from normbox_lab.acquire.store import Store

    require_store(args.store)
    if args.output is not None:
        output_path(args.output, "-o")
    with Store(args.store, read_only=True) as store:
        out = export_run(store, args.run, args.format, args.output)
    print(f"wrote {out}")
    return 0
