"""Scene sources: what training, evaluation and the search need from a scene.

The core never imports the simulator. Training and evaluation take a :class:`SceneSource`:
anything that yields posed frames at poses asked for and renders ground truth there. The
simulator is one (``aes_planner.sim.SimSource``); a source backed by a real rig that captures at
commanded poses is another. Its :class:`~aes_planner.platform.Platform` says where the camera can
go: a pan-tilt rig (its kinematics and joint limits) or a drone (an axis-aligned flight box).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.messages import PosedFrame
from aes_planner.platform import Platform

__all__ = ["SceneSource"]


class SceneSource(ABC):
    """A scene that can be imaged at any pose: frames for the field, ground truth for scoring."""

    #: A name for reports (``indoor:3``, a file name...).
    name: str
    #: The camera's platform and intrinsics.
    platform: Platform

    @abstractmethod
    def capture(self, cam2world: np.ndarray, depth: bool = True, stamp_s: float = 0.0) -> PosedFrame:
        """One frame at ``cam2world [4, 4]`` (world, float64), with depth when ``depth`` and available."""

    @abstractmethod
    def render_rgb(self, cam2world: np.ndarray, intrinsics: Intrinsics | None = None) -> np.ndarray:
        """Ground-truth RGB ``[B, H, W, 3]`` float32 in [0, 1] at ``cam2world [B, 4, 4]``
        (the platform's intrinsics unless given)."""
