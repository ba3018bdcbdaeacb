"""Plausibility bounds of a posed camera: what no real camera, rig or scene has.

One set of bounds, used wherever a frame enters the package: the dataset importers (a file), the
:class:`~aes_planner.messages.PosedFrame` and gimbal messages' own validation (so a frame arriving
on a topic with absurd values is rejected by the subscription and counted, like any message that
does not decode), and the planner's check that a frame belongs to the scene it is modelling.

- field of view within :data:`FOV_RANGE_DEG` (a focal length of 1e300 or 1e-300 px is a broken
  file or sender, not a lens);
- principal point within half the image size of the image;
- camera position within :data:`MAX_COORDINATE_M` of the world origin (GNSS/UTM coordinates are
  ~1e7 m);
- joint angles within :data:`MAX_JOINT_RAD` (a position-mode joint turns less than two turns);
- a frame within :data:`MAX_LOCAL_DISTANCE_M` of the frame before it (the field models one scene
  in a local frame recentred on its first frame);
- a stamp within ``[0, MAX_STAMP_S]`` seconds (the epoch, or a simulated clock's zero, to
  2038-01-19: what ``builtin_interfaces/Time``'s int32 seconds hold; a stamp of 1e11 s is a
  broken clock, not a date), and no more than a receiver's ``max_stamp_ahead_s`` ahead of its clock.

Each function returns what is wrong as text starting with the offending field, or ``None``.
"""

from __future__ import annotations

import math

import numpy as np

from aes_planner.geometry.camera import CAMERA_FOV_RANGE_DEG, MAX_PRINCIPAL_OFFSET, Intrinsics, camera_problem

__all__ = [
    "FOV_RANGE_DEG",
    "MAX_COORDINATE_M",
    "MAX_JOINT_RAD",
    "MAX_LOCAL_DISTANCE_M",
    "MAX_STAMP_S",
    "MAX_STAMP_AHEAD_S",
    "DISTORTION_MODELS",
    "MAX_DISTORTION_ABS",
    "distortion_problem",
    "CAMERA_FOV_RANGE_DEG",
    "MAX_PRINCIPAL_OFFSET",
    "camera_problem",
    "intrinsics_problem",
    "stamp_problem",
    "joint_problem",
    "position_problem",
    "distance_problem",
]

#: Fields of view a camera may have, in degrees.
FOV_RANGE_DEG = (0.1, 175.0)
#: Farthest camera position from the world origin, metres.
MAX_COORDINATE_M = 1e9
#: Largest joint angle magnitude, radians (two turns).
MAX_JOINT_RAD = 4 * math.pi
#: Farthest a frame may be from the one before it and still show the same scene, metres.
MAX_LOCAL_DISTANCE_M = 1e5
#: Default of how far ahead of a receiver's clock a stamp may be, seconds (the planner's and the
#: ROS 2 bridge's ``max_stamp_ahead_s``): further, a publisher's clock is wrong.
MAX_STAMP_AHEAD_S = 5.0
#: Distortion models (ROS ``CameraInfo.distortion_model``) and how many coefficients each takes:
#: OpenCV's, which ``cv2.undistort`` applies.
DISTORTION_MODELS = {"plumb_bob": (4, 5), "rational_polynomial": (8, 8)}
#: Largest distortion coefficient magnitude of a real lens (a wide-angle rational model's k1..k6
#: reach tens).
MAX_DISTORTION_ABS = 1e3
#: Latest stamp a message may carry, seconds (2038-01-19T03:14:07Z: ROS 2 Time's int32 seconds).
MAX_STAMP_S = float(2**31 - 1)


def stamp_problem(
    t_s: float, what: str = "stamp", now_s: float | None = None, max_ahead_s: float = math.inf
) -> str | None:
    """What is implausible about a stamp ``t_s`` (seconds), or None: not finite, negative, beyond
    :data:`MAX_STAMP_S`, or more than ``max_ahead_s`` ahead of the receiver's clock ``now_s``."""
    if not (isinstance(t_s, (int, float)) and math.isfinite(t_s) and 0.0 <= t_s <= MAX_STAMP_S):
        return f"{what}: {t_s:.6g} s is not a time (expected 0 to {MAX_STAMP_S:.0f} s, 2038-01-19)"
    if now_s is not None and t_s - now_s > max_ahead_s:
        return f"{what}: {t_s - now_s:.3g} s ahead of this clock (more than {max_ahead_s:g} s: a clock is wrong)"
    return None


def intrinsics_problem(k: Intrinsics) -> str | None:
    """What is implausible about ``k`` (field of view, principal point), or None."""
    lo, hi = FOV_RANGE_DEG
    for name, fov, f in (("fx", k.hfov_rad, k.fx), ("fy", k.vfov_rad, k.fy)):
        if not lo <= math.degrees(fov) <= hi:
            return (
                f"{name}: a focal length of {f:g} px gives a {math.degrees(fov):.3g} deg field of view over "
                f"{k.width}x{k.height} px; expected {lo} to {hi} deg (are the intrinsics in pixels?)"
            )
    for name, c, size in (("cx", k.cx, k.width), ("cy", k.cy, k.height)):
        if not -0.5 * size <= c <= 1.5 * size:
            return f"{name}: principal point {c:g} px is far outside the {size} px image; expected about {size / 2:g}"
    return None


def distortion_problem(model: str, coefficients) -> str | None:
    """What is wrong with distortion ``coefficients`` of ``model`` (None: plausible). An unknown
    model is refused (never read as another); no coefficients, or all zero, with no model is a
    pinhole camera."""
    d = np.asarray(coefficients, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(d)) or (d.size and float(np.abs(d).max()) > MAX_DISTORTION_ABS):
        return f"distortion: coefficients must be finite and within +-{MAX_DISTORTION_ABS:g}, got {np.array2string(d[:14], precision=3)}"
    if model == "" and not np.any(d):
        return None
    if model not in DISTORTION_MODELS:
        return f"distortion_model: {model[:64]!r} is not supported; use one of {', '.join(DISTORTION_MODELS)}"
    lo, hi = DISTORTION_MODELS[model]
    if np.any(d) and not lo <= d.size <= hi:
        return f"distortion: {model} takes {lo}-{hi} coefficients, got {d.size}"
    return None


def joint_problem(name: str, angle_rad: float | None) -> str | None:
    """What is implausible about a joint angle (``None``: no angle, fine)."""
    if angle_rad is not None and not abs(angle_rad) <= MAX_JOINT_RAD:
        return f"{name}: a joint angle of {angle_rad:.3g} rad is beyond two turns ({MAX_JOINT_RAD:.3g} rad)"
    return None


def position_problem(cam2world: np.ndarray) -> str | None:  # [4, 4]
    """What is implausible about the camera position of ``cam2world``, or None."""
    far = float(np.abs(np.asarray(cam2world)[:3, 3]).max())
    if not far <= MAX_COORDINATE_M:
        return f"cam2world: a camera {far:.3g} m from the world origin is beyond {MAX_COORDINATE_M:.0e} m"
    return None


def distance_problem(cam2world: np.ndarray, previous_cam2world: np.ndarray) -> str | None:  # [4, 4], [4, 4]
    """What is implausible about a frame at ``cam2world`` following one at ``previous_cam2world``."""
    d = float(np.linalg.norm(np.asarray(cam2world)[:3, 3] - np.asarray(previous_cam2world)[:3, 3]))
    if not d <= MAX_LOCAL_DISTANCE_M:
        return (
            f"cam2world: {d:.3g} m from the frame before (more than {MAX_LOCAL_DISTANCE_M:.0e} m: not the same scene)"
        )
    return None
