"""``SimCameraNode``: the simulated camera on the bus.

It renders what the camera sees at ``rate_hz`` and publishes ``camera/frame``. On a rig scene the
pose comes from ``gimbal/state`` through the rig's kinematics (the present joint angles, held
from each state's stamp on); :class:`~aes_planner.node.sim_drone.SimDroneNode` is the same camera
on a simulated drone. Frames carry the joint angles they were taken at, a sequence number, and
the sim camera's pixel noise, pose noise and latency (:class:`~aes_planner.sim.SimCameraConfig`).
Frames are stamped with the node's clock (``now``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from aes_planner.config import ConfigError, require, require_numbers, short_repr
from aes_planner.graph.base import LaunchContext, Node, NodeError, Outputs
from aes_planner.messages import GimbalState, PosedFrame
from aes_planner.messages.posed_frame import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE_PX

log = logging.getLogger(__name__)

__all__ = ["SimCameraNode", "SimCameraNodeConfig"]


def _camera_config_class():
    from aes_planner.sim import SimCameraConfig

    return SimCameraConfig


@dataclass
class SimCameraNodeConfig:
    """* ``rate_hz``: frames per second.
    * ``camera``: the sim camera's settings (``width``, ``height``, ``hfov_deg``, ``supersample``,
      ``pixel_noise_sigma``, ``pose_noise_translation_m``, ``pose_noise_rotation_deg``,
      ``latency_s``, ``seed``).
    * ``depth``: publish the rendered depth with each frame (a real RGB camera has none).
    * ``frame_id``: the frames' name prefix.
    """

    rate_hz: float = 10.0
    camera: dict = field(default_factory=dict)
    depth: bool = True
    frame_id: str = "sim_camera"

    def __post_init__(self):
        require(
            isinstance(self.frame_id, str) and self.frame_id.isprintable() and 1 <= len(self.frame_id) <= 200,
            "frame_id",
            f"must be 1-200 printable characters (each frame's id is FRAME_ID/NUMBER), got {short_repr(self.frame_id)}",
        )
        require_numbers(self, ("rate_hz",))
        require(0.01 <= self.rate_hz <= 240, "rate_hz", f"must be in [0.01, 240] Hz, got {self.rate_hz}")
        from aes_planner.config import from_dict

        self._camera = from_dict(_camera_config_class(), self.camera, "camera")


class SimCameraNode(Node):
    """See the module docstring."""

    config_class = SimCameraNodeConfig
    inputs = {"gimbal/state": (GimbalState, 8)}
    outputs = {"camera/frame": (PosedFrame, False)}

    def __init__(
        self,
        config: SimCameraNodeConfig | None = None,
        node_id: str = "camera",
        context: LaunchContext | None = None,
        scene=None,
    ):
        super().__init__(config or SimCameraNodeConfig(), node_id, context)
        from aes_planner.sim import SimCamera

        self.scene = scene if scene is not None else self.context.load_scene()
        self.camera = SimCamera(self.scene, self.config._camera)
        self._check_frame_size()
        self.frames_published = 0
        self._last_frame_s = -np.inf
        self._joints: tuple[float, float] | None = None
        self._check_platform()

    def _check_frame_size(self) -> None:
        """A camera larger than a ``camera/frame`` message may carry fails here, naming the key,
        not on every step (the scene's camera and ``camera.width``/``height`` allow more, for
        ``sim render``)."""
        k = self.camera.intrinsics
        if max(k.width, k.height) > MAX_IMAGE_SIDE_PX or k.width * k.height > MAX_IMAGE_PIXELS:
            raise ConfigError(
                f"{self.node_id}.camera.width",
                f"a {k.width}x{k.height} camera is larger than a camera/frame message carries (at most "
                f"{MAX_IMAGE_SIDE_PX} px a side and {MAX_IMAGE_PIXELS} pixels); set camera.width / camera.height "
                "smaller (the scene's camera is the default)",
            )

    def _check_platform(self) -> None:
        if self.scene.rig is None:
            raise NodeError(
                f"{self.node_id}: scene {self.scene.name!r} has a drone, not a rig: use the sim_drone node type"
            )

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.rate_hz

    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        for s in inputs.get("gimbal/state", ()):
            self._joints = (s.pan_rad, s.tilt_rad)
            self.camera.move_joints(s.pan_rad, s.tilt_rad, min(s.stamp_s, now))
        return {"camera/frame": self._maybe_capture(now)}

    def _maybe_capture(self, now: float) -> list:
        if now - self._last_frame_s < self.period_s * 0.999 or not self.camera._stamps:
            return []
        self._last_frame_s = now
        frame = self.camera.capture(now)
        msg = PosedFrame(
            image=frame.image,
            intrinsics=frame.intrinsics,
            cam2world=frame.cam2world,
            stamp_s=now,
            depth_m=frame.depth_m if self.config.depth else None,
            frame_id=f"{self.config.frame_id}/{self.frames_published:06d}",
            sequence=self.frames_published,
            **self._joint_fields(),
        )
        msg.extras = frame.extras
        self.frames_published += 1
        return [msg]

    def _joint_fields(self) -> dict:
        if self._joints is None:
            return {}
        return {"pan_rad": float(self._joints[0]), "tilt_rad": float(self._joints[1])}
