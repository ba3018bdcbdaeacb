"""Which ROS 2 messages each package message becomes: shared by the DDS bridge and the bag export.

:meth:`OutboundMapper.map` takes one package message and returns ``[(key, ros_message)]`` with
keys of :data:`aes_planner.ros2.bridge.OUTBOUND` (``suggestion``, ``image``, ``tf``...); the
bridge writes each to its DDS writer, the bag export to its rosbag2 connection. The conversions
themselves are :mod:`aes_planner.ros2.convert`; the mapper keeps the little state they need (the
previous gimbal state for joint velocities, the planner's search latency).
"""

from __future__ import annotations

from aes_planner.messages import Diagnostics, GimbalState, PosedFrame, ViewSuggestion
from aes_planner.ros2 import convert, idl

__all__ = ["OutboundMapper"]


class OutboundMapper:
    """``config``: a :class:`~aes_planner.ros2.bridge.Ros2BridgeConfig` (frames, joint names,
    JPEG quality); ``links``: the rig's :class:`~aes_planner.ros2.links.RigLinks` or None."""

    def __init__(self, config, links=None):
        self.config = config
        self.links = links
        self.last_state: GimbalState | None = None
        self.search_latency_s = 0.0

    def static(self, stamp_s: float) -> list:
        """``/tf_static``'s one message (the rig's fixed links), or nothing without a rig."""
        if self.links is None:
            return []
        return [("tf_static", idl.TFMessage(self.links.static_transforms(self.config, stamp_s)))]

    def map(self, msg) -> list:
        c = self.config
        if isinstance(msg, Diagnostics):
            if msg.node == "planner" or "latency_p50_s" in msg.values:
                self.search_latency_s = msg.values.get("latency_p50_s", self.search_latency_s)
            return [("diagnostics", convert.diagnostic_array(msg))]
        if isinstance(msg, ViewSuggestion):
            out = []
            if msg.kind == "search":  # a drone's waypoints only on view_suggestion, which says which is which
                best = convert.pose_stamped(msg, c.world_frame)
                if best is not None:
                    out.append(("suggestion", best))
                out.append(("suggestions", convert.pose_array(msg, c.world_frame)))
            out.append(("view_suggestion", convert.view_suggestion(msg, c.world_frame, self.search_latency_s)))
            return out
        if isinstance(msg, GimbalState):
            prev, self.last_state = self.last_state, msg
            vel = (0.0, 0.0)
            if prev is not None and msg.stamp_s > prev.stamp_s:
                dt = msg.stamp_s - prev.stamp_s
                vel = ((msg.pan_rad - prev.pan_rad) / dt, (msg.tilt_rad - prev.tilt_rad) / dt)
            out = [("joint_states", convert.joint_state(msg, c.joint_names, vel))]
            if self.links is not None:
                tfs = self.links.joint_transforms(c, msg.pan_rad, msg.tilt_rad, msg.stamp_s)
                out.append(("tf", idl.TFMessage(tfs)))
            return out
        if isinstance(msg, PosedFrame):
            out = [
                ("image", convert.compressed_image(msg, c.camera_frame, c.jpeg_quality)),
                ("camera_info", convert.camera_info(msg, c.camera_frame)),
            ]
            if self.links is not None and msg.pan_rad is not None:
                tfs = self.links.joint_transforms(c, msg.pan_rad, msg.tilt_rad, msg.stamp_s)
            else:
                tfs = [convert.transform_stamped(c.world_frame, c.camera_frame, msg.cam2world, msg.stamp_s)]
            out.append(("tf", idl.TFMessage(tfs)))
            return out
        return []
