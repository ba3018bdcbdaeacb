"""``aes-planner pose IMAGES --out POSED``: pose a folder of photos by structure from motion (pycolmap)."""

from __future__ import annotations

import argparse
import json
import math


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "pose",
        help="pose a folder of ordinary photos (structure from motion with pycolmap) into a posed-frame folder",
        description=(
            "Structure from motion with pycolmap (SIFT features, exhaustive matching, incremental mapping with "
            "bundle adjustment): one shared camera when the photos say one camera took them (size, EXIF), "
            "distortion estimated and removed. Writes the posed-frame folder `suggest` reads (images/, "
            "cameras.json) and a nerfstudio transforms.json beside it, levelled (z up), in metres when a scale is "
            "given (--scale-from or --board), else in units of the distance between the first two photos."
        ),
    )
    p.add_argument("images", metavar="IMAGES", help="a folder of photos (JPEG, PNG, ...), at least 3, walking around")
    p.add_argument("--out", metavar="POSED", required=True, help="the posed-frame folder to write")
    p.add_argument("--json", metavar="FILE", help="write the report (registered, reprojection error, poses) as JSON")
    p.add_argument(
        "--scale-from",
        metavar="IMG_A,IMG_B,METRES",
        help="metric scale: the distance in metres between the cameras of two photos (file names)",
    )
    p.add_argument(
        "--board",
        metavar="SPEC",
        help="metric scale from a calibration board in view of two or more photos (e.g. chessboard:9x6:0.025)",
    )
    p.add_argument(
        "--max-side",
        type=int,
        default=1024,
        metavar="PX",
        help="photos are downscaled to this many pixels a side on the way in (default 1024)",
    )
    p.add_argument(
        "--margin",
        type=float,
        metavar="LENGTH",
        help="the hand-held search region's margin around the walked path, in the output's unit "
        "(default: a quarter of the cameras' spread)",
    )
    p.set_defaults(func=run)


def parse_scale_from(text: str) -> tuple[str, str, float]:
    """``IMG_A,IMG_B,METRES`` -> ``(a, b, metres)``; a :class:`~aes_planner.photos.PoseError` saying the form."""
    from aes_planner.photos import PoseError

    parts = [t.strip() for t in str(text).split(",")]
    try:
        metres = float(parts[2]) if len(parts) == 3 else math.nan
    except ValueError:
        metres = math.nan
    if len(parts) != 3 or not parts[0] or not parts[1] or not (math.isfinite(metres) and metres > 0):
        raise PoseError(
            f"--scale-from {text!r}: write IMG_A,IMG_B,METRES (two photos' file names and the distance in metres "
            "between where they were taken, e.g. IMG_0001.jpg,IMG_0005.jpg,1.2)"
        )
    return parts[0], parts[1], metres


def pose_config(args: argparse.Namespace):
    """The :class:`~aes_planner.photos.PoseConfig` of ``pose``'s (and ``suggest``'s) options."""
    from aes_planner.calibrate.board import parse_board
    from aes_planner.config import ConfigError
    from aes_planner.photos import PoseConfig, PoseError

    try:
        return PoseConfig(
            max_side_px=getattr(args, "max_side", 1024),
            scale_from=parse_scale_from(args.scale_from) if args.scale_from else None,
            board=parse_board(args.board) if args.board else None,
            margin_m=args.margin,
        )
    except ConfigError as exc:
        flag = {"scale_from": "--scale-from", "max_side_px": "--max-side", "margin_m": "--margin"}.get(exc.key, exc.key)
        raise PoseError(f"{flag}: {exc.message}") from None


def run_pose(images, out, cfg, quiet: bool = False):
    """Run the pose step with a progress bar; print the one-paragraph report; returns the result."""
    from tqdm import tqdm

    from aes_planner.photos import pose_images

    bars = []  # opened at the first progress report: bad input is refused before, on one clean line

    def progress(stage: str, done: int, total: int) -> None:
        if not bars:
            bars.append(tqdm(total=total, unit="photo", desc="pose", leave=False, disable=quiet))
        bar = bars[0]
        bar.set_description(f"pose: {stage}")
        if bar.total != total:
            bar.reset(total=total)
        bar.n = done
        bar.refresh()

    try:
        result = pose_images(images, out, cfg, progress=progress)
    finally:
        for bar in bars:
            bar.close()
    print(
        f"posed {len(result.registered)} of {result.total} photos ({result.cameras} camera(s)), mean reprojection "
        f"error {result.mean_reprojection_px:.2f} px, {result.time_s:.1f} s"
    )
    if result.unregistered:
        print(f"not registered: {', '.join(result.unregistered)}")
    if result.other_models:
        print(f"note: {len(result.other_models)} smaller group(s) of photos did not connect to the rest (left out)")
    print(f"unit: {'metres (' + result.scale_source + ')' if result.metric else result.unit}")
    print(f"up: {result.gravity}")
    return result


def run(args: argparse.Namespace) -> int:
    from aes_planner.paths import output_file

    if args.json:
        output_file(args.json, "--json")
    result = run_pose(args.images, args.out, pose_config(args))
    print(f"wrote {result.out_dir / 'cameras.json'} and {result.out_dir / 'transforms.json'}")
    if args.json:
        from pathlib import Path

        Path(args.json).write_text(json.dumps(result.to_json(), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0
