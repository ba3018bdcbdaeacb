"""``RGBScorer``: render RGB from the reconstruction at a pose and score it with the teacher.

The paper's "direct RGB scoring" baseline (and the search's ``rgb`` baseline): the Gaussians of
:func:`aes_planner.reconstruct.reconstruct` are rasterised at each pose (at ``render_width_px``),
composited over ``background``, and the teacher scores the image (``teacher.features`` then
``teacher.explain_map``). Differentiable with respect to the poses through the rasterizer and
the teacher. Coverage is the mean rendered alpha of the observed Gaussians over the view.
"""

from __future__ import annotations

import logging

import torch
from torch import Tensor

from aes_planner.field.common import ScorerConfig, local_world2cam, render_intrinsics
from aes_planner.field.scorer import ScoreOutput, Scorer, ScorerError, check_poses
from aes_planner.gaussians import Gaussians, autograd_on, rasterize
from aes_planner.geometry.camera import Intrinsics
from aes_planner.messages import PosedFrame
from aes_planner.reconstruct import Reconstruction, reconstruct
from aes_planner.teachers import Teacher, get_teacher

__all__ = ["RGBScorer"]

log = logging.getLogger(__name__)


class RGBScorer(Scorer):
    """Teacher scores of RGB rendered from a reconstruction (see the module docstring)."""

    name = "rgb"
    differentiable = True

    def __init__(
        self,
        reconstruction: Reconstruction | None,
        teacher: Teacher,
        intrinsics: Intrinsics,
        config: ScorerConfig | None = None,
    ):
        self.config = config or ScorerConfig()
        self.teacher = teacher
        self.reconstruction = reconstruction
        self.intrinsics = render_intrinsics(intrinsics, self.config.render_width_px)
        self._K = torch.from_numpy(self.intrinsics.K)  # [3, 3] float64
        self._background = torch.tensor(self.config.background, dtype=torch.float32)

    @classmethod
    def build(
        cls, frames: list[PosedFrame], teacher: Teacher | None = None, config: ScorerConfig | None = None
    ) -> RGBScorer:
        """Reconstruct ``frames`` and score renders of the result with ``teacher`` (default:
        the default teacher)."""
        cfg = config or ScorerConfig()
        frames = list(frames)
        if not frames:
            raise ScorerError("RGBScorer.build: no frames; pass at least one PosedFrame")
        # normal tensors under a caller's inference_mode: the search differentiates through them
        with autograd_on():
            rec = reconstruct(frames, cfg.reconstruct_config())
            return cls(rec, teacher or get_teacher(), frames[0].intrinsics, cfg)

    @property
    def gaussians(self) -> Gaussians | None:
        return None if self.reconstruction is None else self.reconstruction.gaussians

    def render(self, cam2world: Tensor) -> tuple[Tensor, Tensor]:  # [B, 4, 4] world -> [B, 3, h, w], [B, h, w]
        """RGB in [0, 1] and alpha at world poses (float64 in, differentiable)."""
        poses = check_poses(cam2world, "RGBScorer")
        k = self.intrinsics
        g = self.gaussians
        if g is None or len(g) == 0:
            # nothing observed: the background everywhere, alpha 0 (keep the graph to the poses)
            zero = poses.sum() * 0.0
            rgb = self._background[None, :, None, None].expand(poses.shape[0], 3, k.height, k.width) + zero.float()
            return rgb, torch.zeros(poses.shape[0], k.height, k.width, dtype=torch.float32) + zero.float()
        w2c = local_world2cam(poses, self.reconstruction.local_frame)
        out = rasterize(g, w2c, self._K, k.width, k.height, background=self._background, validate=False)
        return out.rgb.clamp(0.0, 1.0), out.alpha

    def score(self, cam2world: Tensor) -> ScoreOutput:  # [B, 4, 4] float64 world
        rgb, alpha = self.render(cam2world)
        terms = self.teacher.explain_map(self.teacher.features(rgb))
        score = terms["score"]
        return ScoreOutput(
            score=score,
            coverage=alpha.detach().mean((1, 2)).clamp(0.0, 1.0).to(torch.float64),
            terms={name: t.detach() for name, t in terms.items()},
        )
