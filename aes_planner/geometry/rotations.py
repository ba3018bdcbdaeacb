"""Rotation conversions in numpy, on transforms3d: the one home of roll-pitch-yaw, quaternion and
axis rotations outside the differentiable torch code of :mod:`aes_planner.geometry.poses`.

* **Roll, pitch, yaw** are the aerospace Z-Y-X angles: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (static
  axes x, then y, then z: transforms3d's ``"sxyz"``), as a rig's ``base_rpy_deg`` and
  ``camera_mount_rpy_deg``, MAVLink's ``ATTITUDE`` (NED/FRD) and URDF's ``rpy`` state them. Going
  back, pitch is in [-pi/2, pi/2]; at the poles (pitch = +-pi/2) roll and yaw turn about the same
  axis and the turn is given to **yaw** (roll 0): a gimbal looking straight down keeps its heading.
* **Quaternions** are ``(w, x, y, z)`` (the package's order, transforms3d's); one from a matrix has
  ``w >= 0``; one into a matrix is normalised first.

numpy and transforms3d only: the drone link's process and the messages never load torch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from transforms3d import euler, quaternions

__all__ = ["matrix_to_quat", "matrix_to_rpy", "quat_to_matrix", "rot_x", "rot_y", "rot_z", "rpy_to_matrix"]


def rpy_to_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:  # -> [3, 3]
    """``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return euler.euler2mat(roll_rad, pitch_rad, yaw_rad, "sxyz")


def matrix_to_rpy(r: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of ``r [3, 3]`` (:func:`rpy_to_matrix`'s inverse); pitch in [-pi/2, pi/2]."""
    m = np.asarray(r, dtype=np.float64)
    roll, pitch, yaw = euler.mat2euler(m, "sxyz")
    if abs(m[2, 0]) > 1.0 - 1e-9:  # at a pole: the turn is yaw's (transforms3d gives it to roll)
        return 0.0, float(pitch), float(np.arctan2(-m[0, 1], m[1, 1]))
    return float(roll), float(pitch), float(yaw)


def quat_to_matrix(q_wxyz: Sequence[float]) -> np.ndarray:  # [4] -> [3, 3]
    """A quaternion (w, x, y, z; normalised here) as a rotation matrix."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    return quaternions.quat2mat(q / np.linalg.norm(q))


def matrix_to_quat(r: np.ndarray) -> np.ndarray:  # [3, 3] -> [4], w >= 0
    """A rotation matrix as a unit quaternion (w, x, y, z) with ``w >= 0``."""
    q = quaternions.mat2quat(np.asarray(r, dtype=np.float64))
    q = q / np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rot_x(angle_rad: float) -> np.ndarray:  # -> [3, 3]
    return euler.euler2mat(angle_rad, 0.0, 0.0, "sxyz")


def rot_y(angle_rad: float) -> np.ndarray:  # -> [3, 3]
    return euler.euler2mat(0.0, angle_rad, 0.0, "sxyz")


def rot_z(angle_rad: float) -> np.ndarray:  # -> [3, 3]
    return euler.euler2mat(0.0, 0.0, angle_rad, "sxyz")
