"""``ReconstructConfig``: every knob of reconstruction, validated, loadable with ``from_dict``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from aes_planner.config import require, require_numbers
from aes_planner.errors import AesPlannerError
from aes_planner.reconstruct.stereo import StereoConfig

__all__ = ["MODES", "ReconstructConfig", "ReconstructError"]

MODES = ("auto", "depth", "stereo", "sphere")


class ReconstructError(AesPlannerError, ValueError):
    """Frames that cannot be reconstructed as asked (no depth in depth mode, one frame for
    stereo, a pose stream whose scale makes no sense...). The message says what to change."""


@dataclass
class ReconstructConfig:
    """How posed frames become Gaussians (the modes, merging and budget are described in
    :mod:`aes_planner.reconstruct`).

    Mode
      * ``mode``: ``auto`` picks per frame: ``depth`` when the frame carries a depth map,
        otherwise ``stereo`` when the poses translate enough to see parallax
        (``min_parallax_px`` at ``nominal_depth_m``), otherwise ``sphere``.
      * ``nominal_depth_m``: the scene distance at which parallax is judged.
      * ``min_parallax_px``: the parallax (pixels) two overlapping frames must show for a point
        at ``nominal_depth_m`` before stereo is attempted.
      * ``sphere_radius_m``: rotation-only frames are painted on a sphere of this radius around
        the rig.
      * ``far_radius_m``: pixels without depth (sky, no sensor return) are painted on a sphere
        this far away when ``unknown_depth`` says so.
      * ``unknown_depth``: what to do with pixels that have no depth: ``skip`` them, paint them on
        the ``far`` sphere, or ``fill`` them by interpolating the inverse depth around them
        (``auto``: ``far`` for measured depth, where no return means out of range; ``fill`` for
        stereo, where no depth means no texture).

    Gaussians per frame
      * ``stride_px``: one Gaussian per ``stride x stride`` block; ``0`` = auto,
        ``max(1, round(width / target_width_px))``: no finer than the views it will be rendered at.
      * ``target_width_px``: the render width the auto stride aims at.
      * ``scale_factor``: a splat's standard deviation on screen, rasterizer blur included, in
        units of the block it stands for (0.65: neighbours overlap enough to leave no gaps,
        little enough to stay sharp; measured on the simulator's families).
      * ``flatness``: thickness along the normal relative to the in-plane size.
      * ``max_stretch``: in-plane elongation cap (grazing surfaces), in block sizes.
      * ``opacity``: opacity of every splat. Confidence (stereo) does not thin splats out (a
        see-through wall is no better than a wrong one); it ranks them when frames overlap.
      * ``sharpen_iterations``: Van Cittert steps that correct splat colours so that a frame's
        splats rendered at its own pose give back its image (undoing the blend of overlapping
        splats); each costs one render of the frame.
      * ``edge_rel``, ``edge_ratio``: a depth step between two neighbouring pixels is an edge
        when it exceeds ``edge_rel`` of the inverse depth and ``edge_ratio`` times the smaller of
        the steps beside it (planes have constant steps in inverse depth, so slanted floors are
        not edges).

    Stereo
      * ``stereo``: plane-sweep settings; ``stereo_neighbours``: frames matched per reference;
        ``stereo_consistency``: a stereo depth is kept only where a neighbour's own stereo depth
        agrees within this fraction (0 = keep all).

    Merging, pruning, budget
      * ``dedupe``: merge overlapping frames (False keeps every frame's splats: a baseline).
      * ``merge_cell_factor``: overlapping frames compete in cells this many footprints wide;
        the better-observed frame (smaller footprint, more confident) keeps the cell.
      * ``merge_margin``: a newcomer must beat the incumbent by this fraction (no churn).
      * ``min_opacity``: splats below are pruned.
      * ``min_contribution``: splats whose largest blending weight (summed over pixels) in any
        input view that sees them is below this are pruned as hidden (batch reconstruction).
      * ``budget_ratio``: the budget is ``budget_ratio x`` the samples the deduplicated scene
        holds (its extent, in stride blocks), capped at ``max_gaussians``; ``0`` disables the
        adaptive part (only the cap holds).
      * ``max_gaussians``: the hard cap.
      * ``budget_slack``: when over budget, merge down to ``(1 - slack) x budget`` so that the
        next frames do not trigger another merge.
    """

    mode: Literal["auto", "depth", "stereo", "sphere"] = "auto"
    nominal_depth_m: float = 3.0
    min_parallax_px: float = 2.0
    sphere_radius_m: float = 3.0
    far_radius_m: float = 1000.0
    unknown_depth: Literal["auto", "skip", "far", "fill"] = "auto"

    stride_px: int = 0
    target_width_px: int = 128
    scale_factor: float = 0.65
    flatness: float = 0.1
    max_stretch: float = 8.0
    opacity: float = 0.95
    sharpen_iterations: int = 1
    refit_iterations: int = 2
    edge_rel: float = 0.03
    edge_ratio: float = 3.0

    stereo: StereoConfig = field(default_factory=StereoConfig)
    stereo_neighbours: int = 2
    stereo_consistency: float = 0.05

    dedupe: bool = True
    merge_cell_factor: float = 3.0
    merge_margin: float = 0.5
    min_opacity: float = 0.05
    min_contribution: float = 0.05
    budget_ratio: float = 0.3
    max_gaussians: int = 300_000
    budget_slack: float = 0.1

    def __post_init__(self):
        require(self.mode in MODES, "mode", f"must be one of {list(MODES)}, got {self.mode!r}")
        require_numbers(
            self,
            ("nominal_depth_m", "sphere_radius_m", "far_radius_m", "scale_factor", "flatness", "merge_cell_factor"),
        )
        require(
            self.far_radius_m > self.sphere_radius_m,
            "far_radius_m",
            f"must exceed sphere_radius_m ({self.sphere_radius_m}), got {self.far_radius_m}",
        )
        require(
            self.unknown_depth in ("auto", "skip", "far", "fill"),
            "unknown_depth",
            f"must be auto, skip, far or fill, got {self.unknown_depth!r}",
        )
        require(
            math.isfinite(self.min_parallax_px) and self.min_parallax_px >= 0,
            "min_parallax_px",
            f"must be >= 0 pixels, got {self.min_parallax_px}",
        )
        require(
            isinstance(self.stride_px, int) and self.stride_px >= 0,
            "stride_px",
            f"must be an integer >= 0 (0 = auto), got {self.stride_px!r}",
        )
        require(
            isinstance(self.target_width_px, int) and self.target_width_px >= 1,
            "target_width_px",
            f"must be a positive integer, got {self.target_width_px!r}",
        )
        require(self.max_stretch >= 1, "max_stretch", f"must be >= 1, got {self.max_stretch}")
        require(0 < self.opacity <= 1, "opacity", f"must be in (0, 1], got {self.opacity}")
        require(
            isinstance(self.sharpen_iterations, int) and self.sharpen_iterations >= 0,
            "sharpen_iterations",
            f"must be an integer >= 0, got {self.sharpen_iterations!r}",
        )
        require(
            self.edge_rel > 0 and self.edge_ratio >= 1,
            "edge_rel",
            f"need edge_rel > 0 and edge_ratio >= 1, got {self.edge_rel}, {self.edge_ratio}",
        )
        require(
            isinstance(self.stereo_neighbours, int) and self.stereo_neighbours >= 1,
            "stereo_neighbours",
            f"must be >= 1, got {self.stereo_neighbours!r}",
        )
        require(
            0 <= self.stereo_consistency < 1,
            "stereo_consistency",
            f"must be in [0, 1) (0 = off), got {self.stereo_consistency}",
        )
        require(self.merge_margin >= 0, "merge_margin", f"must be >= 0, got {self.merge_margin}")
        require(0 <= self.min_opacity < 1, "min_opacity", f"must be in [0, 1), got {self.min_opacity}")
        require(self.min_contribution >= 0, "min_contribution", f"must be >= 0 (pixels), got {self.min_contribution}")
        require(
            math.isfinite(self.budget_ratio) and self.budget_ratio >= 0,
            "budget_ratio",
            f"must be >= 0 (0 = cap only), got {self.budget_ratio}",
        )
        require(
            isinstance(self.max_gaussians, int) and self.max_gaussians >= 1,
            "max_gaussians",
            f"must be a positive integer, got {self.max_gaussians!r}",
        )
        require(0 <= self.budget_slack < 1, "budget_slack", f"must be in [0, 1), got {self.budget_slack}")

    def stride_for(self, width_px: int) -> int:
        """The stride used for frames ``width_px`` wide."""
        if self.stride_px:
            return self.stride_px
        return max(1, int(round(width_px / self.target_width_px)))
