"""One path for every node that publishes ``camera/frame``: read a :class:`~aes_planner.devices.Camera`
at the node's rate, pose the image at its stamp, number it, publish it best-effort.

:class:`FrameNode` is that path; a camera node says only where its camera is
(:meth:`FrameNode.observe`: the gimbal's states, a drone's motion) and how an image is posed
(:meth:`FrameNode.pose`). The three that exist:

* :class:`~aes_planner.node.camera.CameraNode`: an OpenCV camera on a rig, posed by the rig's
  kinematics at the gimbal's joints interpolated at the image's stamp (:class:`~aes_planner.geometry.trajectory.JointHistory`);
* :class:`~aes_planner.node.sim_camera.SimCameraNode`: the simulator's camera on a rig, which
  knows (and reports, with its pose noise) where it was;
* :class:`~aes_planner.node.sim_drone.SimDroneNode`: the same camera on a simulated drone;
* :class:`~aes_planner.drone.camera.DroneSimCameraNode`: the same camera where a (simulated)
  flight stack reports the vehicle's camera pose.

Counters (in ``counters``): ``frames`` published, ``read_failures`` (the camera gave nothing),
``unposed`` (no pose at the image's stamp), ``size_mismatch`` (an image that does not match the
calibration), ``withheld`` (due while the camera's pose was stale, :meth:`FrameNode.fresh`). Frames are named ``FRAME_ID/NNNNNN`` and numbered in ``sequence``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from aes_planner.config import require, short_repr
from aes_planner.devices import Camera, CameraError, CameraImage
from aes_planner.geometry.trajectory import JointHistory
from aes_planner.graph.base import Node, Output, Outputs
from aes_planner.messages import PosedFrame

log = logging.getLogger(__name__)

__all__ = ["FRAME_OUTPUT", "FrameNode", "JointHistory", "check_frame_source"]

#: ``camera/frame`` is best-effort: under load a subscriber gets the newest frame rather than
#: blocking the camera's loop.
FRAME_OUTPUT = Output(PosedFrame, latched=False, reliable=False)


def check_frame_source(frame_id: Any, rate_hz: float) -> None:
    """The checks every camera node's config makes (``frame_id``, ``rate_hz``; numbers already
    checked finite)."""
    require(
        isinstance(frame_id, str) and frame_id.isprintable() and 1 <= len(frame_id) <= 200,
        "frame_id",
        f"must be 1-200 printable characters (each frame's id is FRAME_ID/NUMBER), got {short_repr(frame_id)}",
    )
    require(0.01 <= rate_hz <= 240, "rate_hz", f"must be in [0.01, 240] Hz, got {rate_hz}")


class FrameNode(Node):
    """The frame-publishing path (module docstring). Subclasses set ``self.camera`` (a
    :class:`Camera`) and call :meth:`_init_frames` in ``__init__``, implement :meth:`pose`, and may
    override :meth:`observe`. The config gives ``rate_hz``, ``frame_id`` and (optionally)
    ``depth``: publish the camera's depth when it has one."""

    outputs = {"camera/frame": FRAME_OUTPUT}
    camera: Camera

    def _init_frames(self) -> None:
        self.counters = {"frames": 0, "read_failures": 0, "unposed": 0, "size_mismatch": 0, "withheld": 0}
        self._last_frame_s = -np.inf

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.rate_hz

    def observe(self, inputs: Mapping[str, list], now: float) -> None:
        """Take in where the camera is (called every step, before a frame is due)."""

    def fresh(self, now: float) -> bool:
        """Whether where the camera is is known well enough to publish now (default: always); a
        frame due while not fresh is withheld and counted in ``withheld``."""
        return True

    def pose(self, image: CameraImage) -> tuple[np.ndarray, tuple[float, float] | None] | None:
        """``(cam2world [4, 4], (pan, tilt) or None)`` of ``image``; None when it cannot be posed."""
        raise NotImplementedError

    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        self.observe(inputs, now)
        if now - self._last_frame_s < self.period_s * 0.999:
            return {"camera/frame": []}
        if not self.fresh(now):
            self.counters["withheld"] += 1
            return {"camera/frame": []}
        if not self.camera.ready:
            return {"camera/frame": []}
        self._last_frame_s = now
        try:
            image = self.camera.read(now)
        except CameraError as exc:
            self.counters["size_mismatch"] += 1
            log.warning("%s: %s", self.node_id, exc)
            return {"camera/frame": []}
        if image is None:
            self.counters["read_failures"] += 1
            return {"camera/frame": []}
        posed = self.pose(image)
        if posed is None:
            self.counters["unposed"] += 1
            return {"camera/frame": []}
        return {"camera/frame": [self._frame(image, *posed)]}

    def _frame(self, image: CameraImage, cam2world: np.ndarray, joints: tuple[float, float] | None) -> PosedFrame:
        n = self.counters["frames"] + 1  # the first frame is number 1, as every topic's messages
        frame = PosedFrame(
            image=image.image,
            intrinsics=self.camera.intrinsics,
            cam2world=cam2world,
            stamp_s=image.stamp_s,
            depth_m=image.depth_m if getattr(self.config, "depth", True) else None,
            frame_id=f"{self.config.frame_id}/{n:06d}",
            sequence=n,
            **({} if joints is None else {"pan_rad": float(joints[0]), "tilt_rad": float(joints[1])}),
        )
        self.counters["frames"] += 1
        return frame
