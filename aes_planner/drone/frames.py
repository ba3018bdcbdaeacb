"""Frames of a MAVLink vehicle and their one conversion into the package's frames.

Vehicle side (MAVLink, PX4 and ArduPilot):

* **local NED**: x north, y east, z down, metres, origin where the vehicle's estimator set it
  (``LOCAL_POSITION_NED``, ``SET_POSITION_TARGET_LOCAL_NED`` in ``MAV_FRAME_LOCAL_NED``);
* **body FRD**: x forward, y right, z down; ``ATTITUDE`` gives roll, pitch, yaw (Z-Y-X Euler of
  body FRD in local NED: ``R = Rz(yaw) Ry(pitch) Rx(roll)``), yaw = heading (0 north, positive
  toward east, clockwise seen from above), positive pitch = nose up; ``ATTITUDE_QUATERNION`` is the
  same rotation as a quaternion (w, x, y, z);
* **gimbal** (protocol v2, ``GIMBAL_DEVICE_ATTITUDE_STATUS``): a quaternion of the gimbal's FRD
  frame. Its roll and pitch are always relative to the horizon; its yaw is relative to the
  vehicle's heading ("vehicle frame") or to north ("earth frame"), as the flags say
  (``q_earth = q_delta_yaw * q_vehicle``). ``MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW`` takes pitch
  (positive up) and yaw (positive right) in degrees.

Package side (:mod:`aes_planner.geometry`): **world** = REP-103 ENU, x east, y north, z up, with
its origin at the vehicle's local origin plus ``origin_m`` (a translation given in ENU);
**camera** = OpenCV optical frame (x right, y down, z forward); 5-DoF views (x, y, z, yaw, pitch)
with yaw about +z from east toward north and pitch positive up.

The conversions, all exact permutations and sign flips (float64):

* position: ``enu = (ned_y, ned_x, -ned_z)`` and back the same way (the matrix is its own inverse);
* heading: ``yaw_enu = pi/2 - yaw_ned`` and back the same way (wrapped to (-pi, pi]);
* body: ``R_enu_flu = N @ R_ned_frd @ F`` with ``N`` the NED<->ENU swap, ``F = diag(1, -1, -1)``;
* camera: the optical frame in the gimbal's FRD frame is ``R_frd_cv`` (optical x = right = FRD y,
  optical y = down = FRD z, optical z = forward = FRD x), so
  ``cam2world = [N @ R_ned_gimbal @ R_frd_cv | N @ p_ned + origin]``; a camera mount offset
  ``mount_frd_m`` (from the vehicle's origin, body FRD) adds ``N @ R_ned_frd @ mount_frd_m``.

A view (x, y, z, yaw, pitch) maps to the setpoint ``(north, east, down, heading)`` and the gimbal
pitch: a 2-axis gimbal (pitch only) leaves the heading to the vehicle (heading = pi/2 - yaw); a
3-axis gimbal may keep the vehicle's heading and yaw the camera itself (gimbal yaw relative to
the vehicle = view heading - vehicle heading, positive right).
"""

from __future__ import annotations

import math

import numpy as np

from aes_planner.geometry.rotations import matrix_to_quat, matrix_to_rpy, quat_to_matrix, rot_y, rot_z, rpy_to_matrix

__all__ = [
    "FRD_TO_FLU",
    "NED_TO_ENU",
    "R_FRD_CV",
    "camera_rotation_ned",
    "euler_to_matrix",
    "heading_enu_to_ned",
    "heading_ned_to_enu",
    "matrix_to_euler",
    "ned_to_enu",
    "enu_to_ned",
    "pose_to_cam2world",
    "quat_to_matrix",
    "matrix_to_quat",
    "body_flu_in_enu",
    "view_to_setpoint",
    "wrap",
]

#: position / vector swap between local NED and ENU (its own inverse)
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: body FRD <-> FLU (its own inverse)
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])
#: the OpenCV optical frame's axes in a camera/gimbal FRD frame (columns: optical x, y, z)
R_FRD_CV = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def wrap(angle_rad: float) -> float:
    """``angle_rad`` wrapped to (-pi, pi]."""
    a = math.atan2(math.sin(angle_rad), math.cos(angle_rad))
    return math.pi if a == -math.pi else a


def ned_to_enu(p_ned) -> np.ndarray:  # [..., 3] -> [..., 3]
    p = np.asarray(p_ned, dtype=np.float64)
    return p[..., [1, 0, 2]] * np.array([1.0, 1.0, -1.0])


def enu_to_ned(p_enu) -> np.ndarray:  # [..., 3] -> [..., 3]
    return ned_to_enu(p_enu)  # the same swap and flip


def heading_ned_to_enu(yaw_ned_rad: float) -> float:
    """Heading (0 north, clockwise) -> ENU yaw (0 east, counter-clockwise)."""
    return wrap(math.pi / 2 - yaw_ned_rad)


def heading_enu_to_ned(yaw_enu_rad: float) -> float:
    return wrap(math.pi / 2 - yaw_enu_rad)


# The rotations are geometry's (aes_planner.geometry.rotations, on transforms3d), under the names the
# MAVLink side reads them by: R_ned_frd = Rz(yaw) Ry(pitch) Rx(roll) (ATTITUDE; aerospace Z-Y-X).
euler_to_matrix = rpy_to_matrix
matrix_to_euler = matrix_to_rpy


def body_flu_in_enu(r_ned_frd: np.ndarray) -> np.ndarray:  # [3, 3] -> [3, 3]
    """The vehicle's attitude as ``R_enu_flu`` (REP-103 body in the ENU world)."""
    return NED_TO_ENU @ np.asarray(r_ned_frd, dtype=np.float64) @ FRD_TO_FLU


def camera_rotation_ned(
    vehicle_yaw_ned_rad: float, gimbal_q_wxyz=None, yaw_in_earth_frame: bool = False, pitch_rad: float | None = None
) -> np.ndarray:  # -> [3, 3]
    """``R_ned_gimbalfrd``: the gimbal's FRD frame in local NED.

    From ``GIMBAL_DEVICE_ATTITUDE_STATUS`` (``gimbal_q_wxyz``; its yaw relative to north when
    ``yaw_in_earth_frame`` else to the vehicle's heading), or, without a gimbal report, from a
    pitch alone (``pitch_rad``, positive up) on the vehicle's heading (a camera fixed to the
    body's heading, levelled)."""
    if gimbal_q_wxyz is not None:
        r = quat_to_matrix(gimbal_q_wxyz)
        return r if yaw_in_earth_frame else rot_z(vehicle_yaw_ned_rad) @ r
    return rot_z(vehicle_yaw_ned_rad) @ rot_y(pitch_rad or 0.0)


def pose_to_cam2world(
    p_ned_m, r_ned_gimbal: np.ndarray, r_ned_frd: np.ndarray | None = None, mount_frd_m=(0.0, 0.0, 0.0), origin_m=None
) -> np.ndarray:  # -> [4, 4]
    """The camera's ``cam2world`` (ENU world, OpenCV camera) from the vehicle's NED position, the
    gimbal's FRD attitude in NED and the camera's mount offset (body FRD, needs ``r_ned_frd``)."""
    p = np.asarray(p_ned_m, dtype=np.float64).reshape(3)
    mount = np.asarray(mount_frd_m, dtype=np.float64).reshape(3)
    if np.any(mount != 0.0):
        p = p + np.asarray(r_ned_frd, dtype=np.float64) @ mount
    out = np.eye(4)
    out[:3, :3] = NED_TO_ENU @ np.asarray(r_ned_gimbal, dtype=np.float64) @ R_FRD_CV
    out[:3, 3] = ned_to_enu(p) + (0.0 if origin_m is None else np.asarray(origin_m, dtype=np.float64))
    return out


def view_to_setpoint(
    view, axes: int = 2, vehicle_yaw_ned_rad: float | None = None, origin_m=None
) -> tuple[np.ndarray, float, float, float]:
    """A 5-DoF view (ENU world; yaw, pitch in radians) -> (position NED [3], heading NED,
    gimbal pitch (positive up), gimbal yaw relative to the vehicle (positive right)).

    ``axes=2``: the vehicle yaws to the view, the gimbal pitches (gimbal yaw 0). ``axes=3``: the
    vehicle keeps ``vehicle_yaw_ned_rad`` (when given) and the gimbal yaws the difference."""
    v = np.asarray(view, dtype=np.float64).reshape(5)
    p_enu = v[:3] - (0.0 if origin_m is None else np.asarray(origin_m, dtype=np.float64))
    heading = heading_enu_to_ned(float(v[3]))
    if axes == 3 and vehicle_yaw_ned_rad is not None:
        return enu_to_ned(p_enu), wrap(vehicle_yaw_ned_rad), float(v[4]), wrap(heading - vehicle_yaw_ned_rad)
    return enu_to_ned(p_enu), heading, float(v[4]), 0.0
