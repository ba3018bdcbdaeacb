"""The two-stage viewpoint search (the paper's section 3.2), top to bottom.

1. **Coarse sampling.** The input poses are joined into a trajectory (slerp on rotations, lerp on
   positions: :func:`aes_planner.geometry.interpolate_poses`), sampled ``S`` times per segment and
   projected into the search space (rig: the joints that aim the camera there; free: the 5-DoF
   view, inside the box). Around each sample ``N`` neighbours are drawn (direction jitter; in free
   mode also in-plane shifts along the image axes); ``grid_points`` more spread over the whole
   space join them (a rig's joint range; a drone's box, from a lattice of places), so views far
   from the inputs compete too. Every candidate is scored in batches; the
   top ``K`` by objective survive a distance-based duplicate check.
2. **Refinement.** Each survivor is refined by Adam on its parameters (lr 0.01, 25 steps by
   default), projected into the joint limits / box after every step. The best iterate of each is
   kept; they are returned ranked, after the same duplicate check (two survivors refined onto
   nearly the same view are one suggestion).

3. **What the inputs cover.** ``explore_points`` views spread over the space are scored: the
   fraction the inputs cover (``covered_fraction``) and an exploratory candidate (``explore``), the
   best-scored view the inputs only partly cover. Where the best view lies where no input looked,
   one shot cannot know it (``eval search``'s ``covered_oracle``); a loop can go and look there.

The objective is the scorer's score minus a coverage penalty, so views of space the scorer has
not observed lose; suggestions below ``coverage_min`` are dropped unless nothing else remains.
Any :class:`~aes_planner.field.scorer.Scorer` plugs in; a non-differentiable one is refined with
central finite differences (or not at all: ``nondiff_refine="skip"``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from aes_planner.errors import AesPlannerError
from aes_planner.field.scorer import ScoreOutput, Scorer
from aes_planner.gaussians import autograd_on
from aes_planner.geometry.poses import c_order, cam2world_to_view
from aes_planner.geometry.rigid import check_rigid
from aes_planner.geometry.trajectory import interpolate_poses
from aes_planner.messages.fields import POSE_TOL
from aes_planner.platform import Platform
from aes_planner.runtime import suggestion_threads
from aes_planner.search.config import SearchConfig
from aes_planner.search.space import FixedPattern, SearchSpace, space_for

log = logging.getLogger(__name__)

__all__ = ["SearchError", "SearchResult", "Suggestion", "refine_params", "search_views"]


class SearchError(AesPlannerError, ValueError):
    """The search cannot run on these inputs (no poses, non-finite poses, wrong shapes)."""


@dataclass
class Suggestion:
    """One suggested view, world frame. ``pan_rad``/``tilt_rad`` are set on a rig only."""

    cam2world: np.ndarray  # [4, 4] float64, world
    position_m: np.ndarray  # [3]
    yaw_rad: float
    pitch_rad: float
    score: float
    coverage: float
    terms: dict[str, float]
    pan_rad: float | None = None
    tilt_rad: float | None = None
    objective: float = 0.0
    stage1_score: float = 0.0
    held: float | None = None  # with --keep: how much of the kept subject the view holds (1 = whole)

    def to_json(self) -> dict:
        """The ``suggest --json`` entry (degrees at the edge)."""
        out = {
            "cam2world": self.cam2world.tolist(),
            "position_m": self.position_m.tolist(),
            "yaw_deg": math.degrees(self.yaw_rad),
            "pitch_deg": math.degrees(self.pitch_rad),
            "score": self.score,
            "coverage": self.coverage,
            "terms": dict(self.terms),
        }
        if self.held is not None:
            out["held"] = self.held
        if self.pan_rad is not None:
            out = {"cam2world": out.pop("cam2world"), "pan_deg": math.degrees(self.pan_rad),
                   "tilt_deg": math.degrees(self.tilt_rad), **out}  # fmt: skip
        return out


@dataclass
class SearchResult:
    """Suggestions best first, the stage-1 candidates (for plots) and where the time went."""

    suggestions: list[Suggestion]
    mode: str  # the platform kind searched: rig or drone
    timings_ms: dict[str, float] = field(default_factory=dict)
    candidates_cam2world: np.ndarray | None = None  # [C, 4, 4] stage-1 candidates
    candidates_score: np.ndarray | None = None  # [C]
    candidates_coverage: np.ndarray | None = None  # [C]
    candidates_exact: np.ndarray | None = None  # [C] bool: scored by the scorer itself, not its screen (screen_keep)
    scored: int = 0  # poses scored in total
    warnings: list[str] = field(default_factory=list)
    dropped_uncovered: int = 0  # refined candidates left out: their coverage fell below coverage_min
    dropped_duplicates: int = 0  # ... and left out as near-duplicates of a better one after refinement
    covered_fraction: float | None = None  # of cfg.explore_points views spread over the space, the share covered
    explore: Suggestion | None = None  # the exploratory candidate: the edge of what the inputs saw (None: all seen)

    @property
    def best(self) -> Suggestion:
        return self.suggestions[0]


def _check_inputs(inputs_cam2world, name: str = "inputs_cam2world", allow_empty: bool = False) -> np.ndarray:
    """Poses as float64 ``[N, 4, 4]``, each finite and rigid; a :class:`SearchError` naming ``name``."""
    poses = inputs_cam2world.detach().cpu().numpy() if isinstance(inputs_cam2world, Tensor) else inputs_cam2world
    try:  # a copy in C order: reversed views (poses[::-1]) included
        poses = c_order(poses)
    except (TypeError, ValueError):
        raise SearchError(
            f"{name} must be poses [N, 4, 4] (an array of numbers), got {type(inputs_cam2world).__name__}"
        ) from None
    if poses.ndim == 2 and poses.shape == (4, 4):
        poses = poses[None]
    if allow_empty and poses.size == 0:
        return poses.reshape(0, 4, 4)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise SearchError(f"{name} must be [N, 4, 4], got shape {poses.shape}")
    if len(poses) == 0:
        raise SearchError(f"{name} is empty; the search needs at least one input view")
    if not np.all(np.isfinite(poses)):
        raise SearchError(f"{name} contains NaN or inf; pass finite world-frame poses")
    for i, pose in enumerate(poses):  # the same rigidity test as every pose in a message
        check_rigid(pose, f"{name}[{i}]", POSE_TOL, SearchError)
    return poses


def _objective(out: ScoreOutput, cfg: SearchConfig) -> Tensor:  # -> [B]
    shortfall = torch.clamp(cfg.coverage_min - out.coverage.to(out.score.dtype), min=0.0)
    return out.score - cfg.coverage_penalty * shortfall


def _select_distinct(space: SearchSpace, params: Tensor, objective: Tensor, k: int, avoid: Tensor | None) -> Tensor:
    """Indices of the top ``k`` by objective, skipping near-duplicates of kept ones and of ``avoid``."""
    order = torch.argsort(objective, descending=True)
    kept: list[int] = []
    dist_avoid = space.distance(params, avoid) if avoid is not None and len(avoid) else None  # [C, A]
    for idx in order.tolist():
        if dist_avoid is not None and bool((dist_avoid[idx] < 1.0).any()):
            continue
        if kept and bool((space.distance(params[idx : idx + 1], params[kept]) < 1.0).any()):
            continue
        kept.append(idx)
        if len(kept) == k:
            break
    if not kept:  # everything is near an avoided pose: fall back to the best
        kept = order[:k].tolist()
    return torch.tensor(kept, dtype=torch.long)


def _gradient(scorer: Scorer, space: SearchSpace, params: Tensor, cfg: SearchConfig, differentiable: bool):
    """Objective ``[K]`` at ``params [K, D]`` and its gradient ``[K, D]`` (autograd or central FD)."""
    if differentiable:
        with autograd_on():  # stage 2's gradient, also under a caller's no_grad or inference_mode
            p = params.detach().clone().requires_grad_(True)
            out = scorer.score(space.to_poses(p))
            obj = _objective(out, cfg)
            grad = torch.autograd.grad(obj.sum(), p, allow_unused=True)[0] if obj.requires_grad else None
        if grad is not None:
            return obj.detach(), out.detach(), torch.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
        return obj.detach(), out.detach(), torch.zeros_like(params)
    k, d = params.shape
    eye = torch.eye(d, dtype=params.dtype) * cfg.fd_step
    probes = torch.cat([params[:, None], params[:, None] + eye, params[:, None] - eye], dim=1)  # [K, 1 + 2D, D]
    probes = space.project(probes.reshape(-1, d)).reshape(k, 1 + 2 * d, d)
    out = scorer.score_batched(space.to_poses(probes.reshape(-1, d)), cfg.batch_size)
    obj = _objective(out, cfg).reshape(k, 1 + 2 * d)
    step = (probes[:, 1 : 1 + d] - probes[:, 1 + d :]).diagonal(dim1=1, dim2=2)  # [K, D] actual spacing
    grad = (obj[:, 1 : 1 + d] - obj[:, 1 + d :]) / torch.where(step.abs() > 1e-12, step, torch.ones_like(step))
    grad = torch.where(step.abs() > 1e-12, grad, torch.zeros_like(grad))
    first = ScoreOutput(
        out.score.reshape(k, -1)[:, 0],
        out.coverage.reshape(k, -1)[:, 0],
        {n: v.reshape(k, -1)[:, 0] for n, v in out.terms.items()},
    )
    return obj[:, 0], first, torch.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0).to(params.dtype)


def samples_per_segment(cfg: SearchConfig, n_inputs: int) -> int:
    """S, or fewer when the inputs have more than ``cfg.segment_budget`` segments: the trajectory
    then gets S x segment_budget samples in all (at least one per segment)."""
    segments = max(n_inputs - 1, 1)
    if cfg.segment_budget is None or segments <= cfg.segment_budget:
        return cfg.samples_per_segment
    return max(1, cfg.samples_per_segment * cfg.segment_budget // segments)


def refine_params(
    scorer: Scorer, space: SearchSpace, start: Tensor, start_obj: Tensor, cfg: SearchConfig, framing=None
):
    """Stage 2: ``cfg.steps`` Adam steps (lr ``cfg.lr``) of gradient ascent on the objective from
    ``start [K, D]`` (objective ``start_obj [K]``), projected into the bounds after every step.

    Returns ``(last [K, D], best [K, D], best_obj [K])``: the last iterate (never scored) and the
    best scored iterate of each start. Autograd when the scorer is differentiable, else central
    finite differences (``cfg.nondiff_refine = "fd"``) or no steps at all (``"skip"``).
    With a ``framing`` (:class:`~aes_planner.search.framing.Framing`) every step is backtracked
    (halved) until it stays feasible, so feasible starts stay feasible.
    """
    params, best_params, best_obj, _ = _refine(scorer, space, start, start_obj, cfg, framing)
    return params, best_params, best_obj


def _smoothed(space: SearchSpace, candidates: Tensor, obj: Tensor, sigma: float) -> Tensor:  # [C, D], [C] -> [C]
    """Each finite objective replaced by the Gaussian-weighted mean of the finite objectives around
    it (``sigma`` in units of the duplicate distance): a view ranked by its neighbourhood, not by
    one sample of the field's rough landscape."""
    ok = torch.isfinite(obj)
    if int(ok.sum()) < 2:
        return obj
    idx = torch.nonzero(ok).squeeze(1)
    d = space.distance(candidates[idx], candidates[idx]).double()  # [M, M]
    w = torch.exp(-0.5 * (d / sigma) ** 2)
    out = obj.clone()
    out[idx] = (w @ obj[idx]) / w.sum(1)
    return out


def _refine(scorer: Scorer, space: SearchSpace, start: Tensor, start_obj: Tensor, cfg: SearchConfig, framing=None,
            start_out: ScoreOutput | None = None):  # fmt: skip
    """:func:`refine_params`, and the scores of each best iterate (a :class:`ScoreOutput` of
    ``[K]``, the steps' own) when ``start_out`` gives the starts' (else None): the search then
    scores only the last iterates again, not the best ones too."""
    differentiable = bool(scorer.differentiable)
    params = start.detach().clone()
    best_params, best_obj = params.clone(), start_obj.detach().double().clone()
    best_out = None if start_out is None else _copy_out(start_out)
    if cfg.steps == 0 or not (differentiable or cfg.nondiff_refine == "fd"):
        return params, best_params, best_obj, best_out
    adam = Adam(params, cfg.lr, eps=cfg.adam_eps)
    for _ in range(cfg.steps):
        obj, out, grad = _gradient(scorer, space, params, cfg, differentiable)
        better = obj.double() > best_obj
        best_params[better], best_obj[better] = params[better], obj.double()[better]
        if best_out is not None and bool(better.any()):
            best_out.score[better] = out.score[better].to(best_out.score.dtype)
            best_out.coverage[better] = out.coverage[better].to(best_out.coverage.dtype)
            for k, v in best_out.terms.items():
                v[better] = out.terms[k][better].to(v.dtype)
        step = space.project(adam.step(params, -grad))  # ascent
        params = step if framing is None else _feasible_step(space, framing, params, step)
    return params, best_params, best_obj, best_out


def _copy_out(out: ScoreOutput) -> ScoreOutput:
    """A detached copy whose tensors own their memory (rows are overwritten in place)."""
    return ScoreOutput(out.score.detach().clone(), out.coverage.detach().clone(),
                       {k: v.detach().clone() for k, v in out.terms.items()})  # fmt: skip


def _feasible_step(space: SearchSpace, framing, params: Tensor, step: Tensor) -> Tensor:  # [K, D] -> [K, D]
    """``step``, each row halved back towards ``params`` until its view holds the kept subjects
    (``framing.cfg.backtrack_steps`` times at most; then the row stays where it was)."""
    ok = framing.feasible(space.to_poses(step))
    for _ in range(framing.cfg.backtrack_steps):
        if bool(ok.all()):
            break
        bad = ~ok
        step[bad] = space.project(params[bad] + 0.5 * (step[bad] - params[bad]))
        ok = framing.feasible(space.to_poses(step))
    return torch.where(ok[:, None], step, params)


class Adam:
    """Adam (Kingma and Ba; the defaults of ``torch.optim.Adam``) on one detached tensor.

    Written out because ``torch.optim`` imports ``torch._dynamo`` when the first optimiser is
    built, about 2 s of a process's first suggestion (docs/benchmarks.md); equal to
    ``torch.optim.Adam`` step for step (tested).
    """

    def __init__(self, like: Tensor, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        self.lr, self.betas, self.eps, self.t = lr, betas, eps, 0
        self.m = torch.zeros_like(like)  # first moment, like params
        self.v = torch.zeros_like(like)  # second moment

    def step(self, params: Tensor, grad: Tensor) -> Tensor:
        """``params`` after one descent step along ``grad``."""
        b1, b2 = self.betas
        self.t += 1
        self.m = b1 * self.m + (1 - b1) * grad
        self.v = b2 * self.v + (1 - b2) * grad * grad
        denom = self.v.sqrt() / math.sqrt(1 - b2**self.t) + self.eps
        return params - self.lr / (1 - b1**self.t) * self.m / denom


def search_views(
    scorer: Scorer,
    inputs_cam2world,
    platform: Platform,
    cfg: SearchConfig | None = None,
    avoid=None,
    framing=None,
) -> SearchResult:
    """Suggest views from input poses ``[N, 4, 4]`` (world, float64) on ``platform``.

    ``avoid``: poses ``[M, 4, 4]`` already captured or suggested; stage 1 skips candidates that
    duplicate them (same distance test as between candidates), so an active loop gets new views.
    ``framing``: a :class:`~aes_planner.search.framing.Framing` (kept subjects, avoided regions):
    only views that hold every kept subject are candidates and suggestions, and its soft terms join
    the objective; a :class:`~aes_planner.search.framing.FramingError` when no view holds them.
    Returns at most ``cfg.top_k`` suggestions, best first. Runs on the thread count
    :func:`aes_planner.runtime.suggestion_threads` picks (fewer threads beside busy processes).
    """
    with suggestion_threads():
        return _search_views(scorer, inputs_cam2world, platform, cfg, avoid, framing)


def _search_views(
    scorer: Scorer, inputs_cam2world, platform: Platform, cfg: SearchConfig | None, avoid, framing=None
) -> SearchResult:
    if not isinstance(platform, Platform):
        raise SearchError(f"platform must be a Platform (a rig or a drone box), got {type(platform).__name__}")
    if cfg is not None and not isinstance(cfg, SearchConfig):
        raise SearchError(
            f"cfg must be a SearchConfig (e.g. SearchConfig.preset('balanced')), got {type(cfg).__name__}"
        )
    cfg = cfg or SearchConfig.preset("balanced", mode=platform.kind)
    t_start = time.perf_counter()
    inputs = _check_inputs(inputs_cam2world)
    space = space_for(platform, cfg)
    rng = FixedPattern() if cfg.fixed_draws else np.random.default_rng(cfg.seed)
    avoid_poses = None if avoid is None else _check_inputs(avoid, "avoid", allow_empty=True)
    avoid_params = space.from_poses(avoid_poses) if avoid_poses is not None and len(avoid_poses) else None
    framing = framing if framing is not None and framing.active else None
    warnings: list[str] = []
    explore_cfg = cfg  # what "covered" means to covered_fraction / explore, with or without a kept subject
    if framing is not None:
        # the views all hold a seen subject: FramingConfig's milder coverage rule; stage 1's
        # feasible pick stands unless FramingConfig.refine
        cfg = dataclasses.replace(cfg, coverage_min=framing.cfg.coverage_min,
                                  coverage_penalty=framing.cfg.coverage_penalty,
                                  steps=cfg.steps if framing.cfg.refine else 0)  # fmt: skip
        scorer = framing.wrap(scorer)  # the avoided regions and the placement join the score

    # ---- stage 1: trajectory samples + neighbours, scored in batches
    trajectory = interpolate_poses(inputs, samples_per_segment(cfg, len(inputs)))  # [T, 4, 4]
    anchors = space.from_poses(trajectory)  # [T, D]
    candidates = torch.cat(
        [anchors, space.neighbours(anchors, cfg.neighbours, rng), space.grid(cfg.grid_points)]
    )  # [T * (1 + N) + G, D]
    if framing is not None:  # stage 1 keeps the views that hold the subject, aimed ones among them
        from aes_planner.search.framing import feasible_candidates

        asked = framing.cfg.margin_frac
        warnings.extend(framing.notes())
        candidates, framing = feasible_candidates(framing, space, candidates, trajectory, cfg, rng)
        if framing.cfg.margin_frac < asked:
            warnings.append(
                f"no reachable view holds the kept subject with the {100 * asked:g}% margin asked; "
                f"the suggestions hold it whole with a {100 * framing.cfg.margin_frac:g}% margin"
            )
    cand_poses = space.to_poses(candidates)  # [C, 4, 4]
    t_sampled = time.perf_counter()
    if cfg.screen_keep > 0:  # the screen's best scored exactly; the rest can be neither kept nor verified
        fresh = None if avoid_params is None else ~(space.distance(candidates, avoid_params) < 1.0).any(1)  # [C]
        out1, exact = scorer.score_screened(
            cand_poses, cfg.batch_size, cfg.screen_keep, lambda o: _objective(o, cfg), fresh
        )
    else:
        out1, exact = scorer.score_batched(cand_poses, cfg.batch_size), torch.ones(len(candidates), dtype=torch.bool)
    obj1 = torch.where(exact, torch.nan_to_num(_objective(out1, cfg).double(), nan=-math.inf), -math.inf)  # [C]
    rank1 = obj1  # what stage 1 ranks by: the objective, or under a kept subject its neighbourhood mean
    if framing is not None and framing.cfg.smooth_dedup > 0:
        rank1 = _smoothed(space, candidates, obj1, framing.cfg.smooth_dedup)
    keep = _select_distinct(space, candidates, rank1, cfg.top_k, avoid_params)
    t_stage1 = time.perf_counter()

    # ---- stage 2: Adam on the parameters, projected into the bounds after every step
    differentiable = bool(scorer.differentiable)
    refine = cfg.steps > 0 and (differentiable or cfg.nondiff_refine == "fd")
    start_out = ScoreOutput(out1.score[keep], out1.coverage[keep], {k: v[keep] for k, v in out1.terms.items()})
    reuse = refine and bool(exact[keep].all())  # a start carrying the screen's score is scored again below
    params, best_params, best_obj, best_out = _refine(
        scorer, space, candidates[keep], obj1[keep], cfg, framing, start_out if reuse else None
    )
    t_stage2 = time.perf_counter()

    # ---- final scores of the refined poses, ranked
    final_params = best_params
    if refine:  # the last step's parameters were never scored: score them beside the best
        final_params = torch.cat([best_params, params])
    final_poses = space.to_poses(final_params).detach()
    if best_out is not None:  # the best iterates were scored by the steps (the starts by stage 1)
        last = scorer.score_batched(final_poses[len(best_params) :], cfg.batch_size)
        out2 = ScoreOutput(
            torch.cat([best_out.score, last.score.to(best_out.score.dtype)]),
            torch.cat([best_out.coverage, last.coverage.to(best_out.coverage.dtype)]),
            {k: torch.cat([v, last.terms[k].to(v.dtype)]) for k, v in best_out.terms.items()},
        )
    else:
        out2 = scorer.score_batched(final_poses, cfg.batch_size)
    obj2 = torch.nan_to_num(_objective(out2, cfg).double(), nan=-math.inf)
    if rank1 is not obj1 and not refine:  # the kept candidates ranked by their neighbourhoods too
        obj2 = torch.where(torch.isfinite(obj2), rank1[keep], obj2)
    if refine:  # per candidate, the better of its best iterate and its last one
        k = len(best_params)
        pick = torch.where(obj2[k:] > obj2[:k], torch.arange(k) + k, torch.arange(k))
    else:
        pick = torch.arange(len(final_params))
    order = pick[torch.argsort(obj2[pick], descending=True)]
    covered = order[out2.coverage[order].double() >= cfg.coverage_min]
    dropped = len(order) - len(covered) if len(covered) else 0
    if not len(covered):
        best_cov = float(out2.coverage[order].max())
        hint = (  # nothing at all in view: the platform is likely not where the inputs were taken
            "; none of the platform's views sees what the inputs saw: check the rig's base_xyz_m or the drone box"
            if best_cov < 0.05
            else ""
        )
        warnings.append(
            f"no suggestion reaches coverage {cfg.coverage_min:.2f} (best {best_cov:.2f}): "
            f"the scorer has not observed the space around the inputs; capture more views{hint}"
        )
        log.warning(warnings[-1])
        covered = order
    # refinement can bring distinct stage-1 candidates to (nearly) the same pose: keep the best of each
    distinct = covered[_select_distinct(space, final_params[covered], obj2[covered], len(covered), None)]
    suggestions = []
    for i in distinct.tolist():
        sug = _suggestion(space, final_params[i], final_poses[i], out2, i, float(obj2[i]))
        sug.stage1_score = float(out1.score[keep[i % len(keep)]])
        suggestions.append(sug)
    t_verify, t_photo = time.perf_counter(), 0.0
    if framing is not None:
        suggestions = _verify_suggestions(scorer, framing, space, suggestions, final_params[distinct], candidates,
                                         out1, obj1, cfg, avoid_params)  # fmt: skip
        t_photo = time.perf_counter()
        suggestions = _photo_rank(scorer, framing, space, suggestions, candidates, obj1, cfg)
        t_photo = time.perf_counter() - t_photo
        for sug in suggestions:  # the aesthetic score, and how much of the subject the view holds
            sug.score = sug.terms.get("aesthetic", sug.score)
            sug.held = float(framing.held(torch.as_tensor(sug.cam2world)[None])[0])
    t_final = time.perf_counter()
    covered_fraction, explore, explored = _explore(scorer, space, explore_cfg, rng, framing)
    t_end = time.perf_counter()
    timings = {
        "sample": (t_sampled - t_start) * 1e3,
        "stage1_score": (t_stage1 - t_sampled) * 1e3,
        "stage2": (t_stage2 - t_stage1) * 1e3,
        "final": (t_verify - t_stage2) * 1e3,
        "verify": (t_final - t_verify - t_photo) * 1e3,
        "photo_rank": t_photo * 1e3,
        "explore": (t_end - t_final) * 1e3,
        "total": (t_end - t_start) * 1e3,
    }
    steps_scored = cfg.steps * len(keep) * (1 if differentiable else 1 + 2 * space.dims) if refine else 0
    return SearchResult(
        suggestions=suggestions,
        mode=space.kind,
        timings_ms=timings,
        candidates_cam2world=cand_poses.detach().numpy(),
        candidates_score=out1.score.detach().double().numpy(),
        candidates_coverage=out1.coverage.detach().double().numpy(),
        candidates_exact=exact.numpy(),
        scored=len(candidates) + steps_scored + len(final_params) - (0 if best_out is None else len(keep)) + explored,
        warnings=warnings,
        dropped_uncovered=dropped,
        dropped_duplicates=len(covered) - len(distinct),
        covered_fraction=covered_fraction,
        explore=explore,
    )


def _verify_suggestions(scorer, framing, space, suggestions: list, params: Tensor, candidates: Tensor,
                       out1: ScoreOutput, obj1: Tensor, cfg, avoid: Tensor | None = None) -> list:  # fmt: skip
    """The refined ``suggestions`` (their parameters ``params [S, D]``) and the
    ``framing.cfg.verify_top`` best distinct stage-1 ``candidates [C, D]`` (objective ``obj1``,
    scores ``out1``) that cover what the inputs saw and are not near ``avoid [A, D]``, re-ranked by :func:`~aes_planner.search.framing.verified_scores` (see
    :class:`~aes_planner.search.framing.FramingConfig`); as many suggestions as came in, best first, each with its verified
    teacher score in ``terms["verified"]``."""
    from aes_planner.search.framing import verified_scores

    fc = framing.cfg
    if fc.verify_top <= 0 or not suggestions:
        return suggestions
    covered = torch.nonzero(out1.coverage.double() >= cfg.coverage_min).flatten()
    extra = covered[_select_distinct(space, candidates[covered], obj1[covered], fc.verify_top, avoid)]
    poses = space.to_poses(candidates[extra]).detach()
    pool = list(suggestions)
    for j, i in enumerate(extra.tolist()):
        pool.append(_suggestion(space, candidates[i], poses[j], out1, i, float(obj1[i])))
        pool[-1].stage1_score = float(out1.score[i])
    pool_params = torch.cat([params, candidates[extra]])  # [P, D]
    pool_poses = torch.as_tensor(np.stack([s.cam2world for s in pool]))  # [P, 4, 4]
    teacher = verified_scores(scorer, pool_poses, framing.intrinsics, fc.verify_width_px)
    if teacher is None:
        return suggestions
    field = torch.tensor([s.objective for s in pool], dtype=torch.float64)
    ranked = fc.verify_weight * (teacher + framing.soft_terms(pool_poses)) + (1.0 - fc.verify_weight) * field
    for s, t in zip(pool, teacher.tolist()):
        s.terms["verified"] = t
    order = _select_distinct(space, pool_params, ranked, len(suggestions), None)
    log.info("framing: %d views verified; the best is %s", len(pool),
             "a refined one" if int(order[0]) < len(suggestions) else "a stage-1 candidate")  # fmt: skip
    return [pool[i] for i in order.tolist()]


def _turns(space: SearchSpace, params: Tensor, turn_deg: float, step_deg: float) -> Tensor:  # [P, D] -> [P * G, D]
    """Each view of ``params`` turned and tilted by up to ``turn_deg``, ``step_deg`` apart (the
    last two parameters: pan and tilt on a rig, yaw and pitch otherwise), inside the bounds."""
    steps = torch.as_tensor(np.radians(np.arange(-turn_deg, turn_deg + 1e-9, step_deg)), dtype=params.dtype)
    off = torch.cartesian_prod(steps, steps)  # [G, 2]
    turned = params[:, None, :].repeat(1, len(off), 1)  # [P, G, D]
    turned[..., -2:] += off[None]
    return space.project(turned.reshape(-1, params.shape[-1]))


def _photo_rank(scorer, framing, space, suggestions: list, candidates: Tensor, obj1: Tensor, cfg) -> list:
    """The ``suggestions`` re-ranked by the teacher on the input photos warped into each view
    (``FramingConfig.photo_rank``; :func:`~aes_planner.search.photo_warp.warped_photo_scores`),
    among a pool of views that all hold the kept subjects: the suggestions, the
    ``photo_top`` best stage-1 ``candidates [C, D]`` (objective ``obj1``), turns and tilts around
    each input photo and around the 8 best candidates. As many suggestions as came in, best first,
    each with ``terms["photo"]`` (the warped score) and ``terms["photo_cover"]``; the suggestions
    unchanged when there are no photos or none covers a view enough."""
    from aes_planner.search.photo_warp import warped_photo_scores

    fc, photos, teacher = framing.cfg, framing.photos, getattr(scorer, "teacher", None)
    if not fc.photo_rank or photos is None or teacher is None or not suggestions or not framing.keep:
        return suggestions
    finite = torch.nonzero(torch.isfinite(obj1)).flatten()
    top = finite[torch.argsort(obj1[finite], descending=True)[: fc.photo_top]]
    sug_params = space.from_poses(np.stack([s.cam2world for s in suggestions]))  # [S, D]
    around = torch.cat([space.from_poses(photos.cam2world), candidates[top[:8]]])
    extra = torch.cat([
        candidates[top],
        _turns(space, around[: len(photos.cam2world)], fc.photo_turn_deg, fc.photo_step_deg),
        _turns(space, around[len(photos.cam2world):], fc.photo_turn_deg / 3, fc.photo_step_deg),
    ])  # fmt: skip
    extra_poses = space.to_poses(extra).detach()
    ok = framing.feasible(extra_poses)
    extra, extra_poses = extra[ok], extra_poses[ok]
    pool = list(suggestions)
    if len(extra):
        out = scorer.score_batched(extra_poses, cfg.batch_size)
        obj = torch.nan_to_num(_objective(out, cfg).double(), nan=-math.inf)  # [E]
        pool += [_suggestion(space, extra[i], extra_poses[i], out, i, float(obj[i])) for i in range(len(extra))]
    pool_params = torch.cat([sug_params, extra])  # [P, D]
    pool_poses = np.stack([s.cam2world for s in pool])  # [P, 4, 4]
    centre = np.mean([s.centre_m for s in framing.keep], axis=0)
    warped, cover = warped_photo_scores(teacher, photos.images, photos.cam2world,
                                        photos.intrinsics, pool_poses, centre, fc.photo_width_px,
                                        fc.photo_min_cover, cfg.batch_size)  # fmt: skip
    usable = torch.as_tensor(np.isfinite(warped))
    if not bool(usable.any()):
        log.info("framing: no view is covered enough by the input photos to re-rank on them")
        return suggestions
    ranked = torch.as_tensor(np.nan_to_num(warped, nan=-np.inf)) + framing.soft_terms(torch.as_tensor(pool_poses))
    for s, w, c in zip(pool, warped.tolist(), cover.tolist()):
        s.terms["photo"], s.terms["photo_cover"] = w, c
    order = _select_distinct(space, pool_params, torch.where(usable, ranked, -math.inf), len(suggestions), None)
    order = order[usable[order]]
    rest = [s for s in suggestions if all(s is not pool[i] for i in order.tolist())]
    log.info("framing: %d views ranked on the input photos (%d covered); the best is %s", len(pool),
             int(usable.sum()), "a suggestion" if int(order[0]) < len(suggestions) else "a nearby view")  # fmt: skip
    return ([pool[i] for i in order.tolist()] + rest)[: len(suggestions)]


def _explore(scorer: Scorer, space: SearchSpace, cfg: SearchConfig, rng: np.random.Generator, framing=None):
    """``(covered_fraction, explore, views scored)`` over ``cfg.explore_points`` views spread over
    the space (``(None, None, 0)`` when 0): the share of them the inputs cover (coverage >= ``coverage_min``)
    and the exploratory candidate: among the views only partly covered (0 < coverage <
    ``coverage_min``), the best scored, where the scorer's guess still rests on something seen
    (with ``cfg.explore_keep``, the best of the screen's ``explore_keep`` best, the only ones scored
    exactly); with none partly covered, the least covered; None when every view is covered. With a
    ``framing`` that keeps subjects: over the views, of ``framing.cfg.explore_samples`` spread over
    the space, that hold them (the exploratory candidate holds them too; ``(None, None, 0)`` when
    none of those views does)."""
    if cfg.explore_points == 0:
        return None, None, 0
    n = cfg.explore_points if framing is None or not framing.keep else framing.cfg.explore_samples
    spread = space.spread(n, rng)  # [G, D]; free flight: drawn after every stage-1 sample
    poses = space.to_poses(spread).detach()  # [G, 4, 4]
    if framing is not None and framing.keep:  # only the views that hold the kept subjects
        held = framing.feasible(poses)
        spread, poses = spread[held], poses[held]
        if not len(spread):
            return None, None, 0

    def partly_covered(coverage: Tensor) -> Tensor:  # [b] -> [b] bool: 0 < coverage < coverage_min
        cov = coverage.double()
        return (cov > 0.0) & (cov < cfg.coverage_min)

    def screen_rank(o: ScoreOutput) -> Tensor:  # the partly covered views by their screened score
        return torch.where(partly_covered(o.coverage), o.score.double(), -math.inf)

    if cfg.explore_keep > 0:  # the screen's best explore_keep partly covered views decoded, no more
        out, exact = scorer.score_screened(poses, cfg.batch_size, cfg.explore_keep, screen_rank)
    else:  # only the partly covered views' scores are read: a field decodes those alone (Scorer.score_where)
        out, exact = scorer.score_where(poses, cfg.batch_size, partly_covered)
    cov = out.coverage.double()  # [G]
    covered = cov >= cfg.coverage_min
    fraction = float(covered.double().mean())
    if bool(covered.all()):
        return fraction, None, len(spread)
    partly = (cov > 0.0) & ~covered
    if bool(partly.any()):
        score = torch.nan_to_num(out.score.double(), nan=-math.inf)
        scored = partly & exact if bool((partly & exact).any()) else partly  # a screen of NaNs: its own scores
        among = torch.nonzero(scored).flatten()  # [P]: a partly covered view even when every score is NaN
        i = int(among[torch.argmax(score[among])])
    else:  # none partly covered: the least covered, scored exactly on its own
        i = int(torch.argmin(cov))
        with torch.no_grad():
            out = scorer.score(poses[i : i + 1]).detach()
        score = torch.nan_to_num(out.score.double(), nan=-math.inf)
        return fraction, _suggestion(space, spread[i], poses[i], out, 0, float(score[0])), len(spread)
    return fraction, _suggestion(space, spread[i], poses[i], out, i, float(score[i])), len(spread)


def _suggestion(space: SearchSpace, params: Tensor, pose: Tensor, out: ScoreOutput, i: int, obj: float) -> Suggestion:
    pose_np = pose.detach().double().numpy()
    view = cam2world_to_view(pose_np)
    pan, tilt = space.joints(params)
    return Suggestion(
        cam2world=pose_np,
        position_m=pose_np[:3, 3].copy(),
        yaw_rad=float(view[3]),
        pitch_rad=float(view[4]),
        score=float(out.score[i]),
        coverage=float(out.coverage[i]),
        terms={k: float(v[i]) for k, v in out.terms.items()},
        pan_rad=pan,
        tilt_rad=tilt,
        objective=obj,
    )
