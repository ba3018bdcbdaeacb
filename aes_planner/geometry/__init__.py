"""Geometry: frames, poses, cameras, trajectories and pan-tilt kinematics.

Conventions of the whole package, stated here once
===================================================

**World frame.** REP-103: x forward, y left, z up; metres. Gravity is -z.

**Camera frame.** OpenCV optical frame: x right, y down, z forward (out of the lens).

**Poses.** A pose is a 4x4 ``cam2world`` matrix: it maps camera-frame points to the world,
``p_world = cam2world @ p_cam``. Its inverse is ``world2cam`` (what a rasterizer wants).
Transform names read ``A2B``: ``cam2world``, ``tilt2pan``, ``base2world``.

**5-DoF view pose.** ``view = (x, y, z, yaw, pitch)`` in metres and radians, roll = 0:

* ``yaw`` turns about world +z, measured from world +x toward +y (counter-clockwise seen from
  above). ``yaw = 0`` looks along +x, ``yaw = pi/2`` along +y. Output yaw is wrapped to
  ``(-pi, pi]``; input yaw may be any finite number.
* ``pitch`` turns about the camera's horizontal (x, right) axis; **positive looks up**.
  ``pitch = +pi/2`` looks straight up, ``-pi/2`` straight down. Inputs beyond +-pi/2 are clamped
  to +-pi/2 (no upside-down cameras).
* Roll = 0 means the camera's x axis (image right) is horizontal. Its direction is
  ``right = (sin yaw, -cos yaw, 0)``, which depends on yaw only, so the rotation is smooth and
  well defined **at the poles**: at ``pitch = +-pi/2`` the view still has a yaw, carried by the
  image's right axis (image-down points along the yaw direction when looking straight up,
  and against it when looking straight down).
* Going back from a matrix, yaw and pitch are read from the forward (optical) axis; at the poles,
  where the forward axis is vertical, yaw is read from the right axis (``atan2(r_x, -r_y)``).
  Both are finite and differentiable there. A matrix with roll keeps its viewing direction and
  loses its roll.

**Quaternions.** ``(w, x, y, z)`` order, as transforms3d. A zero quaternion means identity.

**Intrinsics.** Pinhole, in pixels. Pixel ``(i, j)`` (column, row) has its centre at
``(u, v) = (i + 0.5, j + 0.5)``; a centred principal point is ``cx = W / 2``.
A camera-frame point ``(X, Y, Z)`` projects to ``u = fx X / Z + cx``, ``v = fy Y / Z + cy``.
Depth maps hold z-depth (``Z``), in metres, not the distance along the ray.

**Angles and units.** Radians inside the package; degrees and servo ticks only at the edges
(config files, CLI flags, the servo driver). Physical quantities carry unit suffixes:
``_rad``, ``_deg``, ``_m``, ``_px``, ``_s``, ``_hz``, ``_ticks``.

**Tensors.** Leading batch dimensions; functions here accept numpy arrays (computed in
float64 and returned as numpy) or torch tensors (differentiable, dtype and device preserved).

**Large coordinates.** GNSS/UTM coordinates (1e5 m and more) lose float32 precision: poses
cross the package boundary in float64 and the field lives in a :class:`LocalFrame` recentred on
the first frame (a pure translation, so z stays up and yaw/pitch keep their meaning).

**Drone (MAVLink).** The world of a drone is ENU (x east, y north, z up) at the vehicle's local
origin (plus a configured offset); the vehicle's local NED and body FRD frames are converted to it
once, in :mod:`aes_planner.drone.frames`, which states the formulas.

**Pan-tilt rig.** See :mod:`aes_planner.geometry.pantilt`: pan turns about the base's +z, tilt
about the pan frame's horizontal axis with positive tilt looking up, the camera sits on a
lever arm from the tilt axis; with an upright base, ``pan = yaw`` and ``tilt = pitch``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# Names resolve lazily (PEP 562) so that the torch-free parts (``geometry.rig``: rig
# configuration, joint limits) import without loading torch: the hardware bridge needs only them.
_EXPORTS = {
    "Intrinsics": "camera",
    "JointCommandError": "rig",
    "JointLimits": "rig",
    "PanTiltConfig": "rig",
    "JointSolution": "pantilt",
    "PanTilt": "pantilt",
    "LocalFrame": "poses",
    "cam2world_to_view": "poses",
    "direction_to_yaw_pitch": "poses",
    "look_at": "poses",
    "matrix_to_quat": "poses",
    "quat_to_matrix": "poses",
    "rigid_inverse": "poses",
    "rot_x": "poses",
    "rot_y": "poses",
    "rot_z": "poses",
    "validate_cam2world": "poses",
    "view_to_cam2world": "poses",
    "world2cam": "poses",
    "wrap_angle": "poses",
    "yaw_pitch_to_direction": "poses",
    "interpolate_poses": "trajectory",
    "interpolate_views": "trajectory",
    "slerp": "trajectory",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'aes_planner.geometry' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"aes_planner.geometry.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # for type checkers and IDEs
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.geometry.pantilt import JointSolution, PanTilt
    from aes_planner.geometry.poses import (
        LocalFrame,
        cam2world_to_view,
        direction_to_yaw_pitch,
        look_at,
        matrix_to_quat,
        quat_to_matrix,
        rigid_inverse,
        rot_x,
        rot_y,
        rot_z,
        validate_cam2world,
        view_to_cam2world,
        world2cam,
        wrap_angle,
        yaw_pitch_to_direction,
    )
    from aes_planner.geometry.rig import JointCommandError, JointLimits, PanTiltConfig
    from aes_planner.geometry.trajectory import interpolate_poses, interpolate_views, slerp
