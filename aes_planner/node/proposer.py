"""What the planner asks of the field and the search: candidate views, and what the field thinks
of the views already captured.

:class:`FieldProposer` keeps a bounded set of frames, builds a scorer from them
(:func:`aes_planner.field.build_scorer`: the aesthetic field, or RGB scoring of a
reconstruction) when they changed, and runs the two-stage search
(:func:`aes_planner.search.search_views`). The planner node talks only to the small
:class:`Proposer` interface, so its state machine is tested with any proposer.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass

import numpy as np
import torch

from aes_planner.messages import Candidate, PosedFrame
from aes_planner.platform import Platform

log = logging.getLogger(__name__)

__all__ = ["FieldProposer", "FramedViews", "Proposal", "Proposer"]


@dataclass
class Proposal:
    """Ranked candidates (best first, the scorer's units) and the same scorer's scores of the
    views already captured (``captured_pred [M]``), so a gain is measured on one scale; what the
    inputs cover of the space (``covered_fraction``, None when not measured) and the exploratory
    candidate at the edge of what they saw (``explore``, None when everything is covered)."""

    candidates: list[Candidate]
    captured_pred: np.ndarray  # [M]
    field_version: int
    covered_fraction: float | None = None
    explore: Candidate | None = None


@dataclass
class FramedViews:
    """Which views the active loop may settle on while a framing is in force: those that hold every
    kept subject by the last search's own rule (``framing``: the subject lifted from the
    reconstruction of that search, at the margin its suggestions hold it with), ranked by their
    captured score plus the framing's soft terms (avoided regions seen, placement), as the
    search ranks its verified views; ``fallback``: that search's best suggestion (feasible), the
    view to settle on when no capture is."""

    framing: object  # aes_planner.search.framing.Framing
    fallback: Candidate | None

    def judge(self, cam2world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [M, 4, 4] -> [M] bool, [M]
        """Whether each view holds every kept subject, and the soft terms added to its score."""
        poses = torch.as_tensor(np.asarray(cam2world, dtype=np.float64).reshape(-1, 4, 4))
        with torch.no_grad():
            ok = self.framing.feasible(poses).numpy()
            soft = self.framing.soft_terms(poses).double().numpy()
        return ok.astype(bool), soft


def _held_under(framing, pose: np.ndarray):
    """The framing a search's best suggestion ``pose [4, 4]`` holds its subjects under: ``framing``,
    else its margin halved, then none (what the search relaxes to when nothing holds them with the
    margin asked: :func:`~aes_planner.search.framing.feasible_candidates`)."""
    p = torch.as_tensor(pose[None])
    if not framing.keep or bool(framing.feasible(p)[0]):
        return framing
    for margin in (framing.cfg.margin_frac / 2, 0.0):
        relaxed = framing.with_margin(margin)
        if bool(relaxed.feasible(p)[0]):
            return relaxed
    return framing


def candidate_of(s) -> Candidate:
    """The wire's :class:`~aes_planner.messages.Candidate` from a search's
    :class:`~aes_planner.search.Suggestion` (coverage kept in [0, 1], at most 32 score terms)."""
    pan = getattr(s, "pan_rad", None)
    tilt = getattr(s, "tilt_rad", None)
    terms = {k: float(v) for k, v in (getattr(s, "terms", None) or {}).items()}
    return Candidate(
        np.asarray(s.cam2world, dtype=np.float64),
        float(s.score),
        float(min(max(getattr(s, "coverage", 1.0), 0.0), 1.0)),
        None if pan is None else float(pan),
        None if tilt is None else float(tilt),
        dict(list(terms.items())[:32]),
    )


class Proposer(ABC):
    """Frames in, candidate views out."""

    #: bumped whenever the frames behind the proposals change
    version: int = 0
    #: the keep/avoid regions its searches apply (``set_framing``), and how much of each kept subject
    #: the last best suggestion held
    framing = None
    framing_held: list[float] = []
    framing_boxes: list = []  # [(keep|avoid, Subject)] of the last search: their 3D boxes

    def framed_views(self) -> FramedViews | None:
        """What the active loop may settle on under the framing in force (None: framing off, or
        no search applied it yet: any view)."""
        return None

    def set_framing(self, keep, avoid, cfg) -> None:
        """Apply keep/avoid regions to the next searches (a proposer without a reconstruction cannot)."""
        from aes_planner.search.framing import FramingError

        if keep or avoid:
            raise FramingError(f"{type(self).__name__} has no reconstruction to lift keep/avoid regions from")

    @abstractmethod
    def add_frame(self, frame: PosedFrame, keep: bool = False) -> None:
        """Integrate a frame; ``keep`` frames (the active loop's captures) are never evicted. A
        proposer that keeps frames off its search's path also takes ``on_path=False`` (the loop
        passes it only for such frames: :class:`FieldProposer`)."""

    @abstractmethod
    def propose(
        self,
        platform: Platform,
        captured_cam2world: np.ndarray,
        top_k: int,
        keep_near: int | None = None,
        search: dict | None = None,
    ) -> Proposal:
        """Candidates for ``platform``, avoiding the captured poses ``[M, 4, 4]`` except the
        neighbourhood of capture ``keep_near`` (the best one: refining around it is allowed);
        ``search``: search settings on top of the preset's (a proposer without a search ignores them)."""

    def score_views(self, cam2world: np.ndarray) -> np.ndarray | None:  # [N, 4, 4] -> [N]
        """The scorer's predictions at ``cam2world`` (teacher units), as the search sees them;
        None: a proposer without a scorer to ask (the loop then takes no view it would rank by it)."""
        return None

    @abstractmethod
    def reset(self) -> None:
        """Forget every frame."""

    @property
    @abstractmethod
    def size(self) -> int:
        """Frames held."""


class FieldProposer(Proposer):
    """The field (or RGB scoring) + the two-stage search, over at most ``max_frames`` frames.

    Passive frames beyond the budget are evicted oldest first; kept frames (captures) stay,
    and when they alone exceed the budget the oldest of them go too.
    """

    def __init__(
        self, scorer: str = "field", preset: str = "balanced", teacher=None, max_frames: int = 24, seed: int = 0
    ):
        self.scorer_kind = scorer
        self.preset = preset
        self.teacher = teacher
        self.max_frames = max_frames
        self.seed = seed
        self._frames: deque[tuple[PosedFrame, bool]] = deque()
        self._off_path: set[int] = set()  # ids of the frames kept off the search's trajectory (add_frame)
        self._scorer = None
        self._scorer_version = -1
        self.version = 0
        self.framing = None  # (keep, avoid, FramingConfig, {frame: view}) the searches apply: set_framing
        #: SearchConfig fields over the preset's for the planner's searches (PlannerConfig.search_steps,
        #: search_grid_points): set by PlannerNode.start
        self.search_settings: dict[str, int] = {}
        self.framing_held: list[float] = []  # how much of each kept subject the last best suggestion held
        self._framed: FramedViews | None = None  # the last search's framing, for the active loop

    def framed_views(self) -> FramedViews | None:
        return self._framed if self.framing is not None else None

    @property
    def size(self) -> int:
        return len(self._frames)

    def reset(self) -> None:
        self._frames.clear()
        self._off_path.clear()
        self._scorer = None
        self.version += 1

    def add_frame(self, frame: PosedFrame, keep: bool = False, on_path: bool = True) -> None:
        """``on_path``: the frame is one of the search's inputs (its trajectory passes through it);
        False: the field's only (a drone's far exploration places, ``PlannerConfig.explore_places``)."""
        self._frames.append((frame, keep))
        if not on_path:
            self._off_path.add(id(frame))
        while len(self._frames) > self.max_frames:
            passive = next((i for i, (_, k) in enumerate(self._frames) if not k), None)
            gone = self._frames[passive if passive is not None else 0][0]
            self._off_path.discard(id(gone))
            del self._frames[passive if passive is not None else 0]
        self.version += 1

    def set_framing(self, keep, avoid, cfg) -> None:
        """Apply keep/avoid regions (:class:`~aes_planner.search.framing.Region`) to the next
        searches; none of either: no framing. Each region's view (pose, camera, image size) is
        resolved now, so a frame evicted later, or ``latest`` (the newest frame held), keeps meaning
        the image the box was drawn on. A :class:`~aes_planner.search.framing.FramingError` (nothing
        changed) when a region names no held frame or lies outside its image."""
        from aes_planner.search.framing import FramingError, frame_index

        if not keep and not avoid:
            self.framing, self.framing_held, self.framing_boxes = None, [], []
            self._framed = None
            return
        frames = [f for f, _ in self._frames]
        index = frame_index(frames)
        if frames:
            index["latest"] = len(frames) - 1
        views = {}
        for key, regions in (("keep", keep), ("avoid", avoid)):
            for r in regions:
                if r.frame not in index:
                    raise FramingError(f"{key} {r.text()}: the planner holds no frame named {r.frame!r}")
                k = frames[index[r.frame]].intrinsics
                r.checked(key, k.width, k.height)
                views[r.frame] = (frames[index[r.frame]].cam2world.copy(), k, (k.width, k.height))
        self.framing, self.framing_held, self.framing_boxes = (list(keep), list(avoid), cfg, views), [], []
        self._framed = None  # until a search applies the new regions

    def _framing(self, scorer, platform):
        """The framing lifted from the present reconstruction (it changes as frames come), or None."""
        if self.framing is None:
            return None
        from aes_planner.search.framing import build_framing

        keep, avoid, cfg, views = self.framing
        photos = [f for f, _ in self._frames]  # the held frames, for FramingConfig.photo_rank
        return build_framing(scorer, views, keep, avoid, platform.intrinsics, cfg, photos)

    def scorer(self):
        """The scorer of the present frames (rebuilt only when they changed)."""
        if self._scorer is None or self._scorer_version != self.version:
            from aes_planner.search import SearchConfig, build_search_scorer

            frames = [f for f, _ in self._frames]
            cfg = SearchConfig.preset(self.preset)
            self._scorer = build_search_scorer(self.scorer_kind, frames, cfg, teacher=self.teacher)
            self._scorer_version = self.version
        return self._scorer

    def score_views(self, cam2world: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [N]
        poses = torch.as_tensor(np.asarray(cam2world, dtype=np.float64).reshape(-1, 4, 4))  # [N, 4, 4]
        if not len(poses):
            return np.zeros(0)
        with torch.no_grad():
            return self.scorer().score_batched(poses).score.double().numpy()

    def propose(
        self,
        platform: Platform,
        captured_cam2world: np.ndarray,
        top_k: int,
        keep_near: int | None = None,
        search: dict | None = None,
    ) -> Proposal:
        """The search over the present frames, avoiding ``captured_cam2world`` (but the one at
        ``keep_near``); ``search``: :class:`~aes_planner.search.SearchConfig` fields set on top of
        the preset (the active loop's stage 1 on a rig: ``PlannerConfig.plan_grid_deg``). The preset
        is the planner's (``SearchConfig.preset(..., planner=True)``: ``balanced`` keeps 25 steps and
        an explore pass over every partly covered view in the loop) with ``search_settings`` over it."""
        from aes_planner.search import SearchConfig, search_views

        scorer = self.scorer()
        frames = [f for f, _ in self._frames]
        inputs = np.stack([f.cam2world for f in frames if id(f) not in self._off_path])  # [N, 4, 4]
        captured = np.asarray(captured_cam2world, dtype=np.float64).reshape(-1, 4, 4)
        config = SearchConfig.preset(
            self.preset,
            mode=platform.kind,
            planner=True,
            **{"top_k": max(top_k, 1), "seed": self.seed, **self.search_settings, **(search or {})},
        )
        avoid = captured if keep_near is None else np.delete(captured, keep_near, axis=0)
        framing = self._framing(scorer, platform)
        result = search_views(scorer, inputs, platform, config, avoid=avoid if len(avoid) else None, framing=framing)
        if framing is not None:
            self.framing_boxes = [
                (kind, sub) for kind, subs in (("keep", framing.keep), ("avoid", framing.avoid)) for sub in subs
            ]
        if framing is not None and result.suggestions:
            pose = torch.as_tensor(result.best.cam2world[None])
            self.framing_held = [float(framing.held_each(pose)[0, i]) for i in range(len(framing.keep))]
            best = candidate_of(result.best)
            self._framed = FramedViews(_held_under(framing, result.best.cam2world), best)
        candidates = [candidate_of(sug) for sug in result.suggestions]
        if len(captured):
            with torch.no_grad():
                pred = scorer.score_batched(torch.as_tensor(captured, dtype=torch.float64)).score.numpy()
        else:
            pred = np.zeros(0)
        explore = result.explore  # its prediction rests on a part-seen view: sent only when finite
        explore = candidate_of(explore) if explore is not None and math.isfinite(explore.score) else None
        return Proposal(candidates, np.asarray(pred, dtype=np.float64), self.version, result.covered_fraction, explore)
