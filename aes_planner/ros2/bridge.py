"""``Ros2BridgeNode`` (node type ``ros2_bridge``): the package's topics on a ROS 2 DDS domain.

Outbound (bus -> ROS 2; keys of :data:`OUTBOUND`, each topic and QoS remappable):

===================  ================================  ===================================  ===========
key                  default ROS 2 topic               type                                 QoS
===================  ================================  ===================================  ===========
``suggestion``       ``/planner/suggestion``           ``geometry_msgs/msg/PoseStamped``    latched
``suggestions``      ``/planner/suggestions``          ``geometry_msgs/msg/PoseArray``      latched
``view_suggestion``  ``/planner/view_suggestion``      ``aes_planner_msgs/msg/ViewSuggestion`` latched
``joint_states``     ``/gimbal/joint_states``          ``sensor_msgs/msg/JointState``       reliable
``image``            ``/camera/image/compressed``      ``sensor_msgs/msg/CompressedImage``  sensor_data
``camera_info``      ``/camera/camera_info``           ``sensor_msgs/msg/CameraInfo``       sensor_data
``tf``               ``/tf``                           ``tf2_msgs/msg/TFMessage``           reliable
``tf_static``        ``/tf_static``                    ``tf2_msgs/msg/TFMessage``           latched
``diagnostics``      ``/diagnostics``                  ``diagnostic_msgs/msg/DiagnosticArray`` reliable
===================  ================================  ===================================  ===========

tf: with the rig's kinematics known (``rig`` in the config, or the launch's simulated scene),
``/tf_static`` holds the fixed links (world -> ``gimbal_base``, ``gimbal_tilt`` ->
``camera_link`` -> ``camera_optical``) and ``/tf`` the two joints (``gimbal_base`` ->
``gimbal_pan`` -> ``gimbal_tilt``) at each frame's and each gimbal state's stamp, so that
world -> ``camera_optical`` at a frame's stamp is the frame's pose and every frame has one
parent. Without a rig, ``/tf`` carries world -> ``camera_optical`` at each frame's stamp.

Inbound (``inbound: true``; ROS 2 camera and ros2_control gimbal -> bus): ``sensor_msgs/Image``
(rgb8, bgr8, mono8) or ``CompressedImage`` with ``CameraInfo`` become ``camera/frame``, posed by
the rig's kinematics at the joint angles interpolated to the image's stamp from
``/joint_states``; joint states become ``gimbal/state``; ``gimbal/command`` goes out as a
``trajectory_msgs/JointTrajectory`` (joint_trajectory_controller) or a
``std_msgs/Float64MultiArray`` (forward_position_controller), clamped to the rig's limits.
Framing (``framing_in: true``, the default, also without ``inbound``): a
``sensor_msgs/RegionOfInterest`` on ``/planner/keep`` (``/planner/avoid``) becomes a
``PlannerRequest`` that sets the planner's kept subject (avoided region) to that box, in pixels of
the frame ``framing_frame`` names (RegionOfInterest has no header: by default ``latest``, the
newest frame the planner holds when the request arrives); the other list stays as it was. A
RegionOfInterest of zero width or height clears that list (docs/guides/framing.md).
Anything unusable is counted in ``ros2/diagnostics`` (``rejected.<key>``) and dropped. The
diagnostics also count what was sent (``sent.<key>``), carry the bus's own counters (the bridge's
inputs' ``<topic>.received``/``dropped``, ``bus.session_ok``, ``bus.session_losses``: a lost bus
session shows on ``/diagnostics`` too) and, as values, the DDS subscribers matched on each outbound
topic (``subscribers.<key>``).
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

from aes_planner.config import ConfigError, require
from aes_planner.geometry.plausible import MAX_STAMP_AHEAD_S
from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.graph.base import LaunchContext, Node, NodeError, Output, Outputs
from aes_planner.messages import Diagnostics, GimbalCommand, GimbalState, PlannerRequest, PosedFrame, ViewSuggestion
from aes_planner.node.scene import launch_scene
from aes_planner.ros2.dds import QOS_PROFILES, DdsConfig

log = logging.getLogger(__name__)

__all__ = ["OUTBOUND", "INBOUND", "Ros2BridgeConfig", "Ros2BridgeNode"]

#: key -> (default ROS 2 topic, "pkg/msg/Type", QoS profile)
OUTBOUND = {
    "suggestion": ("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched"),
    "suggestions": ("/planner/suggestions", "geometry_msgs/msg/PoseArray", "latched"),
    "view_suggestion": ("/planner/view_suggestion", "aes_planner_msgs/msg/ViewSuggestion", "latched"),
    "joint_states": ("/gimbal/joint_states", "sensor_msgs/msg/JointState", "reliable"),
    "image": ("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", "sensor_data"),
    "camera_info": ("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data"),
    "tf": ("/tf", "tf2_msgs/msg/TFMessage", "reliable"),
    "tf_static": ("/tf_static", "tf2_msgs/msg/TFMessage", "latched"),
    "diagnostics": ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "reliable"),
}
INBOUND = {
    "image_in": ("/camera/image_raw", "sensor_msgs/msg/Image", "sensor_data"),
    "compressed_in": ("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", "sensor_data"),
    "camera_info_in": ("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data"),
    "joint_states_in": ("/joint_states", "sensor_msgs/msg/JointState", "sensor_data"),
    "trajectory_out": (
        "/joint_trajectory_controller/joint_trajectory",
        "trajectory_msgs/msg/JointTrajectory",
        "reliable",
    ),
    "forward_out": ("/forward_position_controller/commands", "std_msgs/msg/Float64MultiArray", "reliable"),
    "keep_in": ("/planner/keep", "sensor_msgs/msg/RegionOfInterest", "reliable"),
    "avoid_in": ("/planner/avoid", "sensor_msgs/msg/RegionOfInterest", "reliable"),
}
DEPTHS = {"tf": 100}


def _ros_name(name: str, key: str) -> str:
    from aes_planner.transport import TopicError, validate_topic

    try:
        return "/" + validate_topic(name)
    except TopicError as exc:
        raise ConfigError(key, str(exc)) from None


@dataclass
class Ros2BridgeConfig:
    """* ``dds``: domain, discovery range, peers (:class:`aes_planner.ros2.dds.DdsConfig`).
    * ``outbound``: which of :data:`OUTBOUND` to publish; ``inbound``: read a ROS 2 rig.
    * ``topics`` / ``qos``: per key, the ROS 2 topic name / QoS profile instead of the default.
    * ``world_frame``, ``camera_frame``, ``rig_frames`` (base, pan, tilt, camera link): tf frame ids.
    * ``joint_names``: (pan, tilt) in joint states and commands.
    * ``jpeg_quality``: outbound images; ``image_transport``: inbound ``raw`` or ``compressed``.
    * ``command_interface``: ``joint_trajectory`` or ``forward_position``; ``move_speed_rad_s``
      sets a trajectory point's ``time_from_start``; ``goal_tolerance_rad``: when a move is done.
    * ``rig``: the pan-tilt kinematics (else the launch's scene's); ``state_history_s``: joint
      states kept to pose images; ``poll_hz``: how often DDS readers are polled (inbound);
      ``max_stamp_ahead_s``: an inbound image or joint state stamped further ahead of the node's
      clock is rejected and counted (the planner's guard, where ROS 2 messages enter).
    * ``framing_in``: read ``/planner/keep`` and ``/planner/avoid`` (RegionOfInterest) into
      ``planner/request``; ``framing_frame``: the frame their boxes are drawn on (``latest``: the
      newest the planner holds), ``keep_margin``: the margin those requests ask for.
    * ``ros_graph``: ``jazzy`` (also Iron, Kilted) or ``humble``: announce the bridge as ROS 2 node
      ``ros_node_name`` on ``ros_discovery_info`` (``ros2 node list``); empty = not announced
      (the message's GID differs between Humble and later releases, and a node of the other kind
      would fail to read it).
    """

    dds: DdsConfig = field(default_factory=DdsConfig)
    outbound: tuple[str, ...] = tuple(OUTBOUND)
    inbound: bool = False
    topics: dict[str, str] = field(default_factory=dict)
    qos: dict[str, str] = field(default_factory=dict)
    world_frame: str = "map"
    camera_frame: str = "camera_optical"
    rig_frames: tuple[str, str, str, str] = ("gimbal_base", "gimbal_pan", "gimbal_tilt", "camera_link")
    joint_names: tuple[str, str] = ("pan", "tilt")
    jpeg_quality: int = 90
    image_transport: str = "raw"
    command_interface: str = "joint_trajectory"
    move_speed_rad_s: float = 1.0
    goal_tolerance_rad: float = 0.02
    rig: PanTiltConfig | None = None
    state_history_s: float = 2.0
    max_stamp_ahead_s: float = MAX_STAMP_AHEAD_S
    poll_hz: float = 50.0
    ros_graph: str = ""
    ros_node_name: str = "aes_planner_bridge"
    framing_in: bool = True
    framing_frame: str = "latest"
    keep_margin: float = 0.05

    def __post_init__(self):
        self.outbound = tuple(self.outbound)
        for i, k in enumerate(self.outbound):
            require(k in OUTBOUND, f"outbound[{i}]", f"unknown key {k!r}; known: {', '.join(OUTBOUND)}")
        known = {**OUTBOUND, **INBOUND}
        for k, name in self.topics.items():
            require(k in known, f"topics.{k}", f"unknown key; known: {', '.join(known)}")
            self.topics[k] = _ros_name(name, f"topics.{k}")
        for k, prof in self.qos.items():
            require(k in known, f"qos.{k}", f"unknown key; known: {', '.join(known)}")
            require(prof in QOS_PROFILES, f"qos.{k}", f"must be one of {', '.join(QOS_PROFILES)}, got {prof!r}")
        self.rig_frames = tuple(self.rig_frames)
        require(len(self.rig_frames) == 4, "rig_frames", "must name 4 frames: base, pan, tilt, camera link")
        frames = {"world_frame": self.world_frame, "camera_frame": self.camera_frame}
        frames.update({f"rig_frames[{i}]": f for i, f in enumerate(self.rig_frames)})
        for name, value in frames.items():
            require(
                isinstance(value, str) and 0 < len(value) <= 128 and value.isprintable() and " " not in value,
                name,
                f"must be a tf frame id (1-128 printable characters, no spaces), got {value!r}",
            )
        require(
            isinstance(self.framing_frame, str)
            and 0 < len(self.framing_frame) <= 256
            and self.framing_frame.isprintable(),
            "framing_frame",
            f"must name a frame (1-256 printable characters, or 'latest'), got {self.framing_frame!r}",
        )
        require(
            isinstance(self.keep_margin, (int, float)) and 0 <= self.keep_margin < 0.4,
            "keep_margin",
            f"must be in [0, 0.4), got {self.keep_margin!r}",
        )
        require(len(set(self.joint_names)) == 2 and all(self.joint_names), "joint_names", "must be two distinct names")
        require(1 <= self.jpeg_quality <= 100, "jpeg_quality", f"must be in 1..100, got {self.jpeg_quality}")
        require(self.image_transport in ("raw", "compressed"), "image_transport", "must be 'raw' or 'compressed'")
        require(
            self.ros_graph in ("", "jazzy", "humble"), "ros_graph", "must be '', 'jazzy' (Iron and later) or 'humble'"
        )
        require(
            re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,254}", str(self.ros_node_name)) is not None,
            "ros_node_name",
            f"must be a ROS 2 node name (letters, digits, '_'; not starting with a digit), got {self.ros_node_name!r}",
        )
        require(
            self.command_interface in ("joint_trajectory", "forward_position"),
            "command_interface",
            "must be 'joint_trajectory' or 'forward_position'",
        )
        for name, lo, hi in (
            ("move_speed_rad_s", 1e-3, 100),
            ("goal_tolerance_rad", 1e-4, 1),
            ("state_history_s", 0.1, 60),
            ("max_stamp_ahead_s", 0.0, 3600),
            ("poll_hz", 1, 1000),
        ):
            v = getattr(self, name)
            require(math.isfinite(v) and lo <= v <= hi, name, f"must be in [{lo}, {hi}], got {v}")

    def topic(self, key: str) -> str:
        return self.topics.get(key) or {**OUTBOUND, **INBOUND}[key][0]

    def profile(self, key: str) -> str:
        return self.qos.get(key) or {**OUTBOUND, **INBOUND}[key][2]


class Ros2BridgeNode(Node):
    """See the module docstring."""

    config_class = Ros2BridgeConfig
    inputs = {
        "planner/suggestion": (ViewSuggestion, 8),
        "camera/frame": (PosedFrame, 2),
        "gimbal/state": (GimbalState, 32),
        "planner/diagnostics": (Diagnostics, 8),
        "gimbal/diagnostics": (Diagnostics, 8),
        "drone/diagnostics": (Diagnostics, 8),
        "gimbal/command": (GimbalCommand, 8),
    }
    outputs = {
        "camera/frame": Output(PosedFrame, latched=False, reliable=False),  # frames: best-effort, as a camera's
        "gimbal/state": (GimbalState, False),
        "ros2/diagnostics": (Diagnostics, False),
        "planner/request": (PlannerRequest, False),
    }

    @classmethod
    def sim_clock_problem(cls, config) -> str | None:
        return "bridges to a ROS 2 graph, which runs on its own clock"

    def __init__(
        self, config: Ros2BridgeConfig | None = None, node_id: str = "ros2", context: LaunchContext | None = None
    ):
        super().__init__(config or Ros2BridgeConfig(), node_id, context)
        try:
            import cyclonedds  # noqa: F401
        except ImportError:
            raise NodeError(
                f"{node_id}: the ros2_bridge node needs the ros2 extra: pip install 'aes-planner[ros2]'"
            ) from None
        c = self.config
        rig = c.rig
        if rig is None and self.context.scene is not None and launch_scene(self.context).rig is not None:
            rig = launch_scene(self.context).rig.pan_tilt
        from aes_planner.ros2.links import RigLinks

        self.links = RigLinks(rig) if rig is not None else None
        if c.inbound and self.links is None:
            raise ConfigError("rig", "inbound images are posed by the rig's kinematics: set config.rig")
        # per instance: inbound rigs produce frames and states instead of reading them
        if c.inbound:
            self.inputs = {k: v for k, v in type(self).inputs.items() if k not in ("camera/frame", "gimbal/state")}
            self.outputs = dict(type(self).outputs)
        else:
            self.inputs = {k: v for k, v in type(self).inputs.items() if k != "gimbal/command"}
            self.outputs = {"ros2/diagnostics": type(self).outputs["ros2/diagnostics"]}
        if not c.framing_in:
            self.outputs = {k: v for k, v in self.outputs.items() if k != "planner/request"}
        else:
            self.outputs["planner/request"] = type(self).outputs["planner/request"]
        self.counters: dict[str, int] = {}
        self.dds = None
        self._writers: dict = {}
        from aes_planner.ros2.outbound import OutboundMapper

        self.mapper = OutboundMapper(c, self.links)
        self._last_diag_s = -math.inf
        self._diag_seq = 0  # ros2/diagnostics: 1 for the first report
        self._inbound = None
        self._framing_readers: dict = {}
        self._framing: dict[str, list] = {"keep": [], "avoid": []}  # what the last request set
        self._requests = 0

    @property
    def period_s(self) -> float:
        # outbound work is woken by the bus; only DDS readers (inbound) need polling
        return 1.0 / self.config.poll_hz if self.config.inbound else 0.2  # framing boxes: at 5 Hz

    def count(self, key: str, n: int = 1) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    # -- life cycle ------------------------------------------------------------------------------

    def start(self) -> None:
        from aes_planner.ros2 import idl
        from aes_planner.ros2.dds import DdsParticipant

        c = self.config
        self.dds = DdsParticipant(c.dds)
        for key in c.outbound:
            if c.inbound and key in ("image", "camera_info", "joint_states"):
                continue  # the ROS 2 rig publishes these itself
            _, type_name, _ = OUTBOUND[key]
            self._writers[key] = self.dds.writer(
                c.topic(key), idl.ROS_TYPES[type_name], c.profile(key), DEPTHS.get(key)
            )
        if c.inbound:
            from aes_planner.ros2.inbound import Inbound

            self._inbound = Inbound(self, self.dds)
        if c.framing_in:
            for key in ("keep_in", "avoid_in"):
                self._framing_readers[key] = self.dds.reader(c.topic(key), idl.RegionOfInterest, c.profile(key))
        for key, sample in self.mapper.static(time.time()):
            self._write(key, sample)
        if c.ros_graph:
            self.dds.announce_node(c.ros_node_name, c.ros_graph)
        log.info(
            "%s: ROS 2 bridge on DDS domain %d (discovery %s), %d outbound topics%s",
            self.node_id,
            self.dds.domain_id,
            self.dds.discovery_range,
            len(self._writers),
            ", inbound rig" if c.inbound else "",
        )

    def stop(self) -> None:
        dds, self.dds = self.dds, None
        self._writers.clear()
        self._inbound = None
        self._framing_readers = {}
        if dds is not None:
            dds.close()

    # -- the step --------------------------------------------------------------------------------

    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        out: Outputs = {k: [] for k in self.outputs}
        for topic, msgs in inputs.items():
            for msg in msgs:
                try:
                    self._outbound(topic, msg)
                except Exception as exc:  # one bad conversion or DDS write must not stop the others
                    self.count("write_errors")
                    log.warning("%s: %s not bridged: %s", self.node_id, topic, exc)
        if self._inbound is not None:
            self._inbound.poll(inputs.get("gimbal/command", ()), out, now)
        if self._framing_readers:
            self._poll_framing(out, now)
        if now - self._last_diag_s >= 1.0:
            self._last_diag_s = now
            diag = self.diagnostics(now)
            out["ros2/diagnostics"].append(diag)
            self._outbound("ros2/diagnostics", diag)
        return out

    def _poll_framing(self, out: Outputs, now: float) -> None:
        """RegionOfInterest on /planner/keep or /planner/avoid -> a PlannerRequest setting that list."""
        from aes_planner.messages.diagnostics import FramingRegion
        from aes_planner.ros2 import idl
        from aes_planner.ros2.dds import take_checked

        for key, reader in self._framing_readers.items():
            samples, errors = take_checked(reader, idl.RegionOfInterest)
            for e in errors:
                self.count(f"rejected.{key}")
                log.warning("%s: %s: %s", self.node_id, key, e)
            self.count(f"received.{key}", len(samples) + len(errors))
            if not samples:
                continue
            roi = samples[-1]  # the newest box wins
            which = key.removesuffix("_in")
            if roi.width == 0 or roi.height == 0:
                self._framing[which] = []
            else:
                x0, y0 = float(roi.x_offset), float(roi.y_offset)
                region = FramingRegion(self.config.framing_frame, x0, y0, x0 + roi.width, y0 + roi.height)
                self._framing[which] = [region]
            self._requests += 1
            out["planner/request"].append(
                PlannerRequest(
                    "suggest",
                    stamp_s=now,
                    sequence=self._requests,
                    set_framing=True,
                    keep=list(self._framing["keep"]),
                    avoid=list(self._framing["avoid"]),
                    keep_margin=self.config.keep_margin,
                )
            )

    def _write(self, key: str, sample) -> None:
        w = self._writers.get(key)
        if w is not None and sample is not None:
            w.write(sample)
            self.count(f"sent.{key}")

    def _outbound(self, topic: str, msg) -> None:
        for key, sample in self.mapper.map(msg):
            self._write(key, sample)

    def diagnostics(self, now: float) -> Diagnostics:
        # the bus's own counters too (bus.session_ok, inputs dropped...): a ROS 2 user sees a lost
        # session on /diagnostics, not only on the graph's topics
        counters = dict(list({**self.transport_counters(), **dict(sorted(self.counters.items()))}.items())[:128])
        rejected = sum(v for k, v in self.counters.items() if k.startswith("rejected."))
        state = "rejecting input" if rejected and self._inbound and self._inbound.recent_rejections(now) else "bridging"
        values = {"search_latency_s": self.mapper.search_latency_s}
        for key, w in self._writers.items():  # who listens: the first question when a topic seems silent
            try:
                values[f"subscribers.{key}"] = float(len(w.get_matched_subscriptions()))
            except Exception:  # a writer deleted under us (stopping): no figure
                continue
        self._diag_seq += 1
        return Diagnostics(now, self.node_id, state, counters, values, self._diag_seq)
