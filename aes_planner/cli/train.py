"""``aes-planner train``: distil the aesthetic field from a teacher on procedurally generated scenes.

Builds (or reuses) the sample cache, then trains; ``--resume`` continues from ``OUT/last.npz``.
Training scenes are the simulator's families at seeds >= 1000; evaluation uses seeds < 1000.
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path


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
    samples, val = (
        build_cache(
            config,
            Path(args.cache),
            make_source,
            teacher,
            progress=lambda it, split=split: tqdm(it, desc=f"{split} cache", unit="sample"),
            split=split,
            workers=args.cache_workers,
        )
        for split in ("train", "val")
    )
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
