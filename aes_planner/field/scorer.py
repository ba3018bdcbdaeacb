"""The ``Scorer`` interface: anything that scores camera poses for the search.

A scorer maps a batch of world-frame camera poses to aesthetic scores. The search (stage 1
samples, stage 2 gradient ascent), the planner node and the evaluation all talk to this
interface only, so that the aesthetic field, RGB scoring of a reconstruction and ground truth
(a renderer plus the teacher) plug in side by side.

Contract of :meth:`Scorer.score`:

* ``cam2world``: ``[B, 4, 4]`` float64 tensor in the **world frame of the input frames** (not
  a scorer's internal local frame), OpenCV camera axes, rigid. It may require grad; a
  differentiable scorer (``differentiable = True``) returns scores whose gradient reaches it.
* returns a :class:`ScoreOutput` whose tensors are all ``[B]`` (terms included), finite
  whatever the pose: a view of nothing, of unobserved space, from inside geometry or at the
  poles still has a finite score and coverage.
* ``coverage`` in ``[0, 1]`` says how much of the view the scorer actually knows (for a field:
  the rendered alpha of observed Gaussians); ground truth knows everything (1).
* ``terms`` holds the teacher's named explanation terms (``teacher.explain_map``), detached,
  always including ``"score"``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import Intrinsics

__all__ = ["ScoreOutput", "Scorer", "ScorerError", "check_poses"]


class ScorerError(AesPlannerError, ValueError):
    """Poses a scorer cannot score (wrong shape, non-finite, non-rigid)."""


@dataclass
class ScoreOutput:
    """Scores of a batch of poses; every tensor is ``[B]``."""

    score: Tensor  # [B]  differentiable w.r.t. the poses when the scorer is
    coverage: Tensor  # [B]  in [0, 1]
    terms: dict[str, Tensor] = field(default_factory=dict)  # {name: [B]}, detached

    def detach(self) -> ScoreOutput:
        return ScoreOutput(self.score.detach(), self.coverage.detach(), {k: v.detach() for k, v in self.terms.items()})


def check_poses(cam2world: Tensor, who: str) -> Tensor:  # [B, 4, 4] -> [B, 4, 4] float64
    """Validate a pose batch at a scorer's boundary and return it as float64."""
    if not isinstance(cam2world, Tensor):
        raise ScorerError(f"{who}: cam2world must be a torch.Tensor [B, 4, 4], got {type(cam2world).__name__}")
    if cam2world.dim() != 3 or tuple(cam2world.shape[1:]) != (4, 4):
        raise ScorerError(
            f"{who}: cam2world must be [B, 4, 4], got shape {tuple(cam2world.shape)}; add a batch dimension with [None]"
        )
    if cam2world.shape[0] == 0:
        raise ScorerError(f"{who}: empty batch of poses; pass at least one cam2world")
    if not bool(torch.isfinite(cam2world).all()):
        raise ScorerError(f"{who}: cam2world contains NaN or inf")
    return cam2world.to(torch.float64)


class Scorer(ABC):
    """Scores world-frame camera poses; see the module docstring for the contract."""

    #: Short name used in reports and JSON (``field``, ``rgb``, ``ground_truth``...).
    name: str = "scorer"
    #: Whether :meth:`score` is differentiable with respect to ``cam2world``.
    differentiable: bool = False
    #: The intrinsics the scorer renders at (its render resolution: a speed/accuracy knob).
    intrinsics: Intrinsics

    @abstractmethod
    def score(self, cam2world: Tensor) -> ScoreOutput:  # [B, 4, 4] float64 world -> ScoreOutput
        """Scores, coverage and explanation terms of each pose."""

    def score_batched(self, cam2world: Tensor, batch_size: int = 64) -> ScoreOutput:  # [B, 4, 4]
        """:meth:`score` in chunks of ``batch_size`` poses, without gradients, concatenated."""
        who = f"{type(self).__name__}.score_batched"
        if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
            raise ScorerError(f"{who}: batch_size must be an integer >= 1, got {batch_size!r}")
        cam2world = check_poses(cam2world, who)  # a clear error for an empty or malformed batch
        outs = []
        with torch.no_grad():
            for start in range(0, cam2world.shape[0], batch_size):
                outs.append(self.score(cam2world[start : start + batch_size]).detach())
        terms = {k: torch.cat([o.terms[k] for o in outs]) for k in outs[0].terms}
        return ScoreOutput(
            torch.cat([o.score for o in outs]),
            torch.cat([o.coverage for o in outs]),
            terms,
        )

    def score_screened(
        self,
        cam2world: Tensor,  # [B, 4, 4]
        batch_size: int,
        keep: int,
        rank: Callable[[ScoreOutput], Tensor],  # ScoreOutput of b poses -> [b] objective, higher first
        eligible: Tensor | None = None,  # [B] bool: False = rank last
    ) -> tuple[ScoreOutput, Tensor]:  # ScoreOutput of [B], exact [B] bool
        """Scores of every pose where at least the ``keep`` poses a cheaper screen ranks first
        (by ``rank`` of the screen's scores, ``eligible`` poses before the others) are scored by
        :meth:`score` itself; ``exact`` marks them, the other poses carry the screen's scores. A
        scorer without a cheaper screen scores every pose exactly (this default:
        :meth:`score_batched`); :class:`~aes_planner.field.model.AestheticField` screens with the
        splatted teacher map (its decoder left out)."""
        out = self.score_batched(cam2world, batch_size)
        return out, torch.ones(len(out.score), dtype=torch.bool)

    def score_where(
        self,
        cam2world: Tensor,  # [B, 4, 4]
        batch_size: int,
        which: Callable[[Tensor], Tensor],  # coverage [b] of a batch -> [b] bool: score these exactly
    ) -> tuple[ScoreOutput, Tensor]:  # ScoreOutput of [B], exact [B] bool
        """Coverage of every pose, and scores and terms exact where ``which`` of a batch's
        coverage says so (``exact`` marks them); the other poses carry a cheaper screen's scores,
        or are exact too. For passes that need the score of some views only (the search's explore
        pass: only the partly covered ones). A scorer without a cheaper screen scores every pose
        exactly (this default); :class:`~aes_planner.field.model.AestheticField` renders every
        pose once and decodes only the chosen ones."""
        out = self.score_batched(cam2world, batch_size)
        return out, torch.ones(len(out.score), dtype=torch.bool)
