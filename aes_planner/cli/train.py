"""``aes-planner train``: distil the aesthetic field from a teacher on procedurally generated scenes.

Builds (or reuses) the sample cache, then trains; ``--resume`` continues from ``OUT/last.npz``.
Training scenes are the simulator's families at seeds >= 1000; evaluation uses seeds < 1000.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train", help="train the aesthetic field (distillation on simulated scenes)", description=__doc__
    )
    p.add_argument("--config", metavar="FILE", help="YAML with TrainConfig fields (see aes_planner.field.train)")
    p.add_argument("--out", metavar="DIR", default="runs/field", help="checkpoints go here (default runs/field)")
    p.add_argument("--cache", metavar="DIR", default=".cache/field", help="sample cache (default .cache/field)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.npz")
    p.add_argument("--teacher", metavar="NAME", help="teacher to distil (overrides the config)")
    p.add_argument("--weights", metavar="FILE", help="the teacher's weights (e.g. VEN)")
    p.add_argument("--steps", type=int, help="training steps (overrides the config)")
    p.add_argument("--samples", type=int, help="cached samples (overrides the config)")
    p.add_argument("--cache-only", action="store_true", help="build the cache and stop")
    p.add_argument(
        "--cache-workers", type=int, default=1, metavar="N", help="processes rendering the cache (default 1)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from aes_planner.config import ConfigError, load_yaml
    from aes_planner.field.train import build_cache, load_config, train
    from aes_planner.runtime import set_threads
    from aes_planner.sim import SimSource

    data = load_yaml(args.config) if args.config else {}
    for key, value in (("teacher", args.teacher), ("teacher_weights", args.weights), ("steps", args.steps)):
        if value is not None:
            data[key] = value
    if args.samples is not None:
        data["samples"] = args.samples
    config = load_config(data)
    teacher = config.make_teacher()

    if not 1 <= args.cache_workers <= 64:
        raise ConfigError("--cache-workers", f"must be in [1, 64], got {args.cache_workers}")
    from aes_planner.paths import output_folder

    output_folder(args.cache, "--cache")  # bad destinations fail now, not after the cache is built
    if not args.cache_only:
        output_folder(args.out, "--out")
    make_source = functools.partial(SimSource, supersample=config.gt_supersample)  # picklable for the workers
    set_threads(config.threads)
    propose = SearchProposer(config.hard_preset, config.hard_field or config.init_from) if config.hard_samples else None
    samples, val, hard = (
        build_cache(
            config,
            Path(args.cache),
            make_source,
            teacher,
            progress=lambda it, split=split: tqdm(it, desc=f"{split} cache", unit="sample"),
            split=split,
            workers=args.cache_workers,
            propose=propose,
            propose_tag=propose.tag() if propose else "",
        )
        for split in ("train", "val", "hard")
    )
    samples = samples + hard
    if args.cache_only:
        print(f"{len(samples)} samples cached in {args.cache}")
        return 0
    train(
        config,
        samples,
        Path(args.out),
        resume=args.resume,
        val_samples=val,
        progress=lambda it: tqdm(it, desc="train", unit="step"),
    )
    print(f"wrote {Path(args.out) / 'model.npz'} (resumable: {Path(args.out) / 'last.npz'})")
    return 0


@dataclass(frozen=True)
class SearchProposer:
    """The hard examples' search (:data:`aes_planner.field.train.Proposer`): preset ``preset``
    in rig mode over the field ``model`` (a checkpoint file; None or ``default``: the shipped
    one), the field the training starts from. Picklable for the cache's worker processes."""

    preset: str
    model: str | None = None

    def tag(self) -> str:
        """The first 8 hex digits of the field checkpoint's SHA-256: hard samples name the field they searched."""
        from importlib import resources

        from aes_planner.field.model import DEFAULT_CHECKPOINT

        if self.model in (None, "default"):
            data = resources.files("aes_planner.field").joinpath(DEFAULT_CHECKPOINT).read_bytes()
        else:
            data = Path(self.model).read_bytes()
        return hashlib.sha256(data).hexdigest()[:8]

    def __call__(self, frames: list, inputs_cam2world: np.ndarray, platform, seed: int):
        from aes_planner.field import build_scorer
        from aes_planner.field.model import shared_model
        from aes_planner.search import SearchConfig, search_views

        cfg = SearchConfig.preset(self.preset, mode="rig", seed=seed)
        model = shared_model() if self.model in (None, "default") else _loaded(self.model)
        knobs = {"render_width_px": cfg.render_width_px}
        if cfg.max_gaussians is not None:
            knobs["max_gaussians"] = cfg.max_gaussians
        scorer = build_scorer("field", frames, model=model, **knobs)
        result = search_views(scorer, inputs_cam2world, platform, cfg)
        coverage = np.asarray(result.candidates_coverage, np.float64)
        objective = np.asarray(result.candidates_score, np.float64) - cfg.coverage_penalty * np.maximum(
            0.0, cfg.coverage_min - coverage
        )  # [C], as stage 1 ranks them
        suggestions = np.stack([s.cam2world for s in result.suggestions]) if result.suggestions else np.zeros((0, 4, 4))
        return result.candidates_cam2world, objective, suggestions


@functools.lru_cache(maxsize=2)
def _loaded(path: str):
    from aes_planner.field.model import load_model

    return load_model(path).eval().requires_grad_(False)
