"""``DroneSimCameraNode`` (type ``sim_drone_camera``): the sim camera of a software-in-the-loop
flight. It renders the scene at the camera pose a vehicle reports on ``drone/state`` (each pose
held from its stamp on, as :class:`~aes_planner.sim.SimCamera` does) and publishes
``camera/frame``. No frame is published while the newest state is older than ``max_pose_age_s``
or says the link is lost: the planner waits (counted in ``frames_withheld``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from aes_planner.config import require_numbers
from aes_planner.devices import CameraImage
from aes_planner.graph.base import Input, LaunchContext
from aes_planner.messages import DroneState
from aes_planner.node.sim_camera import SimCameraNode, SimCameraNodeConfig

__all__ = ["DroneSimCameraNode", "DroneSimCameraNodeConfig"]


@dataclass
class DroneSimCameraNodeConfig(SimCameraNodeConfig):
    """The sim camera's settings, and ``max_pose_age_s``: the oldest pose a frame may show."""

    max_pose_age_s: float = 0.5

    def __post_init__(self):
        super().__post_init__()
        require_numbers(self, ("max_pose_age_s",))


class DroneSimCameraNode(SimCameraNode):
    config_class = DroneSimCameraNodeConfig
    inputs = {"drone/state": Input(DroneState, 32)}

    def __init__(self, config=None, node_id: str = "camera", context: LaunchContext | None = None, scene=None):
        super().__init__(config or DroneSimCameraNodeConfig(), node_id, context, scene)
        self._newest: DroneState | None = None

    def _check_platform(self) -> None:
        pass  # a drone scene, or a rig scene flown around its base

    @property
    def frames_withheld(self) -> int:
        return self.counters["withheld"]

    def observe(self, inputs: Mapping[str, list], now: float) -> None:
        for s in inputs.get("drone/state", ()):
            if self._newest is None or s.stamp_s >= self._newest.stamp_s:
                self._newest = s
            self.camera.move_to(s.cam2world, min(s.stamp_s, now))

    def fresh(self, now: float) -> bool:
        s = self._newest
        return s is not None and s.link == "ok" and now - s.stamp_s <= self.config.max_pose_age_s

    def pose(self, image: CameraImage):
        return image.cam2world, None
