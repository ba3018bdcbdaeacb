"""``SplatScorer``: the no-learning baseline of the paper's Table 1 (``splat``).

Each Gaussian carries the teacher's feature map of the input view it came from, sampled at its
source pixel (bilinear); the rendered map at the target pose is average-pooled to the teacher's
map size and scored by the teacher's head. No training, no view conditioning.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from aes_planner.field.common import ScorerConfig, local_world2cam, render_intrinsics
from aes_planner.field.model import FieldInputs
from aes_planner.field.scorer import ScoreOutput, Scorer, check_poses
from aes_planner.gaussians import rasterize
from aes_planner.teachers import Teacher

__all__ = ["SplatScorer"]


class SplatScorer(Scorer):
    """Teacher features splatted through the reconstruction (see the module docstring)."""

    name = "splat"
    differentiable = True

    def __init__(self, inputs: FieldInputs, teacher: Teacher, config: ScorerConfig | None = None):
        self.config = config or ScorerConfig()
        self.teacher = teacher
        self.inputs = inputs
        self.intrinsics = render_intrinsics(inputs.intrinsics, self.config.render_width_px)
        sp = inputs.splats
        g = sp.to_gaussians()
        h, w = inputs.images.shape[-2:]
        up = F.interpolate(inputs.fmaps, size=(h, w), mode="bilinear", align_corners=False)  # [V, C, H, W]
        src = torch.from_numpy(sp.source_frame.clip(0, len(up) - 1)).long()
        col = torch.from_numpy(sp.source_pixel[:, 0].clip(0, w - 1)).long()
        row = torch.from_numpy(sp.source_pixel[:, 1].clip(0, h - 1)).long()
        g.features = up[src, :, row, col].float()  # [N, C]
        self.gaussians = g

    def score(self, cam2world: Tensor) -> ScoreOutput:
        poses = check_poses(cam2world, "SplatScorer")
        k = self.intrinsics
        c = self.teacher.feature_channels
        if len(self.gaussians) == 0:
            zero = poses.sum().float() * 0.0
            maps = torch.zeros(poses.shape[0], c, *self.teacher.feature_size, dtype=torch.float32) + zero
            coverage = torch.zeros(poses.shape[0], dtype=torch.float64)
        else:
            w2c = local_world2cam(poses, self.inputs.local_frame)
            out = rasterize(self.gaussians, w2c, torch.from_numpy(k.K), k.width, k.height, validate=False)
            maps = F.adaptive_avg_pool2d(out.features, self.teacher.feature_size)
            coverage = out.alpha.detach().mean((1, 2)).clamp(0, 1).to(torch.float64)
        terms = self.teacher.explain_scores(maps)
        return ScoreOutput(terms["score"], coverage, {k_: v.detach() for k_, v in terms.items()})
