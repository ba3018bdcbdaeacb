"""Rigid poses, 5-DoF views, quaternions, look-at and the local frame.

Conventions are in :mod:`aes_planner.geometry`. Every function takes numpy arrays (computed in
float64, returned as numpy) or torch tensors (batched, differentiable, dtype/device kept); one
torch implementation serves both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
from torch import Tensor

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.rigid import check_rigid

Array = TypeVar("Array", np.ndarray, Tensor)

__all__ = [
    "LocalFrame",
    "PoseError",
    "cam2world_to_view",
    "direction_to_yaw_pitch",
    "look_at",
    "matrix_to_quat",
    "quat_to_matrix",
    "rigid_inverse",
    "rot_x",
    "rot_y",
    "rot_z",
    "validate_cam2world",
    "view_to_cam2world",
    "world2cam",
    "wrap_angle",
    "yaw_pitch_to_direction",
]

HALF_PI = math.pi / 2

# Rotation from the camera "body" frame (x forward, y left, z up, REP-103) to the OpenCV optical
# frame's axes expressed in the body frame: optical x = -body y, optical y = -body z,
# optical z = body x. Columns are the optical axes.
BODY_TO_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], dtype=np.float64)


class PoseError(AesPlannerError, ValueError):
    """A pose matrix is malformed (shape, non-finite, not a rotation)."""


def c_order(a) -> np.ndarray:
    """``a`` as a float64 array in C order (copied only when not already): torch refuses numpy
    views with negative strides, such as ``poses[::-1]``."""
    arr = np.asarray(a, dtype=np.float64)
    return arr if arr.flags.c_contiguous else np.ascontiguousarray(arr)


def _torchify(fn: Callable[..., Tensor]) -> Callable[..., Array]:
    """Let a torch implementation accept numpy arrays: float64 in, numpy out."""

    def wrapper(*args, **kwargs):
        if any(isinstance(a, Tensor) for a in args):
            return fn(*args, **kwargs)
        targs = [torch.as_tensor(c_order(a)) if a is not None else None for a in args]
        out = fn(*targs, **kwargs)
        if isinstance(out, tuple):
            return tuple(o.numpy() for o in out)
        return out.numpy()

    wrapper.__name__ = fn.__name__
    wrapper.__doc__ = fn.__doc__
    wrapper.__wrapped__ = fn  # type: ignore[attr-defined]
    return wrapper


def wrap_angle(angle_rad: Array) -> Array:
    """Wrap angles to ``(-pi, pi]``."""
    if isinstance(angle_rad, Tensor):
        wrapped = torch.remainder(angle_rad + math.pi, 2 * math.pi) - math.pi
        return torch.where(wrapped <= -math.pi, wrapped + 2 * math.pi, wrapped)
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.remainder(a + math.pi, 2 * math.pi) - math.pi
    wrapped = np.where(wrapped <= -math.pi, wrapped + 2 * math.pi, wrapped)
    return wrapped if wrapped.ndim else float(wrapped)


def _rot(axis: int, angle: Tensor) -> Tensor:
    """Rotation matrices ``[..., 3, 3]`` about a principal axis by ``angle [...]``."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = [one, zero, zero, zero, c, -s, zero, s, c]
    elif axis == 1:
        rows = [c, zero, s, zero, one, zero, -s, zero, c]
    else:
        rows = [c, -s, zero, s, c, zero, zero, zero, one]
    return torch.stack(rows, dim=-1).reshape(*angle.shape, 3, 3)


@_torchify
def rot_x(angle_rad: Tensor) -> Tensor:
    """Rotation ``[..., 3, 3]`` about +x by ``angle_rad [...]`` (right-handed)."""
    return _rot(0, angle_rad)


@_torchify
def rot_y(angle_rad: Tensor) -> Tensor:
    """Rotation ``[..., 3, 3]`` about +y by ``angle_rad [...]`` (right-handed)."""
    return _rot(1, angle_rad)


@_torchify
def rot_z(angle_rad: Tensor) -> Tensor:
    """Rotation ``[..., 3, 3]`` about +z by ``angle_rad [...]`` (right-handed)."""
    return _rot(2, angle_rad)


def _homogeneous(rotation: Tensor, translation: Tensor) -> Tensor:
    """``[..., 3, 3]`` and ``[..., 3]`` -> ``[..., 4, 4]`` (differentiable, no in-place)."""
    top = torch.cat([rotation, translation.unsqueeze(-1)], dim=-1)  # [..., 3, 4]
    bottom = torch.zeros(*top.shape[:-2], 1, 4, dtype=top.dtype, device=top.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def yaw_pitch_rotation(yaw_rad: Tensor, pitch_rad: Tensor) -> Tensor:
    """Camera-to-world rotation ``[..., 3, 3]`` (OpenCV camera axes as columns), roll = 0.

    Columns: right ``(sin y, -cos y, 0)``, down ``(sin p cos y, sin p sin y, -cos p)``,
    forward ``(cos p cos y, cos p sin y, sin p)``. Equals ``Rz(yaw) Ry(-pitch) BODY_TO_OPTICAL``.
    """
    pitch_rad = pitch_rad.clamp(-HALF_PI, HALF_PI)
    cy, sy = torch.cos(yaw_rad), torch.sin(yaw_rad)
    cp, sp = torch.cos(pitch_rad), torch.sin(pitch_rad)
    zero = torch.zeros_like(cy)
    right = torch.stack([sy, -cy, zero], dim=-1)
    down = torch.stack([sp * cy, sp * sy, -cp], dim=-1)
    forward = torch.stack([cp * cy, cp * sy, sp], dim=-1)
    return torch.stack([right, down, forward], dim=-1)


@_torchify
def view_to_cam2world(view: Tensor) -> Tensor:
    """5-DoF view ``[..., 5]`` = (x, y, z, yaw, pitch) -> cam2world ``[..., 4, 4]``.

    Differentiable in all five entries (pitch is clamped to +-pi/2; its gradient is zero beyond).
    """
    if view.shape[-1] != 5:
        raise PoseError(f"view must have 5 entries (x, y, z, yaw, pitch), got shape {tuple(view.shape)}")
    rotation = yaw_pitch_rotation(view[..., 3], view[..., 4])
    return _homogeneous(rotation, view[..., :3])


@_torchify
def cam2world_to_view(cam2world: Tensor) -> Tensor:
    """cam2world ``[..., 4, 4]`` -> 5-DoF view ``[..., 5]``; yaw in ``(-pi, pi]``.

    Roll is discarded. Finite and differentiable at the poles (see the module conventions).
    """
    right = cam2world[..., :3, 0]
    forward = cam2world[..., :3, 2]
    # Yaw from the forward axis; at the poles (forward vertical) from the right axis, which is
    # then horizontal. atan2's inputs are selected, not its outputs, so no NaN gradient leaks.
    at_pole = forward[..., 0] ** 2 + forward[..., 1] ** 2 < 1e-12
    ya = torch.where(at_pole, right[..., 0], forward[..., 1])
    yb = torch.where(at_pole, -right[..., 1], forward[..., 0])
    yaw = torch.atan2(ya, yb)
    # Pitch: forward against the horizontal heading (cos yaw, sin yaw, 0); smooth at the poles.
    pitch = torch.atan2(forward[..., 2], forward[..., 0] * torch.cos(yaw) + forward[..., 1] * torch.sin(yaw))
    pitch = pitch.clamp(-HALF_PI, HALF_PI)
    return torch.cat([cam2world[..., :3, 3], yaw.unsqueeze(-1), pitch.unsqueeze(-1)], dim=-1)


@_torchify
def rigid_inverse(transform: Tensor) -> Tensor:
    """Inverse of rigid transforms ``[..., 4, 4]`` (``R^T``, ``-R^T t``), exact for rotations."""
    rotation_t = transform[..., :3, :3].transpose(-1, -2)
    translation = -(rotation_t @ transform[..., :3, 3:4]).squeeze(-1)
    return _homogeneous(rotation_t, translation)


def world2cam(cam2world: Array) -> Array:
    """``world2cam [..., 4, 4]`` from ``cam2world [..., 4, 4]``."""
    return rigid_inverse(cam2world)


@_torchify
def yaw_pitch_to_direction(yaw_rad: Tensor, pitch_rad: Tensor) -> Tensor:
    """Unit viewing directions ``[..., 3]`` in the world frame."""
    cp = torch.cos(pitch_rad)
    return torch.stack([cp * torch.cos(yaw_rad), cp * torch.sin(yaw_rad), torch.sin(pitch_rad)], dim=-1)


@_torchify
def direction_to_yaw_pitch(direction: Tensor, yaw_hint_rad: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Direction vectors ``[..., 3]`` (any length > 0) -> ``(yaw [...], pitch [...])``.

    For a vertical direction the yaw is undefined: ``yaw_hint_rad`` (default 0) is returned.
    """
    dx, dy, dz = direction.unbind(-1)
    horiz2 = dx * dx + dy * dy
    vertical = horiz2 <= 1e-24 * (horiz2 + dz * dz)
    hint = (
        torch.zeros_like(dx)
        if yaw_hint_rad is None
        else torch.as_tensor(yaw_hint_rad, dtype=dx.dtype, device=dx.device).expand_as(dx)
    )
    safe_x = torch.where(vertical, torch.ones_like(dx), dx)
    safe_y = torch.where(vertical, torch.zeros_like(dy), dy)
    yaw = torch.where(vertical, wrap_angle(hint), torch.atan2(safe_y, safe_x))
    horiz = torch.sqrt(torch.where(vertical, torch.ones_like(horiz2), horiz2))
    horiz = torch.where(vertical, torch.zeros_like(horiz), horiz)
    pitch = torch.atan2(dz, horiz)
    return yaw, pitch


@_torchify
def look_at(eye: Tensor, target: Tensor, yaw_hint_rad: Tensor | None = None) -> Tensor:
    """cam2world ``[..., 4, 4]`` at ``eye [..., 3]`` looking at ``target [..., 3]``, roll = 0.

    Up is world +z. When the target is straight above or below, the yaw is ``yaw_hint_rad``
    (default 0). ``eye == target`` is an error.
    """
    direction = target - eye
    if bool((direction.abs().amax(dim=-1) == 0).any()):
        raise PoseError("look_at: eye and target coincide; the viewing direction is undefined")
    yaw, pitch = direction_to_yaw_pitch.__wrapped__(direction, yaw_hint_rad)
    return _homogeneous(yaw_pitch_rotation(yaw, pitch), eye)


@_torchify
def quat_to_matrix(quat_wxyz: Tensor) -> Tensor:
    """Quaternions ``[..., 4]`` (w, x, y, z; any norm) -> rotations ``[..., 3, 3]``.

    Normalised inside; a zero (or near-zero, < 1e-12) quaternion gives the identity, with finite
    gradients.
    """
    norm2 = (quat_wxyz * quat_wxyz).sum(-1, keepdim=True)
    tiny = norm2 < 1e-24
    identity = torch.zeros_like(quat_wxyz)
    identity[..., 0] = 1.0
    q = torch.where(tiny, identity, quat_wxyz)
    q = q * torch.rsqrt(torch.where(tiny, torch.ones_like(norm2), norm2))
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


@_torchify
def matrix_to_quat(rotation: Tensor) -> Tensor:
    """Rotations ``[..., 3, 3]`` -> unit quaternions ``[..., 4]`` (w, x, y, z) with ``w >= 0``.

    Shepperd's method: the largest of the four candidates is used, so it is stable everywhere.
    """
    m = rotation
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    cands = torch.stack(
        [
            torch.stack(
                [1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            torch.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        dim=-2,
    )  # [..., 4 candidates, 4]
    diag = torch.stack([1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = diag.argmax(dim=-1, keepdim=True)  # [..., 1]
    q = torch.gather(cands, -2, best.unsqueeze(-1).expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    return torch.where(q[..., :1] < 0, -q, q)


def validate_cam2world(cam2world: np.ndarray, name: str = "cam2world", tol: float = 1e-4) -> np.ndarray:
    """Check a pose ``[4, 4]`` (or ``[3, 4]``): finite, rotation orthonormal with det +1.

    Returns it as a float64 ``[4, 4]``. Raises :class:`PoseError` naming ``name``.
    """
    return check_rigid(cam2world, name, tol, PoseError)


@dataclass(frozen=True)
class LocalFrame:
    """A local frame recentred on ``origin_m`` (a world position, float64), axes kept.

    Poses far from the world origin (GNSS/UTM, 1e5 m and more) lose precision in float32: the
    field and the rasterizer work in local coordinates, and poses cross back to world
    coordinates in float64. The frame is a pure translation, so z stays up and yaw/pitch keep
    their meaning.
    """

    origin_m: tuple[float, float, float]

    def __post_init__(self):
        if len(self.origin_m) != 3 or not all(math.isfinite(float(v)) for v in self.origin_m):
            raise PoseError(f"LocalFrame.origin_m must be 3 finite numbers, got {self.origin_m!r}")

    @classmethod
    def centred_on(cls, cam2world: np.ndarray) -> LocalFrame:
        """A frame whose origin is the camera centre of ``cam2world [4, 4]`` (float64)."""
        t = np.asarray(cam2world, dtype=np.float64)[:3, 3]
        return cls(tuple(float(v) for v in t))  # type: ignore[arg-type]

    @property
    def origin(self) -> np.ndarray:
        return np.asarray(self.origin_m, dtype=np.float64)

    def pose_to_local(self, cam2world: np.ndarray) -> np.ndarray:
        """World cam2world ``[..., 4, 4]`` -> local cam2world (float64)."""
        out = np.array(cam2world, dtype=np.float64, copy=True)
        out[..., :3, 3] -= self.origin
        return out

    def pose_to_world(self, cam2world_local: np.ndarray | Tensor) -> np.ndarray:
        """Local cam2world ``[..., 4, 4]`` (any float dtype) -> world cam2world in float64."""
        if isinstance(cam2world_local, Tensor):
            cam2world_local = cam2world_local.detach().cpu().double().numpy()
        out = np.array(cam2world_local, dtype=np.float64, copy=True)
        out[..., :3, 3] += self.origin
        return out

    def points_to_local(self, points_m: np.ndarray) -> np.ndarray:
        """World points ``[..., 3]`` -> local points (float64)."""
        return np.asarray(points_m, dtype=np.float64) - self.origin

    def points_to_world(self, points_m: np.ndarray) -> np.ndarray:
        """Local points ``[..., 3]`` -> world points (float64)."""
        return np.asarray(points_m, dtype=np.float64) + self.origin
