"""Reconstruction: posed frames -> Gaussians, modelling only what the scene requires.

Modes (``ReconstructConfig.mode``; ``auto`` picks per frame):

* **depth** — the frame carries a depth map (RGB-D camera, simulator): one flat Gaussian per
  pixel block on the unprojected surface (:mod:`~aes_planner.reconstruct.splats`).
* **stereo** — RGB frames whose poses translate: plane-sweep stereo against posed neighbours
  (:mod:`~aes_planner.reconstruct.stereo`) gives depth and confidence, then the same splats,
  weighted by confidence.
* **sphere** — RGB frames from a camera that only rotates (a pan-tilt rig: the baseline is the
  lever arm, stereo is ill-posed): the image is painted on a sphere of ``sphere_radius_m``
  around the rig, a panorama that renders correctly from the rig itself.

``auto`` uses depth whenever a frame has it; for RGB frames it measures, from the poses alone,
the parallax a point at ``nominal_depth_m`` would show between two overlapping frames
(:func:`parallax_px`) and runs stereo from ``min_parallax_px`` on, sphere below.

Overlapping frames are deduplicated in a multi-scale voxel hash (the better-observed frame keeps
each cell), hidden splats are pruned, and a **budget** — ``budget_ratio`` x the stride blocks the
deduplicated scene holds, capped at ``max_gaussians`` — is met by merging the cheapest
neighbours first (flat, uniform surfaces before texture and edges) (:mod:`~aes_planner.reconstruct.merge`).
:class:`Reconstructor` does it frame by frame (``add_frame``) with flat memory;
:func:`reconstruct` does a batch. Coordinates are local to the first frame's camera
(:class:`~aes_planner.geometry.LocalFrame`). The core never imports the simulator.
"""

from aes_planner.reconstruct.config import MODES, ReconstructConfig, ReconstructError
from aes_planner.reconstruct.reconstructor import (
    Reconstruction,
    Reconstructor,
    detect_mode,
    parallax_px,
    reconstruct,
    render_local,
)
from aes_planner.reconstruct.splats import SplatSet
from aes_planner.reconstruct.stereo import StereoConfig, StereoResult, expected_disparity_px, plane_sweep_depth

__all__ = [
    "MODES",
    "ReconstructConfig",
    "ReconstructError",
    "Reconstruction",
    "Reconstructor",
    "SplatSet",
    "StereoConfig",
    "StereoResult",
    "detect_mode",
    "expected_disparity_px",
    "parallax_px",
    "plane_sweep_depth",
    "reconstruct",
    "render_local",
]
