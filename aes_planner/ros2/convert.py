"""Package messages <-> ROS 2 messages: the one mapping the DDS bridge and the rosbag2 export share.

Conventions at this boundary (see :mod:`aes_planner.geometry` for the package's):

* ``header.stamp`` is the message's own stamp (a frame's capture time, a suggestion's planning
  time), split into ``int32 sec`` + ``uint32 nanosec``; never the bridge's clock.
* Poses are the camera's OpenCV optical frame (x right, y down, z forward) in the world frame
  (REP-103, x forward, y left, z up), so the ROS 2 frame of a suggestion's pose is the
  ``_optical`` frame of REP-103. Quaternions go out as ROS 2's ``x, y, z, w`` (the package keeps
  ``w, x, y, z`` inside) with ``w >= 0``.
* Intrinsics: the package puts pixel centres at ``+0.5`` (a centred principal point is
  ``W / 2``); ROS 2 and OpenCV put them at integers, so ``K``'s ``cx, cy`` are the package's
  minus 0.5 (and plus 0.5 coming in).
* Joint states: names ``pan`` and ``tilt`` (configurable), radians and rad/s.

Inbound conversions check what a ROS 2 publisher sent (array sizes, finiteness, image sizes
against ``step`` and the data length, encodings) and raise :class:`Ros2InputError` naming the
field; the bridge counts those and keeps running.
"""

from __future__ import annotations

import math

import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError
from aes_planner.geometry.plausible import distortion_problem, intrinsics_problem, joint_problem, stamp_problem
from aes_planner.geometry.rotations import matrix_to_quat
from aes_planner.messages import Candidate, Diagnostics, GimbalState, PosedFrame, ViewSuggestion
from aes_planner.messages.posed_frame import MAX_FRAME_PIXELS, MAX_FRAME_SIDE_PX
from aes_planner.ros2 import idl

__all__ = [
    "Ros2InputError",
    "camera_info",
    "compressed_image",
    "decode_camera_info",
    "decode_compressed_image",
    "decode_image",
    "diagnostic_array",
    "float64_multi_array",
    "joint_positions",
    "joint_state",
    "joint_trajectory",
    "pose",
    "pose_array",
    "pose_stamped",
    "quaternion_xyzw",
    "stamp",
    "stamp_s",
    "transform_stamped",
    "view_candidate",
    "view_suggestion",
]

IMAGE_ENCODINGS = {"rgb8": 3, "bgr8": 3, "mono8": 1}
MAX_COMPRESSED_BYTES = 64 << 20
MAX_DISTORTION = 14  # OpenCV's longest model (k1..k6, p1, p2, s1..s4, tx, ty)
DIAG_OK, DIAG_WARN, DIAG_ERROR = 0, 1, 2
# ViewSuggestion.msg's constants for the package message's ``mode`` and ``kind`` words.
MODE_CODES = {"rig": 0, "free": 1}  # MODE_RIG, MODE_FREE
KIND_CODES = {"search": 0, "waypoint": 1}  # KIND_SEARCH_RESULT, KIND_WAYPOINT

_ERROR_STATES = ("fault", "error", "failed")
_WARN_STATES = ("stopped", "degraded", "stale", "unposed")


class Ros2InputError(AesPlannerError, ValueError):
    """A ROS 2 message the bridge cannot use; the message names the field."""


# -- stamps and poses ---------------------------------------------------------------------------


def stamp(t_s: float) -> idl.Time:
    """Seconds -> ``builtin_interfaces/Time`` (sec floored, 0 <= nanosec < 1e9); a stamp the
    plausibility bounds refuse (negative, beyond 2038: int32 seconds) raises, never clamped."""
    problem = stamp_problem(t_s)
    if problem is not None:
        raise Ros2InputError(problem)
    sec, nsec = divmod(round(t_s * 1e9), 1_000_000_000)
    return idl.Time(int(sec), int(nsec))


def stamp_s(t: idl.Time, what: str = "header.stamp") -> float:
    if not 0 <= t.nanosec < 1_000_000_000:
        raise Ros2InputError(f"{what}.nanosec must be < 1e9, got {t.nanosec}")
    t_s = t.sec + t.nanosec * 1e-9
    problem = stamp_problem(t_s, what)
    if problem is not None:
        raise Ros2InputError(problem)
    return t_s


def quaternion_xyzw(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """A rotation matrix ``[3, 3]`` -> unit quaternion ``(x, y, z, w)``, ``w >= 0``: ROS's order of
    :func:`~aes_planner.geometry.rotations.matrix_to_quat` (the package's one conversion)."""
    w, x, y, z = matrix_to_quat(rotation)
    return float(x), float(y), float(z), float(w)


def pose(a2b: np.ndarray) -> idl.Pose:
    """A rigid ``[4, 4]`` -> ``geometry_msgs/Pose``."""
    x, y, z, w = quaternion_xyzw(a2b[:3, :3])
    p = a2b[:3, 3]
    return idl.Pose(idl.Point(float(p[0]), float(p[1]), float(p[2])), idl.Quaternion(x, y, z, w))


def transform_stamped(parent: str, child: str, child2parent: np.ndarray, t_s: float) -> idl.TransformStamped:
    p = pose(child2parent)
    tr = idl.Transform(idl.Vector3(p.position.x, p.position.y, p.position.z), p.orientation)
    return idl.TransformStamped(idl.Header(stamp(t_s), parent), child, tr)


# -- suggestions --------------------------------------------------------------------------------


def pose_stamped(msg: ViewSuggestion, frame_id: str) -> idl.PoseStamped | None:
    """The best candidate's camera optical-frame pose; None when the suggestion is empty."""
    if not msg.candidates:
        return None
    return idl.PoseStamped(idl.Header(stamp(msg.stamp_s), frame_id), pose(msg.candidates[0].cam2world))


def pose_array(msg: ViewSuggestion, frame_id: str) -> idl.PoseArray:
    """Every candidate, best first."""
    return idl.PoseArray(idl.Header(stamp(msg.stamp_s), frame_id), [pose(c.cam2world) for c in msg.candidates])


def view_candidate(c: Candidate, rank: int) -> idl.ViewCandidate:
    """One of the package's candidates as ``aes_planner_msgs/ViewCandidate``."""
    view = c.view
    return idl.ViewCandidate(
        rank=rank,
        score=c.score,
        coverage=c.coverage,
        pose=pose(c.cam2world),
        yaw=float(view[3]),
        pitch=float(view[4]),
        has_joints=c.pan_rad is not None,
        pan=c.pan_rad or 0.0,
        tilt=c.tilt_rad or 0.0,
        term_names=list(c.terms),
        term_values=[float(v) for v in c.terms.values()],
    )


def view_suggestion(msg: ViewSuggestion, frame_id: str, search_latency_s: float = 0.0) -> idl.ViewSuggestion:
    """Everything the package's suggestion carries, as ``aes_planner_msgs/ViewSuggestion``: the
    optional ``covered_fraction`` as a ``has_`` flag beside the value (0 when absent), the optional
    ``explore`` candidate as a sequence of at most one."""
    return idl.ViewSuggestion(
        header=idl.Header(stamp(msg.stamp_s), frame_id),
        sequence_number=msg.sequence,
        field_version=msg.field_version,
        mode=MODE_CODES[msg.mode],
        kind=KIND_CODES[msg.kind],
        search_latency_s=float(search_latency_s) if math.isfinite(search_latency_s) else 0.0,
        candidates=[view_candidate(c, rank) for rank, c in enumerate(msg.candidates)],
        has_covered_fraction=msg.covered_fraction is not None,
        covered_fraction=msg.covered_fraction or 0.0,
        explore=[] if msg.explore is None else [view_candidate(msg.explore, 0)],
    )


# -- gimbal -------------------------------------------------------------------------------------


def joint_state(
    msg: GimbalState, names: tuple[str, str], velocity_rad_s: tuple[float, float] = (0.0, 0.0)
) -> idl.JointState:
    """``sensor_msgs/JointState`` of the two joints (frame_id empty, as joint_state_broadcaster)."""
    vel = [v if math.isfinite(v) else 0.0 for v in velocity_rad_s]
    return idl.JointState(idl.Header(stamp(msg.stamp_s), ""), list(names), [msg.pan_rad, msg.tilt_rad], vel, [])


def joint_positions(msg: idl.JointState, names: tuple[str, str]) -> tuple[float, float] | None:
    """(pan, tilt) from a joint state that names both joints; None when it names neither (another
    group's state). Mismatched array sizes, a joint named alone, NaN or Inf raise."""
    n = len(msg.name)
    if len(msg.position) != n:
        raise Ros2InputError(f"JointState.position has {len(msg.position)} entries for {n} names")
    for what in ("velocity", "effort"):
        if len(getattr(msg, what)) not in (0, n):
            raise Ros2InputError(f"JointState.{what} has {len(getattr(msg, what))} entries for {n} names")
    idx = [msg.name.index(j) if j in msg.name else -1 for j in names]
    if idx == [-1, -1]:
        return None
    if -1 in idx:
        missing = names[idx.index(-1)]
        raise Ros2InputError(f"JointState names {msg.name[:8]} but not {missing!r}; both joints must be in one message")
    pan, tilt = (float(msg.position[i]) for i in idx)
    if not (math.isfinite(pan) and math.isfinite(tilt)):
        raise Ros2InputError(f"JointState.position of {names} must be finite, got ({pan}, {tilt})")
    problem = joint_problem(f"JointState.position[{names[0]}]", pan) or joint_problem(
        f"JointState.position[{names[1]}]", tilt
    )
    if problem is not None:
        raise Ros2InputError(problem)
    return pan, tilt


def joint_trajectory(pan_rad: float, tilt_rad: float, names: tuple[str, str], duration_s: float) -> idl.JointTrajectory:
    """One point reached ``duration_s`` from now (``header.stamp`` zero = start on receipt, as
    joint_trajectory_controller reads it)."""
    d = stamp(max(0.0, duration_s))
    point = idl.JointTrajectoryPoint(
        positions=[pan_rad, tilt_rad], velocities=[0.0, 0.0], time_from_start=idl.Duration(d.sec, d.nanosec)
    )
    return idl.JointTrajectory(idl.Header(idl.Time(0, 0), ""), list(names), [point])


def float64_multi_array(pan_rad: float, tilt_rad: float) -> idl.Float64MultiArray:
    """forward_position_controller's command: the joints' positions in its configured order."""
    return idl.Float64MultiArray(idl.MultiArrayLayout([], 0), [pan_rad, tilt_rad])


# -- images and camera info ---------------------------------------------------------------------


def compressed_image(frame: PosedFrame, frame_id: str, jpeg_quality: int = 90) -> idl.CompressedImage:
    import cv2

    ok, jpg = cv2.imencode(
        ".jpg", np.ascontiguousarray(frame.image[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
    )
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise Ros2InputError("JPEG encoding failed")
    return idl.CompressedImage(idl.Header(stamp(frame.stamp_s), frame_id), "jpeg", jpg.tobytes())


def camera_info(
    frame: PosedFrame, frame_id: str, distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
) -> idl.CameraInfo:
    """``sensor_msgs/CameraInfo`` (``plumb_bob``) of a frame's (undistorted) camera."""
    k = frame.intrinsics
    cx, cy = k.cx - 0.5, k.cy - 0.5
    K = [k.fx, 0.0, cx, 0.0, k.fy, cy, 0.0, 0.0, 1.0]
    P = [k.fx, 0.0, cx, 0.0, 0.0, k.fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    return idl.CameraInfo(
        header=idl.Header(stamp(frame.stamp_s), frame_id),
        height=frame.height,
        width=frame.width,
        distortion_model="plumb_bob",
        d=[float(v) for v in distortion],
        k=K,
        r=R,
        p=P,
    )


def decode_camera_info(msg: idl.CameraInfo) -> tuple[Intrinsics, np.ndarray]:
    """(intrinsics in the package's convention, distortion coefficients) of a ``CameraInfo``."""
    w, h = int(msg.width), int(msg.height)
    if not (1 <= w <= MAX_FRAME_SIDE_PX and 1 <= h <= MAX_FRAME_SIDE_PX) or w * h > MAX_FRAME_PIXELS:
        raise Ros2InputError(f"CameraInfo is {w}x{h}; the size must be non-zero and within the image caps")
    K = np.asarray(msg.k, dtype=np.float64)
    D = np.asarray(msg.d, dtype=np.float64)
    if K.shape != (9,) or not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
        raise Ros2InputError("CameraInfo.k must be 9 finite numbers with positive focal lengths (k[0], k[4])")
    if D.size > MAX_DISTORTION:
        raise Ros2InputError(f"CameraInfo.d must be at most {MAX_DISTORTION} numbers, got {D.size}")
    problem = distortion_problem(str(msg.distortion_model), D)
    if problem is not None:
        raise Ros2InputError(f"CameraInfo.{problem}")
    try:
        k = Intrinsics(float(K[0]), float(K[4]), float(K[2]) + 0.5, float(K[5]) + 0.5, w, h)
    except IntrinsicsError as exc:
        raise Ros2InputError(f"CameraInfo.k: {exc.problem or exc}") from None
    problem = intrinsics_problem(k)
    if problem is not None:
        raise Ros2InputError(f"CameraInfo.k: {problem}")
    return k, D


def _check_size(w: int, h: int, what: str) -> None:
    if not (1 <= w <= MAX_FRAME_SIDE_PX and 1 <= h <= MAX_FRAME_SIDE_PX) or w * h > MAX_FRAME_PIXELS:
        raise Ros2InputError(
            f"{what} is {w}x{h}; images must be non-empty, at most {MAX_FRAME_SIDE_PX} px a side and "
            f"{MAX_FRAME_PIXELS} px in all"
        )


def decode_image(msg: idl.Image) -> np.ndarray:
    """``sensor_msgs/Image`` (rgb8, bgr8, mono8) -> ``[H, W, 3]`` uint8 RGB."""
    channels = IMAGE_ENCODINGS.get(msg.encoding)
    if channels is None:
        raise Ros2InputError(
            f"Image.encoding {msg.encoding!r} is not supported; publish one of {sorted(IMAGE_ENCODINGS)}"
        )
    w, h, step = int(msg.width), int(msg.height), int(msg.step)
    _check_size(w, h, "Image")
    if step < w * channels:
        raise Ros2InputError(f"Image.step {step} is shorter than width x channels = {w * channels}")
    if len(msg.data) != step * h:
        raise Ros2InputError(f"Image.data has {len(msg.data)} bytes; step x height = {step * h}")
    rows = np.frombuffer(msg.data, np.uint8).reshape(h, step)[:, : w * channels]
    img = rows.reshape(h, w, channels)  # [H, W, C]
    if msg.encoding == "mono8":
        return np.repeat(img, 3, axis=2)
    if msg.encoding == "bgr8":
        return np.ascontiguousarray(img[..., ::-1])
    return np.ascontiguousarray(img)


def decode_compressed_image(msg: idl.CompressedImage) -> np.ndarray:
    """``sensor_msgs/CompressedImage`` (jpeg or png; image_transport's ``"rgb8; jpeg compressed
    bgr8"`` form too) -> ``[H, W, 3]`` uint8 RGB."""
    import cv2

    fmt = msg.format.lower()
    if "jpeg" not in fmt and "jpg" not in fmt and "png" not in fmt:
        raise Ros2InputError(f"CompressedImage.format {msg.format!r} is not supported; publish jpeg or png")
    if not 0 < len(msg.data) <= MAX_COMPRESSED_BYTES:
        raise Ros2InputError(f"CompressedImage.data has {len(msg.data)} bytes; expected 1..{MAX_COMPRESSED_BYTES}")
    data = np.frombuffer(msg.data, np.uint8)
    if data[:8].tobytes() == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        _check_size(int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), "CompressedImage (png)")
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if bgr is None:
        raise Ros2InputError("CompressedImage.data does not decode as an image")
    _check_size(bgr.shape[1], bgr.shape[0], "CompressedImage")
    return np.ascontiguousarray(bgr[..., ::-1])


# -- diagnostics --------------------------------------------------------------------------------


def diagnostic_array(msg: Diagnostics, hardware_id: str = "aes_planner") -> idl.DiagnosticArray:
    """One ``DiagnosticStatus`` named after the node; level from its state word; counters and
    values as key/value strings."""
    state = msg.state.lower()
    level = (
        DIAG_ERROR
        if any(w in state for w in _ERROR_STATES)
        else DIAG_WARN
        if any(w in state for w in _WARN_STATES)
        else DIAG_OK
    )
    values = [idl.KeyValue(k, str(v)) for k, v in msg.counters.items()]
    values += [idl.KeyValue(k, f"{v:.9g}") for k, v in msg.values.items()]
    status = idl.DiagnosticStatus(level, f"aes_planner: {msg.node}", msg.state, hardware_id, values)
    return idl.DiagnosticArray(idl.Header(stamp(msg.stamp_s), ""), [status])
