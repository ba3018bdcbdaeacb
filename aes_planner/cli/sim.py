"""``aes-planner sim render|families``: render simulated scenes into dataset folders."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="the synthetic camera simulator")
    ssub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)

    r = ssub.add_parser(
        "render",
        help="render a scene from poses spread over the rig's joint range (or the drone's box) into a dataset folder",
    )
    r.add_argument("--scene", required=True, metavar="FILE_OR_FAMILY:SEED", help="a scene YAML file, or e.g. indoor:3")
    r.add_argument("--views", type=int, default=4, help="number of views (default 4)")
    r.add_argument("--out", required=True, help="output dataset folder (images + cameras.json)")
    r.add_argument("--width", type=int, help="override the scene camera's width in pixels")
    r.add_argument("--height", type=int, help="override the scene camera's height in pixels")
    r.add_argument("--supersample", type=int, default=2, help="anti-aliasing samples per pixel side (default 2)")
    r.add_argument("--no-depth", action="store_true", help="do not write depth files")
    r.add_argument("--contact-sheet", action="store_true", help="also write contact_sheet.png (RGB over depth)")
    r.add_argument(
        "--allow-outside-paths",
        action="store_true",
        help="let the scene file's image paths leave its folder (absolute, '..', symlinks); only for files you trust",
    )
    r.set_defaults(func=run_render)

    f = ssub.add_parser("families", help="list the procedural scene families")
    f.set_defaults(func=run_families)


def run_render(args: argparse.Namespace) -> int:
    from aes_planner.sim import render_survey

    out = render_survey(
        args.scene,
        args.views,
        args.out,
        args.width,
        args.height,
        args.supersample,
        depth=not args.no_depth,
        contact_sheet=args.contact_sheet,
        allow_outside=args.allow_outside_paths,
    )
    print(f"wrote {args.views} views of {args.scene} to {out}")
    return 0


def run_families(args: argparse.Namespace) -> int:
    from aes_planner.sim import FAMILIES

    for name, fn in FAMILIES.items():
        doc = (fn.__doc__ or "").strip().splitlines()
        print(f"{name:10s} {doc[0] if doc else ''}")
    return 0
