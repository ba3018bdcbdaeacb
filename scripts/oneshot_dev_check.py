"""Where a one-shot suggestion loses against what the inputs cover (dev and validation scenes only;
docs/benchmarks.md, "One shot, and what the inputs cover").

For each scene (rig, the survey sweep's 4 views, as ``aes-planner eval search``) and each search
seed, every variant of the search runs once on the field; the script prints one JSON line per
(scene, seed, variant), prefixed ROW: the oracle-normalised true score of the pick and of every
refined suggestion, their field scores and coverage, and, for the variant's stage-1 candidates,
the true score of the 24 best by the field's objective (the pool a re-ranking could choose from).
Variants are ``NAME=PRESET[,key=value...]`` (SearchConfig fields, ints or floats, and the
field's ``unseen_cells``);
``--model=FILE`` searches over that field checkpoint instead of the shipped one (every variant);
``--rescore=NAME`` also scores that variant's pool with the field at 32, 48 and 64 px and
averaged over 8 jitters of 2 and 4 deg (``pool_f32`` ... ``pool_jit4``).

    .venv/bin/python scripts/oneshot_dev_check.py indoor:500,outdoor:501 0,1,2 \
        fast=fast balanced=balanced b32=balanced,render_width_px=32

Scenes are FAMILY:SEED specs or YAML files; ``textured:FAMILY:SEED[:PHOTO]`` is the procedural
scene with two image-textured pictures added in front of the rig (``sim/assets/photos/PHOTO.jpg``
or sim/assets/sunset.png), like the eval loop's picture scenes: a dev image-textured scene. Never
pass a held-out scene (docs/field.md's seed table): this is for finding out, not for scoring.
"""

import dataclasses
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from framing_rank_check import jittered  # scripts/ is on the path when run

from aes_planner.eval.search import Judge, SearchEvalConfig, _inputs, _source, covered_oracle, scene_oracle
from aes_planner.search import SearchConfig, build_search_scorer, normalized, search_views
from aes_planner.sim.scene import load_scene, scene_to_yaml
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

ROOT = Path(__file__).resolve().parents[1]
SCORER_KNOBS = ("unseen_cells",)  # ScorerConfig fields a variant may set (the rest are SearchConfig's)
HELD_OUT = {"indoor:100", "outdoor:101", "tabletop:102", "gallery:103", "indoor:104", "outdoor:105"}


def textured_scene(spec: str, out_dir: Path) -> str:
    """``textured:FAMILY:SEED[:PHOTO]`` -> a YAML file: the scene with two pictures hung 2.2-3 m
    from the rig at pans of about +-40 deg (random per seed), facing it."""
    _, family, seed, *photo = spec.split(":")
    scene = load_scene(f"{family}:{seed}")
    text = scene_to_yaml(scene)
    rig = scene.rig.pan_tilt
    rng = np.random.default_rng(int(seed) + 7)
    base = np.asarray(rig.base_xyz_m, float)
    yaw0 = float(rig.base_rpy_deg[2])
    image = ROOT / "sim" / "assets" / ("sunset.png" if not photo else f"photos/{photo[0]}.jpg")
    quads = []
    for i, pan0 in enumerate((rng.uniform(-60, -20), rng.uniform(20, 60))):
        pan = math.radians(pan0 + yaw0)
        d = rng.uniform(2.2, 3.0)
        c = base + np.array([d * math.cos(pan), d * math.sin(pan), rng.uniform(-0.1, 0.3)])
        w = rng.uniform(0.9, 1.3)
        quads.append(
            f"- type: quad\n  centre_m: [{c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f}]\n  size_m: [{w:.3f}, {w * 2 / 3:.3f}]\n"
            f"  rpy_deg: [0.0, 0.0, {math.degrees(pan) + 180.0:.2f}]\n  name: picture{i}\n"
            f"  material:\n    albedo: [0.7, 0.7, 0.7]\n    image: {image.name}\n    emission: 0.0\n"
        )
    path = out_dir / f"textured_{family}_{seed}{'_' + photo[0] if photo else ''}.yaml"
    (out_dir / image.name).write_bytes(image.read_bytes())
    path.write_text(text.rstrip("\n") + "\n" + "".join(quads))
    return str(path)


def variant(text: str) -> tuple[str, str, dict]:
    name, _, rest = text.partition("=")
    preset, *pairs = rest.split(",")
    overrides = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        overrides[key] = (
            value
            if not value.lstrip("-").replace(".", "", 1).isdigit()
            else float(value)
            if "." in value
            else int(value)
        )
    return name, preset, overrides


@dataclasses.dataclass
class DevCase:
    """One dev scene as the one-shot checks use it: its rig, its oracle and 4 input frames."""

    path: str
    source: object
    platform: object
    oracle_score: float
    oracle_pose: object
    oracle_extra: dict
    inputs: object
    frames: list


def dev_cases(scenes: list[str], teacher):
    """Each dev scene (held-out ones refused) with its cached oracle and the rig's 4 inputs; image-
    textured scenes are written once to one path per scene, so their oracles are cached too."""
    tmp = Path(tempfile.gettempdir()) / "oneshot_textured"
    tmp.mkdir(exist_ok=True)
    for spec in scenes:
        if spec in HELD_OUT or "loop_heldout" in spec or spec.endswith("_rig.yaml") or "showcase" in spec:
            raise SystemExit(f"{spec} is held out: never tune on it")
        path = textured_scene(spec, tmp) if spec.startswith("textured:") else spec
        cfg = SearchEvalConfig(scenes=[path], modes=["rig"])
        source = _source(load_scene(path), cfg)
        platform = source.platform
        o_score, o_pose, o_extra = scene_oracle(path, source, teacher, platform, cfg)
        inputs = _inputs(source, platform, 4)
        frames = [source.capture(p) for p in inputs]
        yield spec, DevCase(path, source, platform, o_score, o_pose, o_extra, inputs, frames)


def main(scenes: list[str], seeds: list[int], variants: list[tuple[str, str, dict]], rescore=()) -> None:
    teacher = get_teacher()
    evaluator = CompositionEvaluator()
    for spec, case in dev_cases(scenes, teacher):
        source, platform, inputs, frames = case.source, case.platform, case.inputs, case.frames
        o_score, o_pose, o_extra = case.oracle_score, case.oracle_pose, case.oracle_extra
        m = o_extra["mean_random"]
        judge = Judge(source, teacher, evaluator)

        def norm(poses: np.ndarray) -> list[float]:
            return [normalized(float(t), o_score, m) for t in judge.measure(poses)[0]]  # noqa: B023

        cov_pose, oracle_cov = covered_oracle(frames, platform, o_pose, o_extra, teacher)
        head = {"scene": spec, "covered_oracle": norm(cov_pose[None])[0], "oracle_cov": oracle_cov,
                "best_input": max(norm(inputs))}  # fmt: skip
        for seed in seeds:
            for name, preset, overrides in variants:
                knobs = {k: overrides.pop(k) for k in list(overrides) if k in SCORER_KNOBS}
                scfg = SearchConfig.preset(preset, mode="rig", seed=seed, **overrides)
                overrides.update(knobs)
                scorer = build_search_scorer("field", frames, scfg, teacher)
                scorer.config = dataclasses.replace(scorer.config, **knobs)  # e.g. unseen_cells=decoder
                result = search_views(scorer, inputs, platform, scfg)
                sugg = result.suggestions
                row = {**head, "seed": seed, "variant": name,
                       "pick": norm(result.best.cam2world[None])[0],
                       "sugg_gt": norm(np.stack([s.cam2world for s in sugg])),
                       "sugg_field": [s.score for s in sugg], "sugg_cov": [s.coverage for s in sugg],
                       "sugg_stage1": [s.stage1_score for s in sugg],
                       "total_ms": result.timings_ms.get("total")}  # fmt: skip
                if result.candidates_cam2world is not None and len(result.candidates_cam2world):
                    obj = np.asarray(result.candidates_score, float) - scfg.coverage_penalty * np.maximum(
                        0.0, scfg.coverage_min - np.asarray(result.candidates_coverage, float)
                    )
                    top = np.argsort(-obj, kind="stable")[:24]
                    row["pool_gt"] = norm(result.candidates_cam2world[top])
                    row["pool_obj"] = obj[top].tolist()
                    row["pool_cov"] = np.asarray(result.candidates_coverage, float)[top].tolist()
                    if name in rescore:  # the same pool scored by the field at other widths, and jittered
                        pool = torch.as_tensor(result.candidates_cam2world[top])
                        for width in (32, 48, 64):
                            other = build_search_scorer(
                                "field", frames, dataclasses.replace(scfg, render_width_px=width), teacher
                            )
                            out = other.score_batched(pool, 64)
                            row[f"pool_f{width}"] = out.score.double().tolist()
                            row[f"pool_c{width}"] = out.coverage.double().tolist()
                        rng = np.random.default_rng(seed)
                        for deg in (2.0, 4.0):
                            jit = jittered(result.candidates_cam2world[top], deg, rng)
                            out = scorer.score_batched(torch.as_tensor(jit), 64)
                            row[f"pool_jit{deg:g}"] = out.score.double().numpy().reshape(len(top), -1).mean(1).tolist()
                if result.explore is not None:
                    row["explore_gt"] = norm(result.explore.cam2world[None])[0]
                print("ROW", json.dumps(row, default=float), flush=True)


def use_model(path: str) -> None:
    """Every field built without a model of its own (the search's) scores with ``path``."""
    from aes_planner.field.model import DEFAULT_CHECKPOINT, _shared_models, load_model

    _shared_models[DEFAULT_CHECKPOINT] = load_model(path).eval().requires_grad_(False)


if __name__ == "__main__":
    torch.set_grad_enabled(True)
    for a in sys.argv[3:]:
        if a.startswith("--model="):
            use_model(a.split("=", 1)[1])
    args = [a for a in sys.argv[3:] if not a.startswith(("--rescore=", "--model="))]
    rescore = [a.split("=", 1)[1] for a in sys.argv[3:] if a.startswith("--rescore=")]
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], [variant(v) for v in args], rescore)
