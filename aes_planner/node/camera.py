"""``CameraNode``: a real camera on a pan-tilt rig, read through a :class:`~aes_planner.devices.Camera`
device picked by its ``type:`` word, as a gimbal node picks its gimbal (``camera:`` in the config;
``opencv_camera`` by default, whose short form is ``device:`` + ``calibration:``).

The OpenCV device (:class:`aes_planner.drivers.camera.OpenCVCamera`) reads each image, checks it
against the calibration (an OpenCV ``FileStorage`` or ROS ``camera_info`` YAML) and undistorts
it; this node stamps it with the host clock when it is read, and poses it by the rig's kinematics
at the gimbal's joint angles **at that stamp** less the rig's ``camera_latency_s`` (when it was
exposed): ``gimbal/state`` messages are kept for ``state_history_s`` and interpolated linearly
between the two around the stamp (held at the ends). A frame older than the history, or taken
before any gimbal state, is not published (counted). Publishing is the camera nodes' one path,
:class:`~aes_planner.node.frames.FrameNode`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

from aes_planner.config import from_dict, require, require_numbers, tag_of
from aes_planner.devices import DEVICE_TYPES, Camera, CameraImage, device_class, make_camera
from aes_planner.geometry.pantilt import PanTilt, PanTiltConfig
from aes_planner.geometry.trajectory import JointHistory
from aes_planner.graph.base import Input, LaunchContext, NodeError
from aes_planner.messages import GimbalState
from aes_planner.node.frames import FrameNode, check_frame_source
from aes_planner.node.scene import launch_scene

log = logging.getLogger(__name__)

__all__ = ["CameraNode", "CameraNodeConfig"]


@dataclass
class CameraNodeConfig:
    """* ``camera``: the camera device, a mapping ``{type: WORD, <its config keys>}`` like a gimbal
      node's ``device:`` (``aes_planner.devices.DEVICE_TYPES``: ``opencv_camera``, or one a plugin
      registers); unknown keys are errors naming the key.
    * ``device``, ``calibration``: the short form of ``camera: {type: opencv_camera, device:
      DEVICE, calibration: FILE}`` (a ``cv2.VideoCapture`` index or path/URL, and the camera-info
      YAML); not together with ``camera``.
    * ``rate_hz``: frames read per second; ``state_history_s``: gimbal states kept for posing.
    * ``rig``: the pan-tilt kinematics the camera sits on (a sim launch takes the scene's).
    * ``frame_id``: the frames' name prefix.
    """

    camera: dict | None = None
    device: int | str = 0
    calibration: str = ""
    rate_hz: float = 10.0
    state_history_s: float = 2.0
    rig: PanTiltConfig | None = None
    frame_id: str = "camera"

    def __post_init__(self):
        if self.camera is not None:
            require(
                self.device == 0 and self.calibration == "",
                "camera",
                "give the camera either as camera: {type: ..., ...} or as device: / calibration:, not both",
            )
            key = "camera"
            tag_of(self.camera, key, DEVICE_TYPES)  # a mapping with a known type word, or the error naming it
            spec = dict(self.camera)
        else:
            spec = {"type": "opencv_camera", "device": self.device, "calibration": self.calibration}
            key = ""
        # the device's settings, checked now (a bad index must fail before OpenCV sees it)
        word = tag_of(spec, key, DEVICE_TYPES)
        cls = device_class(word, f"{key}.type" if key else "type")
        require(issubclass(cls, Camera), f"{key}.type" if key else "type", f"{word!r} is not a camera device")
        fields = {k: v for k, v in spec.items() if k != "type"}
        self._spec = spec
        self._device = from_dict(cls.config_class, fields, key) if cls.config_class is not None else None
        require_numbers(self, ("rate_hz", "state_history_s"))
        check_frame_source(self.frame_id, self.rate_hz)
        require(self.state_history_s <= 60, "state_history_s", f"must be <= 60 s (memory), got {self.state_history_s}")

    @property
    def device_spec(self) -> dict:
        """The camera as one ``{type: word, <its config keys>}`` mapping (the short form read as an
        ``opencv_camera``): what :func:`aes_planner.devices.make_camera` builds, here and in
        ``aes-planner calibrate``."""
        return dict(self._spec)


class CameraNode(FrameNode):
    """See the module docstring. ``camera`` replaces the configured device (any
    :class:`~aes_planner.devices.Camera`); ``capture`` (anything with ``read() -> (ok, bgr)`` and
    ``release()``) and ``calibration`` replace the OpenCV device's ``cv2.VideoCapture`` and file."""

    config_class = CameraNodeConfig
    inputs = {"gimbal/state": Input(GimbalState, 64)}

    @classmethod
    def sim_clock_problem(cls, config) -> str | None:
        return "reads a real camera, which takes pictures in real time"

    def __init__(
        self,
        config: CameraNodeConfig | None = None,
        node_id: str = "camera",
        context: LaunchContext | None = None,
        capture=None,
        calibration=None,
        camera: Camera | None = None,
    ):
        super().__init__(config or CameraNodeConfig(), node_id, context)
        c = self.config
        rig = c.rig
        if rig is None and self.context.scene is not None and launch_scene(self.context).rig is not None:
            rig = launch_scene(self.context).rig.pan_tilt
        if rig is None:
            raise NodeError(f"{node_id}: the camera node needs the rig's kinematics: set config.rig")
        self.kinematics = PanTilt(rig)
        if camera is None and (capture is not None or calibration is not None):  # test hooks of the OpenCV device
            camera = device_class("opencv_camera")(c._device, capture=capture, calibration=calibration)
        elif camera is None:
            camera = make_camera(c.device_spec, "camera")
        self.camera = camera
        self.history = JointHistory(c.state_history_s)
        self._init_frames()

    def start(self) -> None:
        try:
            self.camera.connect()
        except Exception as exc:
            raise NodeError(f"{self.node_id}: {exc}") from None

    def stop(self) -> None:
        self.camera.disconnect()

    def joints_at(self, stamp_s: float) -> tuple[float, float] | None:
        """Joint angles at ``stamp_s``, linearly interpolated between gimbal states."""
        return self.history.joints_at(stamp_s)

    def observe(self, inputs: Mapping[str, list], now: float) -> None:
        self.history.extend(inputs.get("gimbal/state", ()))

    def pose(self, image: CameraImage):
        joints = self.history.joints_at(image.stamp_s - self.kinematics.config.camera_latency_s)  # when exposed
        if joints is None:
            return None
        return self.kinematics.forward(*joints), joints
