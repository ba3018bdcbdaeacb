"""``aes-planner eval field|search|loop``: the paper's experiments and the closed loop on held-out simulated scenes."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="run the paper's experiments on simulated scenes (tables and plots)")
    esub = p.add_subparsers(dest="eval_command", metavar="EXPERIMENT", required=True)
    register_field(esub)
    register_search(esub)
    register_loop(esub)
    register_framing(esub)


def _int_list(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def register_field(esub: argparse._SubParsersAction) -> None:
    from aes_planner.field.protocol import SOURCES

    f = esub.add_parser("field", help="novel-view aesthetic prediction: rgb, splat, field_nocond, field")
    f.add_argument("--scenes", type=int, default=4, help="held-out family scenes (default 4; ignored with --scene)")
    f.add_argument("--views", default="2,4,6", help="input view counts, comma separated (default 2,4,6)")
    f.add_argument(
        "--source",
        choices=SOURCES,
        default="rig",
        help="inputs: rig (a partial pan sweep, RGB), free (a sideways trajectory with depth), sweep (the rig's "
        "survey sweep, as sim render and the planner take it) or survey (free flight in a box around the rig)",
    )
    f.add_argument(
        "--scene", action="append", metavar="FILE_OR_FAMILY:SEED", help="evaluate on this scene (repeatable)"
    )
    f.add_argument("--targets", type=int, default=100, help="held-out poses per trajectory (default 100)")
    f.add_argument("--model", metavar="FILE", help="field checkpoint (default: the shipped one)")
    f.add_argument("--nocond-model", metavar="FILE", help="checkpoint without view conditioning (default: shipped)")
    f.add_argument("--render-width", type=int, default=None, help="render width in pixels (default: the scorer's)")
    f.add_argument("--json", metavar="OUT", help="write the summary JSON here")
    f.add_argument(
        "--out", metavar="DIR", default="runs/eval_field", help="markdown table and plots (default runs/eval_field)"
    )
    f.set_defaults(func=run_field)


def register_search(esub: argparse._SubParsersAction) -> None:
    s = esub.add_parser(
        "search",
        help="suggestion quality against an exhaustive ground-truth oracle and the baselines (Tables 2-4, S1)",
    )
    s.add_argument("--scene", action="append", metavar="FILE_OR_FAMILY:SEED", help="a scene (repeatable)")
    s.add_argument("--scenes", type=int, default=4, help="number of held-out scenes when no --scene (default 4)")
    s.add_argument("--views", type=_int_list, default=[4], help="input view counts, e.g. 2,4,6 (default 4)")
    s.add_argument("--modes", default="rig,drone", help="rig, drone or rig,drone (default both; free is read as drone)")
    s.add_argument("--methods", help="comma-separated subset of the methods (default all)")
    s.add_argument("--no-ablations", action="store_true", help="skip Tables 3, 4 and S1")
    s.add_argument("--oracle-step-deg", type=float, default=5.0, help="rig oracle grid step (default 5)")
    s.add_argument(
        "--search-seed",
        type=int,
        default=0,
        help="sampling seed of the searches (default 0); the oracle keeps its own: run several for the spread over seeds",
    )
    s.add_argument("--json", metavar="OUT", help="write the results as JSON")
    s.add_argument("--out", metavar="DIR", help="write markdown tables and plots into DIR")
    s.add_argument(
        "--from-json",
        metavar="FILE",
        help="run nothing: print the tables (and the preset front) of an earlier --json result, plots into --out",
    )
    s.set_defaults(func=run_search)


def register_loop(esub: argparse._SubParsersAction) -> None:
    from aes_planner.eval.loop import DEFAULT_PERTURBATIONS

    lp = esub.add_parser(
        "loop",
        help="the closed loop on many scenes under small perturbations (backend, threads, noise, seeds): "
        "oracle-normalised score, moves and spread per scene",
    )
    lp.add_argument(
        "--scene",
        action="append",
        metavar="FILE_OR_FAMILY:SEED[@drone]",
        help="a scene (repeatable; default the held-out loop set)",
    )
    lp.add_argument(
        "--set-name",
        choices=("heldout", "dev"),
        default="heldout",
        help="the scene set when no --scene: heldout (never tuned on) or dev (for tuning); default heldout",
    )
    lp.add_argument(
        "--perturb",
        action="append",
        metavar="P",
        help="a perturbation: base, torch, numba, threads:N, noise:R, seed:N, joined with + (repeatable; default "
        + " ".join(DEFAULT_PERTURBATIONS)
        + ")",
    )
    lp.add_argument("--moves", type=int, default=4, help="suggestion-driven moves at most (default 4)")
    lp.add_argument(
        "--set", action="append", default=[], metavar="ID.KEY=VALUE", help="launch-file override for every run"
    )
    lp.add_argument("--timeout", type=float, default=900.0, help="per run, seconds (default 900)")
    lp.add_argument(
        "--out",
        default="runs/eval_loop",
        metavar="DIR",
        help="results.json (resumed) and report.md (default runs/eval_loop)",
    )
    from aes_planner.cli.processes import add_clock_flag

    add_clock_flag(lp, "sim (a real gimbal, --set gimbal.emulate=false, needs wall)")
    lp.set_defaults(func=run_loop)


def run_loop(args: argparse.Namespace) -> int:
    from aes_planner.eval.loop import (
        DEFAULT_PERTURBATIONS,
        DEV_LOOP_SCENES,
        HELD_OUT_LOOP_SCENES,
        LoopEvalConfig,
        run_loop_eval,
        split_scene,
    )
    from aes_planner.paths import output_folder

    scenes = args.scene or (HELD_OUT_LOOP_SCENES if args.set_name == "heldout" else DEV_LOOP_SCENES)
    _check_scenes([split_scene(s)[0] for s in scenes])
    out = output_folder(args.out, "--out")
    cfg = LoopEvalConfig(
        scenes=list(scenes),
        perturbations=args.perturb or list(DEFAULT_PERTURBATIONS),
        moves=args.moves,
        timeout_s=args.timeout,
        sets=args.set,
    )
    import functools

    from aes_planner.cli.demo import run_demo

    results = run_loop_eval(cfg, Path(out), functools.partial(run_demo, clock=args.clock), progress=print)
    print((Path(out) / "report.md").read_text())
    s = results["summary"]
    return 0 if s.get("errors", 1) == 0 else 1


def register_framing(esub: argparse._SubParsersAction) -> None:
    from aes_planner.platform import KIND_WORDS
    from aes_planner.search.config import PRESETS

    f = esub.add_parser(
        "framing",
        help="suggest --keep: how often the suggestion holds a scene object whole, and its score against the best "
        "view that holds it (a constrained oracle)",
    )
    f.add_argument("--scene", action="append", metavar="FILE_OR_FAMILY:SEED", help="a scene (repeatable)")
    f.add_argument("--scenes", type=int, default=4, help="number of held-out scenes when no --scene (default 4)")
    f.add_argument("--seeds", type=_int_list, default=[0, 1], help="subjects per scene: 0,1 = the two largest")
    f.add_argument("--subject", action="append", metavar="NAME",
                   help="the scene object of this name as the subject (repeatable), boxed in the input view that "
                   "shows most of it, whatever the subject rules say; replaces --seeds")  # fmt: skip
    f.add_argument("--mode", default="rig", choices=KIND_WORDS, help="platform (default rig)")
    f.add_argument("--preset", default="balanced", choices=list(PRESETS), help="search preset")
    f.add_argument("--keep-margin", type=float, default=0.05, metavar="FRAC", help="as suggest --keep-margin")
    f.add_argument("--verify-top", type=int, default=0, metavar="N",
                   help="stage-1 candidates verified beside the refined ones by the teacher on rendered RGB (default 0: off)")  # fmt: skip
    f.add_argument("--verify-weight", type=float, default=1.0, metavar="W",
                   help="weight of the verified score against the field's in the final ranking (default 1)")  # fmt: skip
    f.add_argument("--coverage-min", type=float, default=None, metavar="FRAC",
                   help="the coverage rule's threshold while a subject is kept (default: FramingConfig's, 0.5)")  # fmt: skip
    f.add_argument("--coverage-penalty", type=float, default=None, metavar="W",
                   help="the coverage rule's weight while a subject is kept (default: FramingConfig's, 0.5; "
                   "the search's own rule, before 2026-11-29: --coverage-min 0.7 --coverage-penalty 2)")  # fmt: skip
    f.add_argument("--photo-rank", action=argparse.BooleanOptionalAction, default=None,
                   help="rank the views that hold the subject by the teacher on the input images warped into them "
                   "(default: FramingConfig's, off: on the held-out scenes it lowered the teacher's score; docs/guides/framing.md)")  # fmt: skip
    f.add_argument("--hold-by", default=None, choices=["points", "box"],
                   help="what a view must hold of the subject: the lifted points' outline (default) or the corners "
                   "of its 3D box (the rule before 2026-11-29; docs/results/framing_lift_views_dev.md)")  # fmt: skip
    f.add_argument("--json", metavar="OUT", help="write the results as JSON")
    f.add_argument("--figure", metavar="PNG", help="write a figure: input box, suggestion, constrained oracle per case")
    f.set_defaults(func=run_framing)


def run_framing(args: argparse.Namespace) -> int:
    from aes_planner.config import ConfigError
    from aes_planner.eval.framing import FramingEvalConfig, markdown, run_framing_eval
    from aes_planner.eval.search import HELD_OUT_SCENES
    from aes_planner.paths import output_file

    if not args.scene and not 1 <= args.scenes <= len(HELD_OUT_SCENES):
        raise ConfigError(
            "--scenes", f"must be in [1, {len(HELD_OUT_SCENES)}] (the held-out scenes), got {args.scenes}"
        )
    scenes = args.scene or HELD_OUT_SCENES[: args.scenes]
    _check_scenes(scenes)
    if args.json:
        output_file(args.json, "--json")
    if args.figure:
        output_file(args.figure, "--figure")
    cfg = FramingEvalConfig(
        scenes=scenes, seeds=args.seeds, subjects=args.subject or [], mode=args.mode, preset=args.preset, keep_margin=args.keep_margin,
        verify_top=args.verify_top, verify_weight=args.verify_weight,
        **{k: v for k, v in (("coverage_min", args.coverage_min), ("coverage_penalty", args.coverage_penalty),
                             ("photo_rank", args.photo_rank), ("hold_by", args.hold_by)) if v is not None},
    )  # fmt: skip
    doc = run_framing_eval(cfg, progress=lambda text: log.info("eval framing: %s", text), figure=args.figure)
    print(markdown(doc))
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1, default=float) + "\n")
        print(f"wrote {args.json}")
    return 0


def run_search(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from aes_planner.config import ConfigError
    from aes_planner.eval.search import HELD_OUT_SCENES, METHODS, SearchEvalConfig, markdown, run_search_eval
    from aes_planner.paths import output_file, output_folder

    if not args.scene and not 1 <= args.scenes <= len(HELD_OUT_SCENES):
        raise ConfigError(
            "--scenes", f"must be in [1, {len(HELD_OUT_SCENES)}] (the held-out scenes), got {args.scenes}"
        )
    if args.from_json:
        from aes_planner.eval.search import write_front_plots

        doc = _read_json(args.from_json, "--from-json")
        print(markdown(doc))
        if args.out:
            for path in write_front_plots(doc, output_folder(args.out, "--out")):
                print(f"wrote {path}")
        return 0
    scenes = args.scene or HELD_OUT_SCENES[: args.scenes]
    _check_scenes(scenes)
    if args.json:  # bad destinations fail before the evaluation, not after it
        output_file(args.json, "--json")
    if args.out:
        output_folder(args.out, "--out")
    cfg = SearchEvalConfig(
        scenes=scenes,
        views=args.views,
        modes=[m.strip() for m in args.modes.split(",") if m.strip()],
        methods=[m.strip() for m in args.methods.split(",")] if args.methods else list(METHODS),
        ablations=not args.no_ablations,
        oracle_step_deg=args.oracle_step_deg,
        search_seed=args.search_seed,
    )
    bar = tqdm(desc="eval search", unit="step", leave=False)

    def progress(text: str) -> None:
        bar.set_postfix_str(text)
        bar.update()

    doc = run_search_eval(cfg, out_dir=args.out, progress=progress)
    bar.close()
    print(markdown(doc))
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def run_field(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from aes_planner.errors import AesPlannerError
    from aes_planner.eval.field import FieldEvalConfig, default_scenes, evaluate_field, write_report
    from aes_planner.field.common import ScorerConfig
    from aes_planner.field.model import NOCOND_CHECKPOINT, load_model
    from aes_planner.sim import SimSource
    from aes_planner.teachers import get_teacher

    try:
        views = [int(v) for v in args.views.split(",") if v.strip()]
    except ValueError:
        raise AesPlannerError(f"--views must be comma-separated integers like 2,4,6, got {args.views!r}") from None
    scorer = ScorerConfig(**({"render_width_px": args.render_width} if args.render_width is not None else {}))
    config = FieldEvalConfig(source=args.source, views=views, targets=args.targets, scorer=scorer)
    from aes_planner.config import ConfigError, distinct
    from aes_planner.paths import output_file, output_folder

    if not args.scene and not 1 <= args.scenes <= 2000:
        raise ConfigError("--scenes", f"must be in [1, 2000] (held-out evaluation scenes), got {args.scenes}")
    if args.scene:
        _check_scenes(args.scene)
    output_folder(args.out, "--out")  # bad destinations fail before the evaluation, not after it
    if args.json:
        output_file(args.json, "--json")
    models = {"field": load_model(args.model), "field_nocond": load_model(args.nocond_model or NOCOND_CHECKPOINT)}
    teacher = get_teacher(models["field"].teacher_name)
    scenes = distinct(args.scene, "--scene") if args.scene else default_scenes(args.scenes)
    summary, raw = evaluate_field(
        scenes,
        lambda name: SimSource(name, supersample=2),
        teacher,
        models,
        config,
        progress=lambda it: tqdm(it, desc=f"eval field ({args.source})", unit="scene"),
    )
    paths = write_report(summary, raw, Path(args.out), Path(args.json) if args.json else None)
    for views, methods in summary["views"].items():
        print(f"{views} views: " + ", ".join(f"{m} PLCC {r['plcc']:.3f}" for m, r in methods.items()))
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def _read_json(path: str, flag: str) -> dict:
    from aes_planner.config import ConfigError

    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(flag, f"cannot read {path} as a JSON result of eval search --json ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("views"), dict) or "scenes" not in doc:
        raise ConfigError(flag, f"{path} is not a result of eval search --json (no 'views' and 'scenes')")
    return doc


def _check_scenes(scenes: list[str]) -> None:
    """Every scene spec loads (a bad one fails before the others are evaluated, not after)."""
    from aes_planner.sim import load_scene

    for spec in scenes:
        load_scene(spec)
