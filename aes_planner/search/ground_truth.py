"""``GroundTruthScorer``: the teacher's score of a scene source's ground-truth render.

It needs a :class:`~aes_planner.sources.SceneSource` that renders at any pose (the simulator),
so it is the measuring stick of the evaluation and the scorer of the oracle and of the
``inplane``/``rotation`` baselines. It knows every pose (coverage 1) but is not differentiable:
the search refines with finite differences on it (``SearchConfig.nondiff_refine``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from aes_planner.field.scorer import ScoreOutput, Scorer, check_poses
from aes_planner.geometry.camera import Intrinsics
from aes_planner.sources import SceneSource
from aes_planner.teachers.base import Teacher

__all__ = ["GroundTruthScorer"]


class GroundTruthScorer(Scorer):
    """Renders ``source.render_rgb`` at ``intrinsics`` (the platform's unless given) and scores it."""

    name = "ground_truth"
    differentiable = False

    def __init__(self, source: SceneSource, teacher: Teacher, intrinsics: Intrinsics | None = None):
        self.source = source
        self.teacher = teacher
        self.intrinsics = intrinsics or source.platform.intrinsics
        self.renders = 0  # poses rendered so far (the cost the evaluation reports)

    def render(self, cam2world: Tensor) -> Tensor:  # [B, 4, 4] -> [B, 3, H, W] float32 in [0, 1]
        poses = check_poses(cam2world, "GroundTruthScorer").detach().cpu().numpy()
        rgb = self.source.render_rgb(poses, self.intrinsics)  # [B, H, W, 3]
        self.renders += len(poses)
        return torch.from_numpy(np.ascontiguousarray(rgb)).permute(0, 3, 1, 2)

    def score(self, cam2world: Tensor) -> ScoreOutput:  # [B, 4, 4] -> ScoreOutput [B]
        images = self.render(cam2world)
        with torch.no_grad():
            terms = {k: v.detach().float() for k, v in self.teacher.explain(images).items()}
        score = torch.nan_to_num(terms["score"], nan=0.0, posinf=0.0, neginf=0.0)
        return ScoreOutput(score, torch.ones_like(score), terms)
