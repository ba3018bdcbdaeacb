"""Reconstruction: posed frames -> the geometry the aesthetic field is built on.

Today: multi-view plane-sweep stereo (:mod:`aes_planner.reconstruct.stereo`), the depth source
for RGB frames that translate.
"""

from aes_planner.reconstruct.stereo import StereoConfig, StereoResult, expected_disparity_px, plane_sweep_depth

__all__ = ["StereoConfig", "StereoResult", "expected_disparity_px", "plane_sweep_depth"]
