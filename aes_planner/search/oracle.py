"""The oracle: exhaustive search of the feasible space on ground-truth renders, cached on disk.

* rig: a pan x tilt grid over the joint limits (``step_deg`` apart), then a local pattern search
  (halving steps down to ``min_step_deg``) from the best ``refine_starts`` grid points;
* free: a grid of positions in the flight box x yaw x pitch (inside ``pitch_limits_deg``), then the
  same pattern search in 5-DoF (positions step a fraction of the box).

It also scores ``random_samples`` uniformly random feasible poses (the platform's sampler,
:func:`~aes_planner.search.space.random_poses`): their mean is the "chance" level of the oracle-normalised score ``(s - mean random) / (oracle - mean random)``.

Results are cached as ``.npz`` (arrays) + ``.json`` (settings) under ``cache_dir`` (default
``$AES_PLANNER_CACHE/oracle`` or ``~/.cache/aes-planner/oracle``), keyed by a hash of the scene key,
the platform, the teacher, the intrinsics and the settings. Never pickle.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aes_planner.geometry.rig import rig_dict
from aes_planner.platform import Platform
from aes_planner.search.config import SearchConfig
from aes_planner.search.ground_truth import GroundTruthScorer
from aes_planner.search.space import SearchSpace, random_poses, space_for
from aes_planner.sources import SceneSource

log = logging.getLogger(__name__)

__all__ = ["default_cache_dir", "normalized", "oracle_search", "pattern_search"]

ORACLE_VERSION = 1


def normalized(score: float, oracle_score: float, mean_random: float) -> float:
    """The oracle-normalised score ``(score - mean random) / (oracle - mean random)``: 1 = the
    oracle's view, 0 = chance (0 when the oracle is no better than chance)."""
    span = oracle_score - mean_random
    return float((score - mean_random) / span) if span > 1e-9 else 0.0


def default_cache_dir() -> Path:
    root = os.environ.get("AES_PLANNER_CACHE")
    return Path(root) if root else Path.home() / ".cache" / "aes-planner"


def _platform_dict(platform: Platform) -> dict[str, Any]:
    d: dict[str, Any] = {"kind": platform.kind, "intrinsics": dataclasses.asdict(platform.intrinsics)}
    if platform.rig is not None:
        d["rig"] = rig_dict(platform.rig)  # later fields at their old value left out: older keys hold
    if platform.drone is not None:
        d["drone"] = dataclasses.asdict(platform.drone)
    return d


def pattern_search(
    scorer: GroundTruthScorer,
    space: SearchSpace,
    start: torch.Tensor,
    score0: float,
    steps: np.ndarray,
    min_scale: float,
    feasible=None,
) -> tuple[torch.Tensor, float]:
    """Compass search from ``start [D]``: try +-step on each axis, move to the best, else halve.
    ``feasible``: poses ``[M, 4, 4]`` -> ``[M]`` bool; probes it refuses are never scored."""
    p, best, scale = start.clone(), score0, 1.0
    while scale >= min_scale:
        probes = []
        for d in range(space.dims):
            for sign in (1.0, -1.0):
                q = p.clone()
                q[d] += sign * scale * steps[d]
                probes.append(q)
        probes_t = space.project(torch.stack(probes))
        if feasible is not None:
            probes_t = probes_t[torch.as_tensor(feasible(space.to_poses(probes_t).detach()))]
            if not len(probes_t):
                scale /= 2
                continue
        out = scorer.score_batched(space.to_poses(probes_t))
        i = int(torch.argmax(out.score))
        if float(out.score[i]) > best + 1e-9:
            p, best = probes_t[i], float(out.score[i])
        else:
            scale /= 2
    return p, best


def oracle_search(
    source: SceneSource,
    teacher,
    platform: Platform | None = None,
    *,
    step_deg: float = 5.0,
    free_positions: tuple[int, int, int] = (3, 3, 2),
    free_step_deg: float = 30.0,
    refine_starts: int = 3,
    min_step_deg: float = 0.5,
    random_samples: int = 64,
    pitch_limits_deg: tuple[float, float] = (-60.0, 30.0),
    scene_key: str | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
    seed: int = 0,
) -> tuple[float, np.ndarray, dict[str, Any]]:
    """Best ground-truth teacher score over the feasible space, its pose ``[4, 4]``, and extras.

    ``extras``: ``grid_params [G, D]`` and ``grid_scores [G]`` (the exhaustive grid; on a rig
    ``pan_values``/``tilt_values`` give its axes, scores reshape to ``[tilt, pan]``),
    ``random_scores [R]``, ``mean_random``, ``renders`` and ``cached``.
    """
    platform = platform or source.platform
    space_cfg = SearchConfig(pitch_limits_deg=pitch_limits_deg)
    space = space_for(platform, space_cfg)
    settings = {
        "version": ORACLE_VERSION,
        "scene": scene_key or source.name,
        "platform": _platform_dict(platform),
        "teacher": [getattr(teacher, "name", type(teacher).__name__), repr(getattr(teacher, "config", None))],
        "supersample": getattr(source, "supersample", None),
        "step_deg": step_deg,
        "free_positions": list(free_positions),
        "free_step_deg": free_step_deg,
        "refine_starts": refine_starts,
        "min_step_deg": min_step_deg,
        "random_samples": random_samples,
        "pitch_limits_deg": list(pitch_limits_deg),
        "seed": seed,
    }
    key = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:20]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir() / "oracle"
    npz_path, json_path = cache / f"{key}.npz", cache / f"{key}.json"
    data = _read_cache(npz_path) if use_cache and npz_path.is_file() else None
    if data is not None:
        extras = _extras(space, data, cached=True)
        return float(data["best_score"]), data["best_cam2world"], extras

    scorer = GroundTruthScorer(source, teacher)
    grid, step, steps = space.exhaustive_grid(step_deg, free_step_deg, free_positions)
    log.info("oracle: scoring %d grid poses of %s", len(grid), settings["scene"])
    grid_scores = scorer.score_batched(space.to_poses(grid)).score.double()
    rand = random_poses(platform, random_samples, np.random.default_rng(seed), space_cfg)  # [R, 4, 4]
    random_scores = scorer.score_batched(torch.as_tensor(rand)).score.double()

    best_p, best_s = grid[int(torch.argmax(grid_scores))], float(grid_scores.max())
    for i in torch.argsort(grid_scores, descending=True)[:refine_starts].tolist():
        p, s = pattern_search(
            scorer, space, grid[i], float(grid_scores[i]), steps, math.radians(min_step_deg) / step * 2
        )
        if s > best_s:
            best_p, best_s = p, s
    best_pose = space.to_poses(best_p[None])[0].numpy()
    data = {
        "best_score": np.float64(best_s),
        "best_cam2world": best_pose,
        "best_params": best_p.numpy(),
        "grid_params": grid.numpy(),
        "grid_scores": grid_scores.numpy(),
        "random_scores": random_scores.numpy(),
        "renders": np.int64(scorer.renders),
    }
    if use_cache:
        try:  # atomically: a concurrent run never reads half a file
            cache.mkdir(parents=True, exist_ok=True)
            tmp = npz_path.with_suffix(f".{os.getpid()}.tmp.npz")
            np.savez(tmp, **data)
            tmp.replace(npz_path)
            json_path.write_text(json.dumps(settings, indent=1, default=str) + "\n")
        except OSError as exc:
            log.warning("oracle: not cached (%s: %s)", cache, exc.strerror or exc)
    return best_s, best_pose, _extras(space, data, cached=False)


_CACHE_KEYS = ("best_score", "best_cam2world", "best_params", "grid_params", "grid_scores", "random_scores", "renders")


def _read_cache(path: Path) -> dict[str, np.ndarray] | None:
    """A cached oracle result, or None (recompute) when the file is damaged, incomplete or not finite."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # a damaged cache file is recomputed, never trusted
        log.warning("oracle: ignoring the damaged cache file %s (%s)", path, type(exc).__name__)
        return None
    ok = all(k in data and data[k].dtype.kind in "fiu" for k in _CACHE_KEYS)
    ok = ok and data["best_cam2world"].shape == (4, 4) and len(data["random_scores"]) > 0
    ok = ok and all(np.isfinite(data[k]).all() for k in _CACHE_KEYS)
    if not ok:
        log.warning("oracle: ignoring the incomplete cache file %s", path)
        return None
    return data


def _extras(space: SearchSpace, data: dict[str, np.ndarray], cached: bool) -> dict[str, Any]:
    extras: dict[str, Any] = {
        "grid_params": data["grid_params"],
        "grid_scores": data["grid_scores"],
        "random_scores": data["random_scores"],
        "mean_random": float(np.mean(data["random_scores"])),
        "best_params": data["best_params"],
        "renders": int(data["renders"]),
        "cached": cached,
    }
    extras.update(space.grid_axes(data["grid_params"]))
    return extras
