"""The inbound half of the ROS 2 bridge: a ROS 2 camera and ros2_control gimbal drive the planner.

Polled from :meth:`aes_planner.ros2.bridge.Ros2BridgeNode.step`:

* ``CameraInfo`` (latest kept) -> intrinsics and distortion; images are undistorted with it.
* ``JointState`` naming both joints -> the joint history and a ``gimbal/state`` (``goal`` = the
  last command; ``moving`` while a joint turns faster than 0.02 rad/s, or the goal is further
  than ``goal_tolerance_rad`` for up to 5 s after the command).
* ``Image`` / ``CompressedImage`` -> ``camera/frame`` posed at the joints interpolated to the
  image's stamp. No camera info yet, a size that differs from it, or no joint state near the
  stamp: dropped and counted (``no_camera_info``, ``size_mismatch``, ``unposed``).
* Every entry is held to the package's plausibility bounds (``aes_planner.geometry.plausible``):
  stamps within 0..2038 and at most ``max_stamp_ahead_s`` ahead of the node's clock (the
  planner's guard, applied where the messages enter), joint angles, intrinsics and distortion
  (an unknown ``distortion_model`` is refused, never read as plumb_bob); what fails is rejected
  and counted (``rejected.<input>``). Joint states that jump back in time by more than
  ``state_history_s`` (a publisher's clock corrected, a bag replayed from its start) reset the
  joint history (``joint_history_resets``), so no stale or far-future state poisons it for good.
* ``gimbal/command`` (move, stop) -> one trajectory point or a forward command, clamped to the
  rig's limits: here the bridge stands where a :class:`~aes_planner.devices.Gimbal` device
  stands, so this is the one clamp of the clamp rule (:class:`~aes_planner.geometry.rig.JointLimits`);
  ``reboot`` has no ROS 2 counterpart here and is counted (``ignored_commands``).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from aes_planner.geometry.plausible import stamp_problem
from aes_planner.geometry.trajectory import JointHistory
from aes_planner.messages import GimbalCommand, GimbalState, MessageError, PosedFrame
from aes_planner.ros2 import convert, idl
from aes_planner.ros2.convert import Ros2InputError
from aes_planner.ros2.dds import take_checked

log = logging.getLogger(__name__)

__all__ = ["Inbound"]

MOVING_RAD_S = 0.02
SETTLE_TIMEOUT_S = 5.0


class Inbound:
    """Readers and the command writer of an inbound bridge (``node``: the bridge node)."""

    def __init__(self, node, dds):
        self.node = node
        c = node.config
        self.image_key = "image_in" if c.image_transport == "raw" else "compressed_in"
        image_type = idl.Image if c.image_transport == "raw" else idl.CompressedImage
        self.readers = {
            "camera_info_in": (
                dds.reader(c.topic("camera_info_in"), idl.CameraInfo, c.profile("camera_info_in")),
                idl.CameraInfo,
            ),
            "joint_states_in": (
                dds.reader(c.topic("joint_states_in"), idl.JointState, c.profile("joint_states_in"), 50),
                idl.JointState,
            ),
            self.image_key: (dds.reader(c.topic(self.image_key), image_type, c.profile(self.image_key)), image_type),
        }
        cmd_key = "trajectory_out" if c.command_interface == "joint_trajectory" else "forward_out"
        cmd_type = idl.JointTrajectory if cmd_key == "trajectory_out" else idl.Float64MultiArray
        self.cmd_key = cmd_key
        self.command_writer = dds.writer(c.topic(cmd_key), cmd_type, c.profile(cmd_key))
        self.history = JointHistory(c.state_history_s)
        self.calibration = None
        self.goal: tuple[float, float] | None = None
        self.goal_s = -math.inf
        self.frames = 0
        self.states = 0
        self._rejections: list[float] = []
        self._last_joint: tuple[float, float, float] | None = None
        self._now = -math.inf  # the time of the step being polled

    def recent_rejections(self, now: float, window_s: float = 10.0) -> int:
        """Inputs refused in the ``window_s`` seconds before ``now`` (the node's step time)."""
        self._rejections = [t for t in self._rejections if now - t < window_s]
        return len(self._rejections)

    def _reject(self, key: str, reason: str) -> None:
        self.node.count(f"rejected.{key}")
        self._rejections.append(self._now)
        n = self.node.counters[f"rejected.{key}"]
        log.log(
            logging.WARNING if n <= 3 else logging.DEBUG, "ros2 bridge: rejected %s (%d so far): %s", key, n, reason
        )

    def _take(self, key: str) -> list:
        reader, idl_type = self.readers[key]
        samples, errors = take_checked(reader, idl_type)
        for e in errors:
            self._reject(key, e)
        self.node.count(f"received.{key}", len(samples) + len(errors))
        return samples

    # -- the poll --------------------------------------------------------------------------------

    def poll(self, commands, out: dict, now: float) -> None:
        self._now = now  # the step's time: every decision below takes its time from it
        for cmd in commands:
            self._command(cmd, now)
        for msg in self._take("camera_info_in"):
            try:
                self.calibration = convert.decode_camera_info(msg)
            except Ros2InputError as exc:
                self._reject("camera_info_in", str(exc))
        for msg in self._take("joint_states_in"):
            try:
                state = self._joint_state(msg, now)
            except (Ros2InputError, MessageError) as exc:
                self._reject("joint_states_in", str(exc))
                continue
            if state is not None:
                out["gimbal/state"].append(state)
        for msg in self._take(self.image_key):
            try:
                frame = self._frame(msg, now)
            except (Ros2InputError, MessageError) as exc:
                self._reject(self.image_key, str(exc))
                continue
            if frame is not None:
                out["camera/frame"].append(frame)

    def _stamp(self, msg, what: str, now: float) -> float:
        """The message's stamp, held to the plausibility bounds and the stamp-ahead guard."""
        t = convert.stamp_s(msg.header.stamp, what)
        problem = stamp_problem(t, what, now, self.node.config.max_stamp_ahead_s)
        if problem is not None:
            raise Ros2InputError(f"{problem}; synchronise the clocks (e.g. chrony)")
        return t

    def _joint_state(self, msg: idl.JointState, now: float) -> GimbalState | None:
        c = self.node.config
        joints = convert.joint_positions(msg, c.joint_names)
        if joints is None:
            self.node.count("ignored_joint_states")
            return None
        t = self._stamp(msg, "JointState.header.stamp", now)
        newest_s = self.history.newest_stamp_s
        if newest_s is not None and t < newest_s - c.state_history_s:
            log.warning(
                "ros2 bridge: joint states jumped back %.3g s in time: the joint history starts again",
                newest_s - t,
            )
            self.node.count("joint_history_resets")
            self.history = JointHistory(c.state_history_s)
            self._last_joint = None
        pan, tilt = joints
        speed = 0.0
        if len(msg.velocity) == len(msg.name):
            v = [float(msg.velocity[msg.name.index(j)]) for j in c.joint_names]
            speed = max(abs(x) for x in v) if all(math.isfinite(x) for x in v) else 0.0
        elif self._last_joint is not None and t > self._last_joint[0]:
            t0, p0, q0 = self._last_joint
            speed = max(abs(pan - p0), abs(tilt - q0)) / (t - t0)
        self._last_joint = (t, pan, tilt)
        self.history.add(t, pan, tilt)
        goal = self.goal or (pan, tilt)
        far = max(abs(goal[0] - pan), abs(goal[1] - tilt)) > c.goal_tolerance_rad
        moving = speed > MOVING_RAD_S or (far and self._now - self.goal_s < SETTLE_TIMEOUT_S)
        self.states += 1
        return GimbalState(pan, tilt, goal[0], goal[1], moving=bool(moving), stamp_s=t, sequence=self.states)

    def _frame(self, msg, now: float) -> PosedFrame | None:
        import cv2

        if isinstance(msg, idl.Image):
            rgb = convert.decode_image(msg)
        else:
            rgb = convert.decode_compressed_image(msg)
        if self.calibration is None:
            self.node.count("no_camera_info")
            return None
        k, dist = self.calibration
        if rgb.shape[:2] != (k.height, k.width):
            self.node.count("size_mismatch")
            raise Ros2InputError(f"image is {rgb.shape[1]}x{rgb.shape[0]} but CameraInfo says {k.width}x{k.height}")
        t = self._stamp(msg, "image header.stamp", now)
        joints = self.history.joints_at(t)
        if joints is None:
            self.node.count("unposed")
            return None
        if dist.size and np.any(dist):
            K = np.array([[k.fx, 0, k.cx - 0.5], [0, k.fy, k.cy - 0.5], [0, 0, 1]])
            rgb = cv2.undistort(rgb, K, dist)
        pan, tilt = joints
        frame = PosedFrame(
            image=rgb,
            intrinsics=k,
            cam2world=self.node.links.kinematics.forward(pan, tilt),
            stamp_s=t,
            frame_id=(msg.header.frame_id or "camera")[:200],
            sequence=self.frames + 1,
            pan_rad=pan,
            tilt_rad=tilt,
        )
        self.frames += 1
        return frame

    def _command(self, cmd: GimbalCommand, now: float) -> None:
        c = self.node.config
        kin = self.node.links.kinematics
        if cmd.kind == "reboot":
            self.node.count("ignored_commands")
            return
        present = self.history.latest()
        if cmd.kind == "stop":
            if present is None:
                self.node.count("ignored_commands")
                return
            pan, tilt = present
        else:
            pan, tilt = kin.clamp(cmd.pan_rad, cmd.tilt_rad)
        dist = max(abs(pan - present[0]), abs(tilt - present[1])) if present else 0.0
        speed = cmd.speed_rad_s or c.move_speed_rad_s
        if self.cmd_key == "trajectory_out":
            sample = convert.joint_trajectory(pan, tilt, c.joint_names, max(0.1, dist / speed))
        else:
            sample = convert.float64_multi_array(pan, tilt)
        self.command_writer.write(sample)
        self.node.count(f"sent.{self.cmd_key}")
        self.goal = (pan, tilt)
        self.goal_s = now
