"""``aes-planner dataset info|import``: inspect and convert posed-frame datasets."""

from __future__ import annotations

import argparse
import math

_OUTSIDE_HELP = (
    "let image and depth paths in the input leave its folder (absolute, '..', symlinks); only for files you trust"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dataset", help="inspect or import posed-frame datasets")
    dsub = p.add_subparsers(dest="dataset_command", metavar="ACTION", required=True)

    info = dsub.add_parser("info", help="summarise a dataset folder (images + cameras.json)")
    info.add_argument("path", help="dataset folder or its cameras.json")
    info.add_argument("--allow-outside-paths", action="store_true", help=_OUTSIDE_HELP)
    info.set_defaults(func=run_info)

    imp = dsub.add_parser("import", help="convert nerfstudio or RealEstate10K data into a dataset folder")
    imp.add_argument("kind", choices=["nerfstudio", "re10k"])
    imp.add_argument("path", help="transforms.json (nerfstudio) or the clip's camera .txt (re10k)")
    imp.add_argument("--frames", help="re10k: folder of frames named <timestamp>.png/.jpg")
    imp.add_argument(
        "--up",
        choices=["cameras", "keep"],
        help="world up: from the mean camera up, or keep (default: keep for nerfstudio, cameras for re10k)",
    )
    imp.add_argument("--every", type=int, default=1, help="re10k: keep every n-th frame")
    imp.add_argument("--out", required=True, help="output dataset folder")
    imp.add_argument("--allow-outside-paths", action="store_true", help=_OUTSIDE_HELP)
    imp.set_defaults(func=run_import)


def run_info(args: argparse.Namespace) -> int:
    from aes_planner.dataset import load_dataset
    from aes_planner.geometry import cam2world_to_view

    ds = load_dataset(args.path, allow_outside=args.allow_outside_paths)
    print(f"{len(ds)} frames in {ds.root}")
    if ds.meta:
        print(f"meta: {ds.meta}")
    for f in ds.frames:
        x, y, z, yaw, pitch = cam2world_to_view(f.cam2world)
        depth = "depth" if f.depth_m is not None else "-"
        print(
            f"{f.frame_id:>8} {f.width}x{f.height} fx={f.intrinsics.fx:.1f} t={f.stamp_s:.3f}s "
            f"xyz=({x:.3f}, {y:.3f}, {z:.3f}) yaw={math.degrees(yaw):.1f} pitch={math.degrees(pitch):.1f} {depth}"
        )
    return 0


def run_import(args: argparse.Namespace) -> int:
    from aes_planner.dataset import DatasetError, import_nerfstudio, import_re10k, save_dataset
    from aes_planner.dataset.folder import check_output_folder

    check_output_folder(args.out)  # before reading anything: a bad --out fails fast
    if args.kind == "nerfstudio":
        ds = import_nerfstudio(args.path, up=args.up or "keep", allow_outside=args.allow_outside_paths)
    else:
        if not args.frames:
            raise DatasetError("re10k import needs --frames DIR (the clip's frames named by timestamp)")
        ds = import_re10k(
            args.path, args.frames, up=args.up or "cameras", every=args.every, allow_outside=args.allow_outside_paths
        )
    path = save_dataset(args.out, ds.frames, meta=ds.meta)
    print(f"wrote {len(ds)} frames to {path.parent}")
    return 0
