"""`normbox-lab scene export REF_RUN --out DIR [--light-map RUN] [--store FILE]`."""

from __future__ import annotations

import argparse

from normbox_lab.commands.common import add_store_argument, require_store


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scene", help="renderer-neutral scene packages of a campaign")
    ssub = p.add_subparsers(dest="scene_command", metavar="ACTION")
    e = ssub.add_parser(
        "export", help="write the scene package of a reference run",
        description="Everything another renderer needs to predict a reference run: the box "
                    "per sample angle (OBJ), the light (CSV), the fitted BRDFs (JSON), the "
                    "radiometer's view, a Mitsuba 3 scene per configuration, the BSDF as a "
                    "stand-alone plugin, render_mitsuba.py and a README. Render it, then "
                    "`normbox-lab import prediction`.")
    e.add_argument("run", metavar="REF_RUN")
    e.add_argument("--out", required=True, metavar="DIR")
    e.add_argument("--light-map", metavar="RUN_ID",
                   help="the light-map run (default: what the prediction recorded, else the "
                        "latest finished light-map run)")
    add_store_argument(e)
    e.set_defaults(handler=_export)
    p.set_defaults(handler=lambda a: p.print_help() or 2)


def _export(args: argparse.Namespace) -> int:
    from pathlib import Path

    from normbox_lab.acquire.queries import scene_package_inputs
    from normbox_lab.acquire.store import Store
    from normbox_lab.predict.scene_package import write_scene_package

    require_store(args.store)
    with Store(args.store) as store:
        inputs = scene_package_inputs(store, args.run, light_map_run=args.light_map)
    s = write_scene_package(inputs, args.out)
    print(f"scene package of run {s.ref_run}: {len(s.configurations)} configurations, "
          f"{len(s.files)} files in {s.out_dir}")
    print(f"render: python {Path(s.out_dir) / 'render_mitsuba.py'} --spp 256 --out "
          "predictions.csv")
    return 0
