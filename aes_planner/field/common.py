"""Pieces shared by the scorers of this package: knobs, the world -> local pose move, intrinsics.

Every scorer here works in the reconstruction's :class:`~aes_planner.geometry.LocalFrame` (a
translation recentred on the first frame, so GNSS/UTM poses keep their precision) and takes
world-frame poses at its boundary in float64; :func:`local_world2cam` moves them inside,
differentiably.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import torch
from torch import Tensor

from aes_planner.config import from_dict, require
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import LocalFrame, rigid_inverse
from aes_planner.reconstruct import ReconstructConfig

__all__ = ["UNSEEN_CELLS", "ScorerConfig", "local_world2cam", "render_intrinsics"]

#: What the field puts into a view's unseen cells when it scores (``ScorerConfig.unseen_cells``).
UNSEEN_CELLS = ("inputs", "decoder")


@dataclass
class ScorerConfig:
    """Knobs every scorer built from frames shares (the search presets override them).

    * ``render_width_px``: width of the views the scorer renders (height keeps the input
      frames' aspect ratio): the speed/accuracy knob of scoring.
    * ``max_gaussians``: the reconstruction's Gaussian budget cap (memory stays flat below it).
    * ``background``: RGB the rendered colour is composited over where nothing was observed.
    * ``unseen_cells`` (the field): what a view's cells that no input saw hold when it is scored.
      ``"decoder"`` (default): the decoder's own guess, a smooth map the head reads as empty
      frame edges and a clean horizon, which over-rates the views a search picks.
      ``"inputs"``: the mean over the input views of the teacher's head on the field's map
      blended, cell by cell with the rendered alpha, into that input's own map (what the scene
      holds where the inputs looked, at the same place in the frame). It removes most of the
      over-rating but ranks no better and the searches and the demo pick no better: tried, not
      the default (docs/results/oneshot/rank_diagnosis.md).
    * ``reconstruct``: every other reconstruction knob.
    """

    render_width_px: int = 48
    max_gaussians: int = 20_000
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    unseen_cells: str = "decoder"
    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)

    def __post_init__(self):
        if isinstance(self.reconstruct, Mapping):  # from YAML or keyword knobs
            self.reconstruct = from_dict(ReconstructConfig, self.reconstruct, "reconstruct")
        require(
            isinstance(self.reconstruct, ReconstructConfig),
            "reconstruct",
            f"must be a ReconstructConfig or a mapping of its fields, got {type(self.reconstruct).__name__}",
        )
        self.background = tuple(float(v) for v in self.background)
        require(
            isinstance(self.render_width_px, int) and 8 <= self.render_width_px <= 4096,
            "render_width_px",
            f"must be an integer in [8, 4096] pixels, got {self.render_width_px!r}",
        )
        require(
            isinstance(self.max_gaussians, int) and self.max_gaussians >= 1,
            "max_gaussians",
            f"must be a positive integer, got {self.max_gaussians!r}",
        )
        require(len(self.background) == 3, "background", f"must be 3 numbers (RGB), got {self.background!r}")
        require(
            self.unseen_cells in UNSEEN_CELLS,
            "unseen_cells",
            f"must be one of {list(UNSEEN_CELLS)}, got {self.unseen_cells!r}",
        )

    def reconstruct_config(self) -> ReconstructConfig:
        """The reconstruction config with this config's budget cap, aiming its splat stride at the
        render width (Gaussians finer than the views they are rendered at cost time, add nothing)."""
        from dataclasses import replace

        return replace(
            self.reconstruct,
            max_gaussians=min(self.reconstruct.max_gaussians, self.max_gaussians),
            target_width_px=self.render_width_px,
        )


def render_intrinsics(frame_intrinsics: Intrinsics, width_px: int) -> Intrinsics:
    """The frames' camera resampled to ``width_px`` wide (same field of view and aspect)."""
    height = max(1, int(round(frame_intrinsics.height * width_px / frame_intrinsics.width)))
    return frame_intrinsics.scaled(width_px, height)


def local_world2cam(cam2world: Tensor, local: LocalFrame | None) -> Tensor:  # [B, 4, 4] f64 world -> [B, 4, 4] f64
    """World-frame ``cam2world`` -> ``world2cam`` in the local frame, float64, differentiable."""
    if local is not None:
        shift = torch.zeros(4, 4, dtype=torch.float64, device=cam2world.device)
        shift[:3, 3] = torch.as_tensor(local.origin, dtype=torch.float64)
        cam2world = cam2world - shift  # a constant translation: exact in float64, gradient passes unchanged
    return rigid_inverse(cam2world)
