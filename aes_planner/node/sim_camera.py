"""``SimCameraNode``: the simulated camera on the bus.

It renders what the camera sees at ``rate_hz`` and publishes ``camera/frame``. On a rig scene the
pose comes from ``gimbal/state`` through the rig's kinematics (the present joint angles, held
from each state's stamp on); :class:`~aes_planner.node.sim_drone.SimDroneNode` is the same camera
on a simulated drone. Frames carry the joint angles they were taken at, a sequence number, and
the sim camera's pixel noise, pose noise and latency (:class:`~aes_planner.sim.SimCameraConfig`).
Frames are stamped with the node's clock (``now``) and posed at ``now`` less the rig's
``camera_latency_s`` (its calibrated delay; the sim camera's ``latency_s`` is the simulated one).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

from aes_planner.config import ConfigError, require_numbers
from aes_planner.devices import CameraImage
from aes_planner.geometry.trajectory import JointHistory
from aes_planner.graph.base import Input, LaunchContext, NodeError
from aes_planner.messages import GimbalState
from aes_planner.messages.posed_frame import MAX_FRAME_PIXELS, MAX_FRAME_SIDE_PX
from aes_planner.node.frames import FrameNode, check_frame_source
from aes_planner.node.scene import launch_scene

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
        require_numbers(self, ("rate_hz",))
        check_frame_source(self.frame_id, self.rate_hz)
        from aes_planner.config import from_dict

        self._camera = from_dict(_camera_config_class(), self.camera, "camera")


class SimCameraNode(FrameNode):
    """See the module docstring."""

    config_class = SimCameraNodeConfig
    needs_scene = True
    inputs = {"gimbal/state": Input(GimbalState, 8)}

    def __init__(
        self,
        config: SimCameraNodeConfig | None = None,
        node_id: str = "camera",
        context: LaunchContext | None = None,
        scene=None,
    ):
        super().__init__(config or SimCameraNodeConfig(), node_id, context)
        from aes_planner.sim import SimCamera

        self.scene = scene if scene is not None else launch_scene(self.context)
        self.camera = SimCamera(self.scene, self.config._camera)
        self._check_frame_size()
        self.history = JointHistory(history_s=1.0)
        self._init_frames()
        self._check_platform()

    def _check_frame_size(self) -> None:
        """A camera larger than a ``camera/frame`` message may carry fails here, naming the key,
        not on every step (the scene's camera and ``camera.width``/``height`` allow more, for
        ``sim render``)."""
        k = self.camera.intrinsics
        if max(k.width, k.height) > MAX_FRAME_SIDE_PX or k.width * k.height > MAX_FRAME_PIXELS:
            raise ConfigError(
                f"{self.node_id}.camera.width",
                f"a {k.width}x{k.height} camera is larger than a camera/frame message carries (at most "
                f"{MAX_FRAME_SIDE_PX} px a side and {MAX_FRAME_PIXELS} pixels); set camera.width / camera.height "
                "smaller (the scene's camera is the default)",
            )

    def _check_platform(self) -> None:
        if self.scene.rig is None:
            raise NodeError(
                f"{self.node_id}: scene {self.scene.name!r} has a drone, not a rig: use the sim_drone node type"
            )

    def observe(self, inputs: Mapping[str, list], now: float) -> None:
        states = inputs.get("gimbal/state", ())
        for s in states:  # the camera is where the gimbal put it, from each state's stamp on
            self.camera.move_joints(s.pan_rad, s.tilt_rad, min(s.stamp_s, now))
        self.history.extend(states)

    def pose(self, image: CameraImage):
        """The pose the sim camera reports (with its pose noise; at the exposure when the rig has a
        calibrated ``camera_latency_s``), and the joints at the stamp."""
        latency_s = self.scene.rig.pan_tilt.camera_latency_s
        cam2world = self.camera.pose_at(image.stamp_s - latency_s) if latency_s else image.cam2world
        return cam2world, self.history.joints_at(image.stamp_s)
