"""Where a framed suggestion loses against the constrained oracle (docs/results/framing_loss_dev.md).

The cases are those of ``aes-planner eval framing``. For each case the script gives the teacher
score of the stage-1 pick (stage 2 off, the default) and of the search with stage 2 on
(``FramingConfig.refine``). It also takes the whole feasible stage-1 pool, scores it on
ground-truth renders, and gives the pool's best view and its rank in the field's ordering. Every
score is normalised to the constrained oracle.

    .venv/bin/python scripts/framing_loss_check.py tabletop:3,indoor:4,outdoor:5,gallery:6 0,1
    # one JSON line per case, prefixed ROW
"""

import dataclasses
import json
import sys
from types import SimpleNamespace

import numpy as np

from aes_planner.eval.framing import FramingEvalConfig, constrained_oracle, object_points, pick_subject
from aes_planner.eval.search import Judge, _inputs, _mode_platform, _source
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.search.framing import FramingError, build_framing
from aes_planner.search.space import space_for
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(np.argsort(np.argsort(a)), np.argsort(np.argsort(b)))[0, 1])


def subjects(scenes: list[str], seeds: list[int]):
    """The subjects of ``aes-planner eval framing``, one namespace each: cfg, spec, seed, source,
    platform, inputs, frames (the input frames), k (intrinsics), scfg, named (the input frames by
    region name), scorer (the field, built once per scene), picked, points (the object's)."""
    cfg = FramingEvalConfig(scenes=scenes, seeds=seeds)
    for spec in scenes:
        source = _source(spec, cfg)
        platform = _mode_platform(source, cfg.mode, cfg.free_box_m)
        inputs = _inputs(source, platform, cfg.views)
        frames = [source.capture(p) for p in inputs]
        scfg, scorer = SearchConfig.preset(cfg.preset, mode=platform.kind), None
        named = {f"view{i}": (f.cam2world, f.intrinsics, (f.intrinsics.width, f.intrinsics.height))
                 for i, f in enumerate(frames)}  # fmt: skip
        for seed in seeds:
            picked = pick_subject(source.scene, inputs, frames[0].intrinsics, seed, cfg)
            if picked is None:
                continue
            scorer = scorer or build_search_scorer("field", frames, scfg)
            yield SimpleNamespace(cfg=cfg, spec=spec, seed=seed, source=source, platform=platform, inputs=inputs,
                                  frames=frames, k=platform.intrinsics, scfg=scfg, named=named, scorer=scorer,
                                  picked=picked, points=object_points(source.scene.objects[picked[0]]))  # fmt: skip


def cases(scenes: list[str], seeds: list[int]):
    """:func:`subjects` with a constrained oracle, one namespace each: those keys and judge, space,
    oracle."""
    teacher, evaluator = get_teacher(), CompositionEvaluator()
    scene: dict = {}
    for s in subjects(scenes, seeds):
        if s.spec not in scene:
            scene = {s.spec: (Judge(s.source, teacher, evaluator), space_for(s.platform, s.scfg))}
        judge, space = scene[s.spec]
        oracle = constrained_oracle(space, judge, s.points, s.k, s.cfg)
        if oracle is not None:
            yield SimpleNamespace(**vars(s), judge=judge, space=space, oracle=oracle)


def framed_search(c: SimpleNamespace) -> SimpleNamespace | None:
    """The framed search of one case (the eval's framing settings) and the stage-1 objective its
    candidates were ranked by; None when the subject cannot be framed. Fields: framing, result,
    poses [N, 4, 4], field [N] (NaN as -1e9), cov [N], obj [N]."""
    try:
        framing = build_framing(c.scorer, c.named, [c.picked[2]], [], c.k, c.cfg.framing())
        result = search_views(c.scorer, c.inputs, c.platform, c.scfg, framing=framing)
    except FramingError:
        return None
    fc = framing.cfg
    field = np.nan_to_num(result.candidates_score, nan=-1e9)
    cov = result.candidates_coverage
    obj = field - fc.coverage_penalty * np.clip(fc.coverage_min - cov, 0, None)
    return SimpleNamespace(
        framing=framing, result=result, poses=result.candidates_cam2world, field=field, cov=cov, obj=obj
    )


def main(scenes: list[str], seeds: list[int]) -> None:
    for c in cases(scenes, seeds):
        cfg, spec, seed, platform, inputs, k, judge = c.cfg, c.spec, c.seed, c.platform, c.inputs, c.k, c.judge
        scfg, scorer, named, picked, oracle = c.scfg, c.scorer, c.named, c.picked, c.oracle
        runs = {}
        try:
            for refine in (False, True):
                fc = dataclasses.replace(cfg.framing(), refine=refine)
                runs[refine] = search_views(
                    scorer, inputs, platform, scfg, framing=build_framing(scorer, named, [picked[2]], [], k, fc)
                )
        except FramingError:
            continue

        mean, span = oracle["mean_teacher"], oracle["best_teacher"] - oracle["mean_teacher"]
        norm = lambda t, m=mean, d=span: (np.asarray(t, float) - m) / d  # noqa: E731

        pool = runs[False].candidates_cam2world
        field = np.nan_to_num(runs[False].candidates_score, nan=-np.inf)
        t_pool = norm(judge.measure(pool)[0])
        t_pick = norm(judge.measure(runs[False].best.cam2world[None])[0])[0]
        t_s2 = norm(judge.measure(runs[True].best.cam2world[None])[0])[0]
        best = int(np.argmax(t_pool))
        row = {"scene": spec, "seed": seed, "pool": len(pool), "pool_best": float(t_pool[best]),
               "pool_best_field_rank": int((field > field[best]).sum()),
               "field_top5_best": float(t_pool[np.argsort(-field)[:5]].max()),
               "stage1_pick": float(t_pick), "after_stage2": float(t_s2),
               "stage2_field_gain": runs[True].best.objective - runs[False].best.objective,
               "field_teacher_spearman": spearman(field, t_pool)}  # fmt: skip
        print("ROW", json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")])
