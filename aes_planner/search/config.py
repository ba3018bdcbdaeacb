"""``SearchConfig``: every knob of the two-stage viewpoint search, with presets.

Presets (``fast``, ``balanced``) fix the speed/accuracy knobs; any field can be
overridden (``SearchConfig.preset("balanced", steps=30)``); ``mode="drone"`` gives a preset's
values for a drone's 5 DoF (``FREE_MODE_PRESETS``), ``planner=True`` the planner node's (the
closed loop's searches: ``PLANNER_PRESETS``). Their place on the speed/accuracy curve is measured
by ``aes-planner bench search`` and written to ``docs/benchmarks.md``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from aes_planner.config import ConfigError, require, require_finite

__all__ = [
    "DRONE_PLANNER_PRESETS",
    "FREE_MODE_PRESETS",
    "PLANNER_PRESETS",
    "PRESETS",
    "REMOVED_PRESETS",
    "SearchConfig",
]

from aes_planner.messages.suggestion import MAX_CANDIDATES

#: Largest counts a search takes: each of ``top_k`` is refined by ``steps`` renders and reported as a
#: tile (at most a suggestion message's candidates); the candidates (segments x samples x neighbours)
#: are scored in batches.
_MOST = {
    "samples_per_segment": 4096,
    "neighbours": 1024,
    "top_k": MAX_CANDIDATES,
    "batch_size": 4096,
    "steps": 10_000,
}


@dataclass
class SearchConfig:
    """Knobs of :func:`aes_planner.search.search_views` (and of the scorer built for it).

    Stage 1 (coarse sampling):

    * ``samples_per_segment`` (S): poses per segment of the interpolated input trajectory.
    * ``segment_budget``: the trajectory gets at most S x ``segment_budget`` samples; inputs with
      more segments get fewer per segment (at least 1), so a search over the closed loop's 14
      captures costs about what one over 4 frames (3 segments: unchanged) does. None = no cap.
    * ``neighbours`` (N): perturbed poses around each trajectory sample (direction jitter; in free
      mode also in-plane shifts). 0 = none: on a rig with ``grid_points`` stage 1 then draws
      nothing at random, and the seed does not change which views it scores.
    * ``jitter_fov``: direction jitter, as a fraction of the horizontal field of view (uniform in
      +-jitter on yaw/pan and pitch/tilt).
    * ``shift_frac``: in-plane shift (free mode), as a fraction of the flight box's diagonal.
    * ``grid_points``: extra candidates spread evenly over the whole space, independent of the
      inputs (rig: a pan x tilt grid of about this many; free: at most this many, the places of a
      lattice of the box each looking 8 ways at 3 pitches, none below 24), so views away from the
      input trajectory compete too. 0 = the paper's stage 1 (the presets; a drone's active loop
      sets 216: ``PlannerConfig.search_grid_points``).
    * ``top_k`` (K): distinct candidates handed to stage 2.
    * ``screen_keep``: stage 1 ranks every candidate by the scorer's cheaper screen (the field:
      its splatted teacher map, the decoder left out) and scores only the screen's best
      ``screen_keep`` exactly (:meth:`~aes_planner.field.scorer.Scorer.score_screened`); ``top_k``
      is picked among those. 0 = every candidate exactly (scorers without a screen always).
    * ``dedup_fov`` / ``dedup_frac``: two candidates closer than this angle (fraction of the hfov)
      plus position distance (fraction of the box diagonal) are duplicates.

    Stage 2 (refinement): ``steps`` Adam steps of learning rate ``lr`` on the pose parameters
    (rig: pan, tilt in radians; free: x, y, z in metres, yaw, pitch in radians), projected back into
    the joint limits / flight box after every step. A scorer that is not differentiable is refined
    with central finite differences of step ``fd_step`` (``nondiff_refine = "fd"``) or not at all
    (``"skip"``).

    ``adam_eps``: Adam's epsilon in stage 2 (torch's default 1e-8): a parameter whose slope is
    much below it moves by much less than ``lr`` a step, instead of a full step whose sign the
    last bits of a nearly flat slope decide.

    Coverage: the objective is ``score - coverage_penalty * max(0, coverage_min - coverage)``; final
    suggestions with coverage below ``coverage_min`` are dropped unless nothing else is left (then
    the result says so in ``warnings``).

    Scorer knobs (used when the search builds the scorer: ``suggest``, ``eval``, ``bench``; see
    :func:`aes_planner.search.build_search_scorer`): ``render_width_px`` (width of the views the
    field/RGB scorer renders; the height keeps the aspect) and ``max_gaussians`` (the Gaussian
    budget; ``None``: the scorer's default).

    Information: ``explore_points`` views spread over the whole space (rig: a pan x tilt grid; drone:
    uniform at random) are scored once more after stage 2 to say how much of the reachable space the
    inputs cover (``SearchResult.covered_fraction``) and to offer a second, exploratory candidate
    (``SearchResult.explore``): the best-scored view at the edge of what the inputs saw. 0 = neither.
    ``explore_keep``: of the partly covered views, only the best ``explore_keep`` by the scorer's
    screen are scored exactly, and the exploratory candidate is the best of those
    (:meth:`~aes_planner.field.scorer.Scorer.score_screened`); 0 = every partly covered view.

    ``pitch_limits_deg``: the pitch range searched in free mode (a drone gimbal's range).
    ``batch_size``: poses per scorer call in stage 1. ``seed``: the sampling seed.
    ``fixed_draws``: stage 1's neighbours and the coverage points come from a fixed
    low-discrepancy pattern (:class:`~aes_planner.search.space.FixedPattern`, a Kronecker sequence), not from a
    generator seeded with ``seed``: the search then scores the same views whatever its seed (a
    drone's active loop: ``PlannerConfig.plan_draws``).
    """

    samples_per_segment: int = 16
    segment_budget: int | None = 3
    neighbours: int = 8
    grid_points: int = 0
    explore_points: int = 64
    explore_keep: int = 0
    top_k: int = 2
    screen_keep: int = 0
    steps: int = 25
    lr: float = 0.01
    adam_eps: float = 1e-8
    jitter_fov: float = 0.35
    shift_frac: float = 0.05
    dedup_fov: float = 0.2
    dedup_frac: float = 0.05
    coverage_min: float = 0.7
    coverage_penalty: float = 2.0
    fd_step: float = 0.02
    nondiff_refine: str = "fd"
    render_width_px: int = 48
    max_gaussians: int | None = None
    pitch_limits_deg: tuple[float, float] = (-60.0, 30.0)
    batch_size: int = 64
    seed: int = 0
    fixed_draws: bool = False
    preset_name: str = "custom"

    def __post_init__(self):
        for name in ("samples_per_segment", "top_k", "batch_size", "render_width_px"):
            v = getattr(self, name)
            require(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1, name, f"must be an integer >= 1, got {v!r}"
            )
        v = self.neighbours  # 0: stage 1 draws nothing at random (the trajectory and the grid)
        require(
            isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "neighbours",
            f"must be an integer >= 0, got {v!r}",
        )
        for name, most in _MOST.items():
            v = getattr(self, name)
            require(v <= most, name, f"must be <= {most}, got {v}")
        require(
            isinstance(self.explore_points, int)
            and not isinstance(self.explore_points, bool)
            and 0 <= self.explore_points <= 4096,
            "explore_points",
            f"must be an integer in [0, 4096], got {self.explore_points!r}",
        )
        require(
            isinstance(self.explore_keep, int)
            and not isinstance(self.explore_keep, bool)
            and 0 <= self.explore_keep <= 4096,
            "explore_keep",
            f"must be an integer in [0, 4096] (0 = score every partly covered view exactly), got {self.explore_keep!r}",
        )
        require(
            isinstance(self.screen_keep, int)
            and not isinstance(self.screen_keep, bool)
            and 0 <= self.screen_keep <= 100_000,
            "screen_keep",
            f"must be an integer in [0, 100000] (0 = score every stage-1 candidate exactly), got {self.screen_keep!r}",
        )
        require(
            isinstance(self.grid_points, int)
            and not isinstance(self.grid_points, bool)
            and 0 <= self.grid_points <= 10_000,
            "grid_points",
            f"must be an integer in [0, 10000], got {self.grid_points!r}",
        )
        require(
            isinstance(self.steps, int) and not isinstance(self.steps, bool) and self.steps >= 0,
            "steps",
            f"must be an integer >= 0, got {self.steps!r}",
        )
        require(
            isinstance(self.seed, int) and not isinstance(self.seed, bool) and self.seed >= 0,
            "seed",
            f"must be an integer >= 0, got {self.seed!r}",
        )
        require(isinstance(self.fixed_draws, bool), "fixed_draws", f"must be true or false, got {self.fixed_draws!r}")
        if self.segment_budget is not None:
            require(
                isinstance(self.segment_budget, int)
                and not isinstance(self.segment_budget, bool)
                and self.segment_budget >= 1,
                "segment_budget",
                f"must be an integer >= 1 or None, got {self.segment_budget!r}",
            )
        for name in ("lr", "jitter_fov", "shift_frac", "dedup_fov", "dedup_frac", "fd_step"):
            v = getattr(self, name)
            require_finite(v, name)
            require(v > 0, name, f"must be > 0, got {v}")
        for name in ("coverage_min", "coverage_penalty"):
            v = getattr(self, name)
            require_finite(v, name)
            require(v >= 0, name, f"must be >= 0, got {v}")
        require(self.coverage_min <= 1.0, "coverage_min", f"must be in [0, 1], got {self.coverage_min}")
        # larger values overflow the scorers' float32 objective (every uncovered view ties at -inf)
        require(self.coverage_penalty <= 1e6, "coverage_penalty", f"must be in [0, 1e6], got {self.coverage_penalty}")
        for name in ("jitter_fov", "shift_frac"):  # fractions of the view: a few at most
            require(getattr(self, name) <= 10.0, name, f"must be in (0, 10], got {getattr(self, name)}")
        require(
            8 <= self.render_width_px <= 4096, "render_width_px", f"must be in [8, 4096] px, got {self.render_width_px}"
        )
        require_finite(self.adam_eps, "adam_eps")
        require(0.0 < self.adam_eps <= 1.0, "adam_eps", f"must be in (0, 1], got {self.adam_eps}")
        require(self.lr <= 1.0, "lr", f"must be in (0, 1] (radians or metres per step), got {self.lr}")
        require(
            self.nondiff_refine in ("fd", "skip"),
            "nondiff_refine",
            f"must be 'fd' (finite differences) or 'skip', got {self.nondiff_refine!r}",
        )
        if self.max_gaussians is not None:
            require(
                isinstance(self.max_gaussians, int) and self.max_gaussians >= 1,
                "max_gaussians",
                f"must be a positive integer or None, got {self.max_gaussians!r}",
            )
        try:
            p = tuple(self.pitch_limits_deg)
        except TypeError:
            raise ConfigError(
                "pitch_limits_deg", f"must be (min, max) in degrees, got {self.pitch_limits_deg!r}"
            ) from None
        require(len(p) == 2, "pitch_limits_deg", f"must be (min, max), got {self.pitch_limits_deg!r}")
        require_finite(list(p), "pitch_limits_deg")
        require(-90.0 <= p[0] < p[1] <= 90.0, "pitch_limits_deg", f"must satisfy -90 <= min < max <= 90, got {p}")
        self.pitch_limits_deg = (float(p[0]), float(p[1]))

    @property
    def pitch_limits_rad(self) -> tuple[float, float]:
        return (math.radians(self.pitch_limits_deg[0]), math.radians(self.pitch_limits_deg[1]))

    @classmethod
    def preset(cls, name: str = "balanced", mode: str = "rig", planner: bool = False, **overrides: Any) -> SearchConfig:
        """The named preset for a platform kind ``mode`` (``rig`` or ``drone``, ``free`` read as
        drone: ``FREE_MODE_PRESETS`` change some presets for a drone) with ``overrides`` applied;
        ``planner``: the planner node's searches (``PLANNER_PRESETS`` on top of the one-shot
        preset; on a drone ``DRONE_PLANNER_PRESETS`` instead of ``FREE_MODE_PRESETS``, over both).
        Unknown names or keys are errors."""
        from aes_planner.platform import parse_kind

        if name in REMOVED_PRESETS:
            raise ConfigError("preset", f"{name!r} was removed: {REMOVED_PRESETS[name]}")
        if name not in PRESETS:
            raise ConfigError("preset", f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
        kind = parse_kind(mode, "mode", allow_handheld=True)
        known = {f.name for f in dataclasses.fields(cls)}
        for key in overrides:
            if key not in known:
                raise ConfigError(key, f"unknown search setting; expected one of: {', '.join(sorted(known))}")
        five_dof = DRONE_PLANNER_PRESETS if planner else FREE_MODE_PRESETS  # the loop's are pinned apart
        drone = five_dof.get(name, {}) if kind in ("drone", "handheld") else {}  # both 5 DoF
        loop = PLANNER_PRESETS.get(name, {}) if planner else {}
        values = {**PRESETS[name], **loop, **drone, "preset_name": name, **overrides}
        return cls(**values)


#: Preset name -> the fields it sets (everything else keeps the dataclass default). These are a
#: one-shot suggestion's (``suggest``, ``eval search``); the planner node's searches take
#: ``PLANNER_PRESETS`` on top.
PRESETS: dict[str, dict[str, Any]] = {
    "fast": dict(samples_per_segment=4, neighbours=4, top_k=1, steps=10, render_width_px=32, explore_points=16),
    "balanced": dict(
        samples_per_segment=16, neighbours=8, top_k=2, steps=20, render_width_px=48, screen_keep=128, explore_keep=8
    ),
}

#: What a preset keeps in the planner node's searches (the active loop's plannings and
#: verifications, a passive node's suggestions; ``SearchConfig.preset(..., planner=True)``,
#: ``PlannerConfig.search_steps``). ``balanced`` one-shot takes 20 Adam steps and an explore pass
#: that decodes 8 (the same one-shot picks and exploratory candidates, less CPU); the loop keeps 25
#: and every partly covered view: with 20 steps dev tabletop:210 fell 1.000 -> 0.878 and ``demo``
#: 0.93 -> 0.88 (docs/decisions.md), and the loop moves to its exploratory candidate.
PLANNER_PRESETS: dict[str, dict[str, Any]] = {
    "balanced": dict(steps=25, explore_keep=0),
}

#: Presets no longer offered, and why (docs/decisions.md): each slower preset must beat the faster
#: ones by >= 0.03 of the oracle on held-out scenes (``eval search`` prints the front).
REMOVED_PRESETS: dict[str, str] = {
    "accurate": "it was not better than balanced on held-out scenes (rig 0.68 vs 0.71 of the oracle, "
    "3x the time; docs/decisions.md); use balanced, or override its fields, e.g. samples_per_segment",
}

#: What a preset changes for a drone's one-shot suggestions (5 DoF, "free mode"; the drone loop's
#: searches take ``DRONE_PLANNER_PRESETS``). There a denser stage 1 finds better views; in rig mode
#: (2 DoF, already densely sampled) it finds more of the field's over-estimates (S 32, K 3: validation
#: 0.620 -> 0.654, hand-written 0.637 -> 0.754; docs/journal/benchmarks.md, "The closed loop's plans").
#: The rig's stage-1 screen (128 decoded) gives the same picks for ~2/3 of the CPU (12 validation
#: drone scenes x 3 seeds: 35 of 36 the same, one-thread CPU 1090 -> 698 ms; held-out 11 of 12 the
#: same, one better). K 4 scored higher on validation (0.674 against 0.664) but lost 0.07 held-out;
#: 20 steps with 8 decoded in the explore pass were lower on validation (0.659): docs/decisions.md.
FREE_MODE_PRESETS: dict[str, dict[str, Any]] = {
    "balanced": dict(samples_per_segment=32, top_k=3, screen_keep=128, steps=25, explore_keep=0),
}

#: What a preset changes for a drone's (or a hand-held camera's) planner-node searches: the closed
#: loop's plannings and verifications, in place of ``FREE_MODE_PRESETS`` (``SearchConfig.preset(...,
#: mode="drone", planner=True)``). Pinned apart from the one-shot drone presets, which are chosen on
#: the one-shot preset front: the dev drone loop was tuned with these values (session 28, 47 dev
#: cells: ``DroneMotion.turns_one_by_one``), and a change here changes every drone loop's path, so it
#: needs the dev drone loop re-run, not the one-shot eval. These are the session-28 one-shot values.
DRONE_PLANNER_PRESETS: dict[str, dict[str, Any]] = {
    "balanced": dict(samples_per_segment=32, top_k=3, screen_keep=0, steps=25, explore_keep=0),
}
