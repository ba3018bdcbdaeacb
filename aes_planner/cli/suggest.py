"""``aes-planner suggest DATASET_DIR``: suggest better views from a posed-frame folder (or from a folder of
photos without poses: the pose step runs first, :mod:`aes_planner.photos`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: What a suggestion computes with, imported with the program's start-up when the command runs
#: (:func:`aes_planner.cli.main`: under the start-up's garbage-collector settings, and frozen with
#: it; numba and the kernels would otherwise come in lazily at the first render, ~230 modules
#: walked by the collections of the build), not for ``--help``. ``bench search``'s import-only
#: process (``search.cold_suggest.imports_ms``) imports the same list.
PROGRAM_IMPORTS = (
    "aes_planner.dataset",
    "aes_planner.search",
    "aes_planner.search.report",
    "aes_planner.field.model",
    "aes_planner.teachers",
    "aes_planner.gaussians.kernels",
)


def register(sub: argparse._SubParsersAction) -> None:
    from aes_planner.photos.refine import RefineConfig
    from aes_planner.platform import HANDHELD, KIND_WORDS
    from aes_planner.search.config import PRESETS
    from aes_planner.search.scorers import SCORERS

    p = sub.add_parser(
        "suggest",
        help="suggest camera views with better composition from a posed-frame folder",
        description=(
            "Build the aesthetic field (or RGB scoring) from the folder's frames and run the two-stage view "
            "search: rig mode searches the gimbal's pan/tilt inside its limits (kinematics from the folder's "
            "metadata, as `sim render` writes it, or --rig FILE); free mode searches 5-DoF views inside the "
            "drone's box; handheld mode (a folder of photos without poses: `aes-planner pose` runs first) "
            "searches the region the photographer walked and says each suggestion from the nearest photo."
        ),
    )
    p.add_argument(
        "dataset",
        metavar="DATASET_DIR",
        help="folder with cameras.json and images/, or a folder of photos without poses (posed first)",
    )
    p.add_argument("--preset", default="balanced", choices=list(PRESETS), help="speed/accuracy")
    p.add_argument(
        "--mode",
        choices=[*KIND_WORDS, HANDHELD],
        help="platform: rig, drone (free: the older word for drone) or handheld (photos); default: the folder's "
        "platform (rig if it has none)",
    )
    p.add_argument("--rig", metavar="FILE", help="rig kinematics and joint limits as YAML (PanTiltConfig fields)")
    p.add_argument("--top", type=int, metavar="K", help="number of suggestions (default: the preset's K)")
    p.add_argument(
        "--scorer",
        choices=list(SCORERS),
        help="what scores views (default: the field; RGB scoring, with a warning, when this build has no field)",
    )
    p.add_argument(
        "--truth-scene",
        metavar="FILE_OR_FAMILY:SEED",
        help="render the report's ground-truth row from this scene (default: the folder's scene when `sim render` "
        "wrote it from FAMILY:SEED; a scene file named inside a folder is never opened)",
    )
    p.add_argument(
        "--keep",
        action="append",
        default=[],
        metavar="FRAME:X0,Y0,X1,Y1",
        help="keep this subject whole in the suggested view: a box in pixels of the input image FRAME (its file "
        "name as in cameras.json, e.g. 00003.png:21,0,61,36); repeatable (docs/guides/framing.md)",
    )
    p.add_argument(
        "--avoid",
        action="append",
        default=[],
        metavar="FRAME:X0,Y0,X1,Y1",
        help="steer away from views that show what this box shows (same form as --keep); repeatable",
    )
    p.add_argument(
        "--keep-at", choices=["centre", "thirds"], help="also prefer the kept subject at the centre or on the thirds"
    )
    p.add_argument(
        "--keep-margin",
        type=float,
        default=0.05,
        metavar="FRAC",
        help="the kept subject stays this fraction of the frame's width/height inside every edge (default 0.05)",
    )
    p.add_argument(
        "--photo-rank",
        action="store_true",
        help="with --keep: rank the views that hold the subject by the teacher on the input photos warped into "
        "them, not by the field alone (about ten times the search time; docs/guides/framing.md, "
        '"Ranked on the input photos")',
    )
    p.add_argument("--json", metavar="OUT", help="write the suggestions as JSON")
    p.add_argument("--out", metavar="DIR", help="write the report image (report.png) into DIR")
    p.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="CPU threads for torch and the rasterizer (default: the cores idle when it starts, so one beside "
        "a busy process on two cores; the count used is printed)",
    )
    photos = p.add_argument_group("photos without poses (DATASET_DIR holds only photos: `aes-planner pose` runs first)")
    photos.add_argument(
        "--posed",
        metavar="DIR",
        help="where the pose step writes the posed folder (default: OUT/posed with --out, else DATASET_DIR-posed "
        "beside the photos)",
    )
    photos.add_argument(
        "--scale-from",
        metavar="IMG_A,IMG_B,METRES",
        help="metric scale: the distance in metres between the cameras of two photos (file names)",
    )
    photos.add_argument(
        "--board", metavar="SPEC", help="metric scale from a calibration board in view (e.g. chessboard:9x6:0.025)"
    )
    photos.add_argument(
        "--margin",
        type=float,
        metavar="LENGTH",
        help="the hand-held search region's margin around the walked path (default: a quarter of the cameras' spread)",
    )
    photos.add_argument(
        "--refine-turn",
        type=float,
        default=RefineConfig.max_turn_deg,
        metavar="DEG",
        help="suggest first the best view within DEG of turn and tilt of the photos the teacher likes best, scored on "
        f"the photos warped into it (default {RefineConfig.max_turn_deg:g}; 0: the search's ranking alone)",
    )
    photos.add_argument(
        "--refine-at",
        type=int,
        default=RefineConfig.around_best,
        metavar="N",
        help=f"refine at the N photos the teacher likes best (default {RefineConfig.around_best})",
    )
    photos.add_argument(
        "--refine-forward",
        default=",".join(f"{f:g}" for f in RefineConfig.forward_fracs),
        metavar="FRACS",
        help="steps towards the subject tried there, as fractions of its distance (default "
        f"{','.join(f'{f:g}' for f in RefineConfig.forward_fracs)})",
    )
    photos.add_argument(
        "--refine-caution",
        type=float,
        default=RefineConfig.caution,
        metavar="K",
        help="rank the refined views by their predicted score less K times the estimate's expected error "
        f"(default {RefineConfig.caution:g}; 0: by the prediction alone)",
    )
    photos.add_argument(
        "--refine-min-gain",
        type=float,
        default=RefineConfig.min_gain,
        metavar="SCORE",
        help="trust a refined view only when that lower bound clears the best photo by SCORE; else suggestion #1 is "
        f"the fall-back (default {RefineConfig.min_gain:g})",
    )
    photos.add_argument(
        "--refine-fallback",
        choices=("turn", "photo"),
        default="turn" if RefineConfig.fallback_turn else "photo",
        help="when no refined view is trusted: the best photo as taken, turned and tilted on the spot when that "
        "clears it by the same lower bound, else the photo itself (turn); or always the photo itself (photo) "
        f"(default {'turn' if RefineConfig.fallback_turn else 'photo'})",
    )
    p.set_defaults(func=run)


def _pose_first(args: argparse.Namespace) -> str:
    """The posed-frame folder to read: DATASET_DIR itself when it has a cameras.json (or is not a folder of
    photos); otherwise the folder the pose step writes from its photos, said so on the way."""
    from aes_planner.photos.sfm import IMAGE_SUFFIXES

    src = Path(args.dataset)
    if not src.is_dir() or (src / "cameras.json").exists():
        return args.dataset
    if not any(f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES for f in src.iterdir()):
        return args.dataset  # the folder reader says what is missing
    from aes_planner.cli.pose import pose_config, run_pose

    cfg = pose_config(args)
    if args.posed:
        posed = Path(args.posed)
    elif args.out:
        posed = Path(args.out) / "posed"
    else:
        posed = src.resolve().parent / f"{src.resolve().name}-posed"  # "." names its folder
    print(f"{src}: photos without poses: running the pose step first (aes-planner pose {src} --out {posed})")
    run_pose(src, posed, cfg)
    return str(posed)


def _platform(meta: dict, frames, mode: str | None, rig_file: str | None):
    import numpy as np

    from aes_planner.config import from_dict, load_yaml
    from aes_planner.geometry.rig import PanTiltConfig
    from aes_planner.platform import (
        HANDHELD,
        DroneBox,
        DronePlatform,
        HandHeldPlatform,
        RigPlatform,
        parse_kind,
        platform_from_meta,
    )
    from aes_planner.search import SearchError

    k = frames[0].intrinsics
    stored = platform_from_meta(meta, k)
    kind = (
        parse_kind(mode, "--mode", allow_handheld=True)
        if mode
        else (stored.kind if stored is not None else RigPlatform.kind)
    )
    if stored is not None and stored.kind == kind and not rig_file:
        if stored.rig is not None and not meta.get("rig"):
            raise SearchError("meta.rig: empty; give the rig's PanTiltConfig fields or pass --rig FILE")
        return stored
    if kind == RigPlatform.kind:
        if rig_file:
            doc = load_yaml(rig_file)
            if not doc:
                raise SearchError(f"--rig {rig_file}: the file sets nothing; give the rig's PanTiltConfig fields")
            return RigPlatform(k, from_dict(PanTiltConfig, doc, "rig"))
        raise SearchError(
            "rig mode needs the rig's kinematics and joint limits: this folder's cameras.json meta has no 'rig' "
            "section; pass --rig FILE (YAML with PanTiltConfig fields) or use --mode drone"
        )
    if rig_file:
        log.warning("--rig %s is not used for a %s", rig_file, kind)
    if kind == HANDHELD:  # the region walked: within a margin of the paths between the inputs' cameras
        return HandHeldPlatform.around_photos(k, np.stack([f.cam2world for f in frames]))
    if stored is not None and stored.drone is not None:
        return stored
    pos = np.stack([f.cam2world[:3, 3] for f in frames])
    lo, hi = pos.min(0) - 1.0, pos.max(0) + 1.0
    log.warning("no drone box in the folder's metadata: searching the inputs' bounding box grown by 1 m")
    return DronePlatform(k, DroneBox(tuple(lo), tuple(hi)))


def print_table(result, top: int, framed: bool = False) -> None:
    shown = result.suggestions[:top]
    rig = bool(shown) and getattr(shown[0], "pan_rad", None) is not None  # joints: a rig's suggestions
    # positions far from the origin (a site's own coordinates) widen their columns rather than shift the row
    w = max([7] + [len(f"{v:.2f}") for s in shown for v in (() if rig else s.position_m)])
    head = "pan_deg tilt_deg" if rig else f"{'x_m':<{w}} {'y_m':<{w}} {'z_m':<{w}} yaw_deg pitch_deg"
    print(f" #  {head}  score   coverage  strongest terms")
    for i, s in enumerate(shown):
        if rig:
            where = f"{math.degrees(s.pan_rad):7.1f} {math.degrees(s.tilt_rad):8.1f}"
        else:
            x, y, z = s.position_m
            where = f"{x:{w}.2f} {y:{w}.2f} {z:{w}.2f} {math.degrees(s.yaw_rad):7.1f} {math.degrees(s.pitch_rad):9.1f}"
        terms = sorted(((k, v) for k, v in s.terms.items() if k != "score"), key=lambda kv: -kv[1])[:3]
        print(f"{i + 1:2d}  {where}  {s.score:6.3f}  {s.coverage:8.2f}  " + ", ".join(f"{k} {v:.2f}" for k, v in terms))
    print_coverage(result, rig, framed)


def print_coverage(result, rig: bool, framed: bool = False) -> None:
    """How much of the reachable space the inputs cover (``framed``: of the reachable views that
    hold the kept subjects), and the exploratory candidate: the best view may lie where no input
    looked (one shot cannot know it; capturing there can)."""
    if getattr(result, "covered_fraction", None) is None:  # none measured (explore_points 0, no view holds it)
        return
    which = "reachable views that hold the kept subject" if framed else "reachable views"
    line = f"the inputs cover {100 * result.covered_fraction:.0f} % of the {which}"
    e = result.explore
    if e is None:
        print(line)
        return
    if rig:
        where = f"pan {math.degrees(e.pan_rad):.1f} deg, tilt {math.degrees(e.tilt_rad):.1f} deg"
    else:
        x, y, z = e.position_m
        where = f"({x:.2f}, {y:.2f}, {z:.2f}) m, yaw {math.degrees(e.yaw_rad):.1f} deg, pitch {math.degrees(e.pitch_rad):.1f} deg"
    print(f"{line}; a better view may lie where no input looked: explore {where} (coverage {e.coverage:.2f})")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from aes_planner.dataset import load_dataset
    from aes_planner.messages.suggestion import MAX_CANDIDATES
    from aes_planner.platform import HANDHELD
    from aes_planner.runtime import suggestion_threads
    from aes_planner.search import SearchConfig, SearchError, build_search_scorer, search_views
    from aes_planner.search.report import render_with, write_report

    if args.top is not None and not 1 <= args.top <= MAX_CANDIDATES:
        raise SearchError(f"--top must be in [1, {MAX_CANDIDATES}], got {args.top}")
    if args.threads is not None:
        from aes_planner.runtime import MAX_THREADS, set_threads

        if not 1 <= args.threads <= MAX_THREADS:
            raise SearchError(f"--threads must be in [1, {MAX_THREADS}], got {args.threads}")
        set_threads(args.threads)
    from aes_planner.paths import output_file, output_folder, output_in

    if args.json:  # a bad destination fails before the search, not after it
        output_file(args.json, "--json")
    if args.out:
        output_in(output_folder(args.out, "--out"), "report.png")
    elif args.truth_scene:
        raise SearchError("--truth-scene renders the report's ground-truth row: give --out DIR for the report too")
    from aes_planner.images import MAX_WORKING_SIDE_PX

    framing_cfg, keep, avoid = _framing_args(args)  # a malformed box fails before the pose step and the search
    refine_cfg = _refine_args(args)
    args.dataset = _pose_first(args)
    data = load_dataset(args.dataset, load_depth=True, max_side_px=MAX_WORKING_SIDE_PX)
    for (w, h), n in data.downscaled.items():  # say so: the report shows the downscaled views
        print(
            f"{n} photo(s) of {w}x{h} px downscaled as read: the field works at {MAX_WORKING_SIDE_PX} px a side at most"
        )
    if not data.frames:
        raise SearchError(f"{args.dataset}: the folder has no frames")
    # the ground truth is set up before the search, so a bad --truth-scene fails first
    gt = _ground_truth(data.meta, data.frames[0].intrinsics, args.truth_scene) if args.out else None
    platform = _platform(data.meta, data.frames, args.mode, args.rig)
    overrides = {"top_k": args.top} if args.top else {}
    cfg = SearchConfig.preset(args.preset, mode=platform.kind, **overrides)
    t0 = time.perf_counter()
    kind = args.scorer or "field"
    with suggestion_threads() as job:  # --threads pinned the count; else fewer beside busy processes
        try:
            scorer = build_search_scorer(kind, data.frames, cfg)
        except SearchError as exc:
            if args.scorer:  # asked for explicitly: no silent substitute
                raise
            print(f"warning: {exc}; scoring with rgb instead")
            kind = "rgb"
            scorer = build_search_scorer(kind, data.frames, cfg)
        args.scorer = kind
        framing, refined = None, None
        if keep or avoid:
            from aes_planner.search.framing import build_framing, dataset_frames

            frames = dataset_frames(data.frames)
            framing = build_framing(scorer, frames, keep, avoid, platform.intrinsics, framing_cfg, data.frames)
            for line in framing.describe():
                print(f"framing: {line}")
        search_cfg = cfg
        if platform.kind == HANDHELD and not framing:  # more candidates, ranked again against the photos
            search_cfg = dataclasses.replace(cfg, top_k=MAX_CANDIDATES)
        result = search_views(scorer, data.cam2worlds(), platform, search_cfg, framing=framing)
        if platform.kind == HANDHELD and not framing:
            from aes_planner.photos.anchor import anchor_on_photos

            images = [f.image for f in data.frames]
            result.suggestions = anchor_on_photos(scorer, data.cam2worlds(), images, result.suggestions)
            refined = _refine(scorer, data, platform, refine_cfg)
            if refined is not None:
                result.suggestions = [refined["pick"], *result.suggestions]
    latency_ms = (time.perf_counter() - t0) * 1e3
    top = args.top or cfg.top_k
    print(f"{len(result.suggestions[:top])} suggestion(s), {result.mode} mode, preset {args.preset}, "
          f"scorer {args.scorer}, {latency_ms:.0f} ms, {job.threads} thread(s)")  # fmt: skip
    print_table(result, top, framed=framing is not None and bool(framing.keep))
    moves = _hand_held_moves(platform, data, result.suggestions[:top])
    if refined is not None:
        within = f"{refine_cfg.max_turn_deg:g} deg"
        if refined["confident"]:
            print(
                f"#1 refined at a photo the teacher likes best, {refined['photo']} (teacher {refined['photo_score']:.3f}): "
                f"predicted {refined['pick'].score:.3f} ({refined['top_gain']:+.3f}, at least "
                f"{refined['top_gain_low']:+.3f} after the estimate's expected error) on the photos warped into it, "
                f"best of {refined['candidates']} views within {within}"
            )
        else:
            pick = refined["pick"]
            how = (
                f"turned on the spot (predicted {pick.score:.3f}, {pick.terms['photo_gain']:+.3f}, at least "
                f"{pick.terms['photo_gain_low']:+.3f} on the photo itself turned)"
                if refined["kind"] == "turn"
                else "as taken"
            )
            print(
                f"#1 is the photo the teacher likes best, {refined['best_photo']} (teacher "
                f"{refined['best_photo_score']:.3f}), {how}: none of {refined['candidates']} views within {within} "
                f"cleared it by the estimate's expected error (the best predicted {refined['top_gain']:+.3f}, at least "
                f"{refined['top_gain_low']:+.3f}; needed {refine_cfg.min_gain:+.3f})"
            )
    if moves:
        unit = data.meta.get("unit", "m")
        if unit != "m":
            print(f"positions in units of {unit}")
        print(
            f"search space: hand-held, within {platform.margin_m:.2f} {'m' if unit == 'm' else 'units'} of the path "
            f"walked between the {len(platform.centres)} photos' cameras"
        )
        for i, move in enumerate(moves):
            print(f"#{i + 1} {move.text()}")
    if len(result.suggestions) < top:  # say what the search left out
        if result.dropped_uncovered:
            print(
                f"note: {result.dropped_uncovered} refined candidate(s) left out: their coverage fell below "
                f"{cfg.coverage_min:.2f} (views of space the inputs did not see are not suggested)"
            )
        if result.dropped_duplicates:
            print(f"note: {result.dropped_duplicates} refined candidate(s) left out: they converged onto a better one")
    if framing is not None and framing.cfg.photo_rank:
        best = result.best.terms if result.suggestions else {}
        if "photo" in best:
            print(f"#1 ranked on the input photos warped into it: teacher {best['photo']:.3f}, "
                  f"the photos cover {best['photo_cover']:.0%} of it")  # fmt: skip
        else:
            print(f"note: --photo-rank ranked nothing: the {args.scorer} scorer has no teacher or no view was covered")
    for w in result.warnings:
        print(f"warning: {w}")
    if args.json:
        doc = {
            "mode": result.mode,
            "preset": args.preset,
            "scorer": args.scorer,
            "latency_ms": latency_ms,
            "suggestions": [s.to_json() for s in result.suggestions[:top]],
            "covered_fraction": result.covered_fraction,  # of the reachable views (holding the kept subject), the share the inputs cover
            "explore": None if result.explore is None else result.explore.to_json(),  # where no input looked
        }
        if moves:  # the frame of the poses the pose step wrote, and each view from its nearest photo
            doc["posed_folder"] = str(data.root)
            doc["unit"] = data.meta.get("unit", "m")
            doc["frame"] = data.meta.get("frame", "the posed folder's frame")
            doc["search_space"] = {"kind": "handheld", "margin": platform.margin_m, "cameras": len(platform.centres)}
            for entry, move in zip(doc["suggestions"], moves):
                entry["from_photo"] = move.to_json()
            if refined is not None:  # #1: a refined view (trusted), the best photo turned, or as taken
                doc["suggestions"][0]["refined"] = refined["kind"] == "refined"
                doc["suggestions"][0]["turned"] = refined["kind"] == "turn"
                doc["suggestions"][0]["as_taken"] = refined["kind"] == "as_taken"
                doc["refine"] = {
                    "confident": refined["confident"],
                    "kind": refined["kind"],
                    "photo": refined["photo"],
                    "photo_score": refined["photo_score"],
                    "best_photo": refined["best_photo"],
                    "best_photo_score": refined["best_photo_score"],
                    "candidates": refined["candidates"],
                    "top_gain": refined["top_gain"],
                    "top_gain_low": refined["top_gain_low"],
                    **dataclasses.asdict(refine_cfg),
                }
        if framing is not None:
            doc["keep"] = [s.to_json() for s in framing.keep]
            doc["avoid"] = [s.to_json() for s in framing.avoid]
            doc["keep_margin"] = framing.cfg.margin_frac
            doc["photo_rank"] = framing.cfg.photo_rank
        Path(args.json).write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
    if args.out:
        renderers, scores, row_labels = {}, {}, {}
        poses = np.stack([s.cam2world for s in result.suggestions])  # [K, 4, 4] world
        if moves:  # the photo each suggestion is said from, beside the suggested view
            every = _hand_held_moves(platform, data, result.suggestions)
            renderers["from photo"] = lambda _poses: [data.frames[m.photo_index].image for m in every]
            row_labels["from photo"] = [f"#{i + 1} {m.photo}" for i, m in enumerate(every)]
        own = render_with(scorer)
        if own is not None:
            renderers[args.scorer] = own
        if args.scorer != "rgb":
            rgb_scorer = build_search_scorer("rgb", data.frames, cfg)
            rgb = render_with(rgb_scorer)
            if rgb is not None:
                renderers["rgb"] = rgb
                scores["rgb"] = _scores(rgb_scorer, poses)
        if gt is not None:
            truth_images = gt(poses)  # [K, H, W, 3] uint8, rendered once for the score and the report
            renderers["truth"] = lambda _poses: truth_images
            scores["truth"] = _teacher_scores(scorer, truth_images)
            print(
                "ground truth (the teacher on the simulator's render at each suggestion): "
                + ", ".join(f"#{i + 1} {v:.3f}" for i, v in enumerate(scores["truth"][:top]))
            )
        report = write_report(
            output_in(args.out, "report.png"),
            [f.image for f in data.frames],
            result,
            renderers,
            scores=scores,
            outlines=_outlines(framing, data.frames) if framing is not None else None,
            labels=row_labels,
        )
        print(f"wrote {report}")
    return 0


def _refine_args(args):
    """``--refine-turn``/``--refine-forward`` -> RefineConfig, checked before anything is loaded."""
    from aes_planner.config import ConfigError
    from aes_planner.photos.refine import RefineConfig
    from aes_planner.search import SearchError

    try:
        fracs = tuple(float(t) for t in str(args.refine_forward).split(","))
    except ValueError:
        raise SearchError(
            f"--refine-forward: {args.refine_forward!r} is not a comma-separated list of fractions (e.g. 0,0.1,0.2)"
        ) from None
    try:
        return RefineConfig(
            max_turn_deg=args.refine_turn,
            forward_fracs=fracs,
            around_best=args.refine_at,
            caution=args.refine_caution,
            min_gain=args.refine_min_gain,
            fallback_turn=args.refine_fallback == "turn",
        )
    except ConfigError as exc:
        flags = {
            "forward_fracs": "--refine-forward",
            "around_best": "--refine-at",
            "caution": "--refine-caution",
            "min_gain": "--refine-min-gain",
        }
        flag = next((f for key, f in flags.items() if key in str(exc)), "--refine-turn")
        raise SearchError(f"{flag}: {exc}") from None


def _refine(scorer, data, platform, cfg) -> dict | None:
    """Suggestion #1 near the photos the teacher likes best
    (:func:`aes_planner.photos.refine.refine_at_best_photo`): the best refined view when its lower
    bound clears the best photo, else that photo as taken; None when off or nothing was tried."""
    if not cfg.enabled:
        return None
    from aes_planner.photos.refine import refine_at_best_photo
    from aes_planner.teachers import get_teacher

    teacher = getattr(scorer, "teacher", None) or get_teacher()
    images = [f.image for f in data.frames]
    found = refine_at_best_photo(teacher, data.cam2worlds(), images, data.frames[0].intrinsics, cfg, platform)
    if found.pick is None:
        log.info("refinement at the best photos tried no view")
        return None
    names = _photo_names(data)
    top = found.suggestions[0]
    at = int(found.photo_of[0]) if found.confident else found.best_photo
    return {
        "pick": found.pick,
        "kind": found.kind,  # refined / turn / as_taken
        "confident": found.confident,
        "photo": names[at],
        "photo_score": float(found.photo_scores[at]),
        "best_photo": names[found.best_photo],
        "best_photo_score": float(found.photo_scores[found.best_photo]),
        "candidates": len(found.suggestions),
        "top_gain": top.terms["photo_gain"],  # the first-ranked view's predicted gain and its lower bound
        "top_gain_low": top.terms["photo_gain_low"],
    }


def _hand_held_moves(platform, data, suggestions) -> list:
    """Each suggestion as a move from the nearest input photo (a hand-held platform only; else [])."""
    from aes_planner.photos import moves_from_photos
    from aes_planner.platform import HANDHELD

    if platform.kind != HANDHELD or not suggestions:
        return []
    import numpy as np

    unit = data.meta.get("unit", "m")
    targets = np.stack([s.cam2world for s in suggestions])  # [K, 4, 4]
    return moves_from_photos(targets, data.cam2worlds(), _photo_names(data), "m" if unit == "m" else str(unit))


def _photo_names(data) -> list[str]:
    """The input photos' file names (the pose step's ``photos`` list), else the frames' ids."""
    names = data.meta.get("photos")
    if isinstance(names, list) and len(names) == len(data.frames) and all(isinstance(n, str) for n in names):
        return names
    return [f.frame_id or f"input {i + 1}" for i, f in enumerate(data.frames)]


def _framing_args(args):
    """``--keep``/``--avoid``/``--keep-at``/``--keep-margin``/``--photo-rank`` -> (FramingConfig, keep,
    avoid), checked before anything is loaded."""
    from aes_planner.config import ConfigError
    from aes_planner.search.framing import FramingConfig, FramingError, Region

    keep = [Region.parse(t, "--keep") for t in args.keep]
    avoid = [Region.parse(t, "--avoid") for t in args.avoid]
    if args.keep_at and not keep:
        raise FramingError("--keep-at places the kept subject: give the subject with --keep FRAME:X0,Y0,X1,Y1")
    if args.photo_rank and not keep:
        raise FramingError(
            "--photo-rank ranks the views that hold a kept subject: give it with --keep FRAME:X0,Y0,X1,Y1"
        )
    try:
        cfg = FramingConfig(margin_frac=args.keep_margin, keep_at=args.keep_at, photo_rank=args.photo_rank)
    except ConfigError as exc:
        raise FramingError(f"--keep-margin: {exc}") from None
    return cfg, keep, avoid


def _outlines(framing, frames) -> dict:
    """What the report outlines: each region's box in its input image, each subject's 3D box."""
    from aes_planner.search.framing import frame_index

    index = frame_index(frames)
    boxes = []
    for kind, subjects in (("keep", framing.keep), ("avoid", framing.avoid)):
        for s in subjects:
            f = frames[index[s.region.frame]]
            w, h = f.extras.get("stored_size", (f.intrinsics.width, f.intrinsics.height))
            sx, sy = f.image.shape[1] / w, f.image.shape[0] / h
            r = s.region.scaled(sx, sy)
            boxes.append((index[s.region.frame], kind, (r.x0, r.y0, r.x1, r.y1)))
    return {"input_boxes": boxes, "framing": framing}


def _scores(scorer, poses) -> list[float]:
    """A scorer's own scores of poses ``[K, 4, 4]`` (no gradients)."""
    import torch

    with torch.no_grad():
        return scorer.score(torch.as_tensor(poses, dtype=torch.float64)).score.double().tolist()


def _teacher_scores(scorer, images) -> list[float]:
    """The search's teacher's scores of RGB ``images [K, H, W, 3]`` uint8."""
    import numpy as np
    import torch

    from aes_planner.teachers import get_teacher

    teacher = getattr(scorer, "teacher", None) or get_teacher()
    x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float() / 255.0  # [K, 3, H, W]
    with torch.no_grad():
        return teacher.score(x).double().tolist()


def _ground_truth(meta: dict, intrinsics, truth_scene: str | None = None):
    """Ground-truth renders for the report: from ``truth_scene`` (the user's own argument), else
    from the scene `sim render` named in the folder's metadata when that is FAMILY:SEED."""
    import numpy as np

    from aes_planner.search import SearchError
    from aes_planner.sim import SimSource

    scene = truth_scene
    if scene is None:
        if meta.get("source") != "aes-planner sim render" or not meta.get("scene"):
            return None
        import re

        if not isinstance(meta["scene"], str) or not re.fullmatch(r"[a-z_]+:[0-9]{1,18}", meta["scene"]):
            # a file named by a data file is not read (it could be anywhere): families only
            log.info(
                "no ground truth in the report: the folder's scene %.80r is not FAMILY:SEED (give it with --truth-scene)",
                meta["scene"],
            )
            return None
        scene = meta["scene"]
    try:
        source = SimSource(scene, supersample=2)
    except Exception as exc:
        if truth_scene is not None:  # asked for: say so rather than quietly leave the row out
            raise SearchError(f"--truth-scene {truth_scene!r}: {exc}") from exc
        log.warning("no ground truth in the report: %s", exc)
        return None
    return lambda poses: (source.render_rgb(poses, intrinsics) * 255).round().astype(np.uint8)
