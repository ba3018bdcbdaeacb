"""Pan-tilt kinematics: joints <-> camera pose, with the tilt offset and the camera lever arm.

The chain, each transform a function of the configuration or a joint::

    cam2world = base2world                  # where the rig stands, its base orientation
              @ Rz(pan)                     # pan joint: about the base's +z (up)
              @ T(tilt_offset_m)            # tilt-axis origin in the pan frame
              @ Ry(-tilt)                   # tilt joint: positive tilt looks up
              @ T(lever_arm_m)              # camera optical centre in the tilt frame
              @ R(camera_mount_rpy_deg)     # the camera's mounting error on the bracket (small)
              @ BODY_TO_OPTICAL             # x forward/y left/z up -> OpenCV optical axes
              @ Rz(camera_roll_deg)         # the image's rotation about the optical axis

The pan and tilt frames are REP-103 body frames (x forward, y left, z up). With an upright base
(``base_rpy_deg = (0, 0, 0)``) and zero offsets the camera's 5-DoF view is
``(base position, yaw = pan, pitch = tilt)``. Joint angles are radians here; degrees appear only
in :class:`PanTiltConfig` (the YAML edge). The servo driver maps radians to ticks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from aes_planner.geometry.poses import BODY_TO_OPTICAL, cam2world_to_view, direction_to_yaw_pitch
from aes_planner.geometry.rig import JointCommandError, JointLimits, PanTiltConfig
from aes_planner.geometry.rotations import rot_z, rpy_to_matrix

__all__ = ["PanTiltConfig", "PanTilt", "JointSolution", "JointCommandError", "chain_forward", "rpy_matrix_torch"]


@dataclass(frozen=True)
class JointSolution:
    """Joint angles that aim the camera, and whether the limits allowed it.

    ``pan_rad``/``tilt_rad`` are inside the joint limits (clamped when the aim was not
    reachable); ``error_rad`` is the angle between the requested and achieved viewing directions.
    """

    pan_rad: float
    tilt_rad: float
    reachable: bool
    error_rad: float


def rpy_matrix_torch(rpy_rad: Tensor) -> Tensor:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` ``[3, 3]`` from ``rpy_rad [3]``, differentiable (:func:`~aes_planner.geometry.rotations.rpy_to_matrix` in torch)."""
    r, p, y = rpy_rad.unbind(-1)
    one, zero = torch.ones_like(r), torch.zeros_like(r)
    rx = torch.stack([one, zero, zero, zero, r.cos(), -r.sin(), zero, r.sin(), r.cos()]).reshape(3, 3)
    ry = torch.stack([p.cos(), zero, p.sin(), zero, one, zero, -p.sin(), zero, p.cos()]).reshape(3, 3)
    rz = torch.stack([y.cos(), -y.sin(), zero, y.sin(), y.cos(), zero, zero, zero, one]).reshape(3, 3)
    return rz @ ry @ rx


def chain_forward(
    pan: Tensor,  # [...] rad
    tilt: Tensor,  # [...] rad, same shape
    tilt_offset: Tensor,  # [3] m, pan frame
    lever: Tensor,  # [3] m, tilt frame
    body_to_camera: Tensor,  # [3, 3] tilt frame -> camera axes (mount, optical axes, roll)
    base_r: Tensor,  # [3, 3] base -> world
    base_t: Tensor,  # [3] m
) -> Tensor:  # [..., 4, 4] cam2world
    """The chain of the module docstring with every link a tensor, differentiable in all of them
    (:meth:`PanTilt.forward` and the rig calibration's least squares both run it)."""
    cp, sp = torch.cos(pan), torch.sin(pan)
    ct, st = torch.cos(tilt), torch.sin(tilt)
    zero, one = torch.zeros_like(cp), torch.ones_like(cp)
    # Rz(pan) @ Ry(-tilt), built directly: [..., 3, 3]
    r_pan = torch.stack([cp, -sp, zero, sp, cp, zero, zero, zero, one], -1).reshape(*cp.shape, 3, 3)
    r_tilt = torch.stack([ct, zero, -st, zero, one, zero, st, zero, ct], -1).reshape(*cp.shape, 3, 3)
    r_joint = r_pan @ r_tilt  # tilt frame -> base frame
    # camera centre in the base frame: Rz(pan) (offset + Ry(-tilt) lever)
    centre_base = (r_pan @ (tilt_offset + (r_tilt @ lever.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
    rotation = base_r @ (r_joint @ body_to_camera)
    centre = (base_r @ centre_base.unsqueeze(-1)).squeeze(-1) + base_t
    top = torch.cat([rotation, centre.unsqueeze(-1)], dim=-1)
    bottom = torch.zeros(*top.shape[:-2], 1, 4, dtype=top.dtype, device=top.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


class PanTilt:
    """Forward and inverse kinematics of a :class:`PanTiltConfig` rig."""

    def __init__(self, config: PanTiltConfig | None = None):
        self.config = config or PanTiltConfig()
        c = self.config
        self.base2world = np.eye(4)
        self.base2world[:3, :3] = rpy_to_matrix(*(math.radians(a) for a in c.base_rpy_deg))
        self.base2world[:3, 3] = c.base_xyz_m
        self.tilt_offset = np.asarray(c.tilt_offset_m, dtype=np.float64)
        self.lever_arm = np.asarray(c.lever_arm_m, dtype=np.float64)
        roll = math.radians(c.camera_roll_deg)
        mount = rpy_to_matrix(*(math.radians(a) for a in c.camera_mount_rpy_deg))
        # tilt frame -> camera axes: the mount's error, then OpenCV optical axes turned about the optical (z) axis by the roll
        self.body_to_camera = mount @ BODY_TO_OPTICAL @ rot_z(roll)
        self.limits = JointLimits.from_config(c)
        self.pan_limits_rad = self.limits.pan_rad
        self.tilt_limits_rad = self.limits.tilt_rad

    # ----------------------------------------------------------------------------- limits
    def clamp(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        """Clamp joint angles to the limits; NaN or Inf raise :class:`JointCommandError`."""
        return self.limits.clamp(pan_rad, tilt_rad)

    def within_limits(self, pan_rad: float, tilt_rad: float, tol_rad: float = 1e-9) -> bool:
        return self.limits.within(pan_rad, tilt_rad, tol_rad)

    # ---------------------------------------------------------------------------- forward
    def forward(self, pan_rad, tilt_rad):
        """Joint angles ``[...]`` -> cam2world ``[..., 4, 4]``.

        Torch in, torch out (differentiable, the base pose in the joints' dtype); numpy or float in,
        float64 numpy out.
        """
        if isinstance(pan_rad, Tensor) or isinstance(tilt_rad, Tensor):
            pan = torch.as_tensor(pan_rad)
            tilt = torch.as_tensor(tilt_rad, dtype=pan.dtype, device=pan.device)
            return self._forward_torch(pan, tilt)
        pan = torch.as_tensor(np.asarray(pan_rad, dtype=np.float64))
        tilt = torch.as_tensor(np.asarray(tilt_rad, dtype=np.float64))
        return self._forward_torch(pan, tilt).numpy()

    def _forward_torch(self, pan: Tensor, tilt: Tensor) -> Tensor:
        try:
            pan, tilt = torch.broadcast_tensors(pan, tilt)
        except RuntimeError:
            raise JointCommandError(
                f"PanTilt.forward: pan_rad {tuple(pan.shape)} and tilt_rad {tuple(tilt.shape)} do not broadcast; "
                "give one angle pair or arrays of one shape"
            ) from None
        for name, angle in (("pan_rad", pan), ("tilt_rad", tilt)):
            if not bool(torch.isfinite(angle).all()):
                raise JointCommandError(f"PanTilt.forward: {name} contains NaN or Inf; joint angles must be finite")
        kw = dict(dtype=pan.dtype, device=pan.device)
        return chain_forward(
            pan,
            tilt,
            torch.as_tensor(self.tilt_offset, **kw),
            torch.as_tensor(self.lever_arm, **kw),
            torch.as_tensor(self.body_to_camera, **kw),
            torch.as_tensor(self.base2world[:3, :3], **kw),
            torch.as_tensor(self.base2world[:3, 3], **kw),
        )

    # ---------------------------------------------------------------------------- inverse
    def _pick_pan(self, pan_rad: float, pan_hint_rad: float) -> float:
        """Of the equivalent angles ``pan + 2 k pi``, the one inside the limits nearest the hint."""
        lo, hi = self.pan_limits_rad
        candidates = [pan_rad + 2 * math.pi * k for k in (-1, 0, 1)]
        inside = [c for c in candidates if lo - 1e-12 <= c <= hi + 1e-12]
        pool = inside or candidates
        return min(pool, key=lambda c: abs(c - pan_hint_rad))

    def inverse_direction(self, direction_world: Sequence[float], pan_hint_rad: float = 0.0) -> JointSolution:
        """Joints that point the optical axis along ``direction_world [3]``.

        The lever arm translates the camera but does not turn it, so the orientation alone fixes
        the joints; use :meth:`inverse_look_at` to aim at a point, where the lever arm matters.
        Straight up or down (relative to the base) the pan is free: ``pan_hint_rad`` is kept.
        A camera mount error (``camera_mount_rpy_deg``) turns the optical axis off the tilt frame's
        x: a few fixed-point steps correct the joints for it.
        """
        d = np.asarray(direction_world, dtype=np.float64)
        return self._solution(*self.direction_joints(d, pan_hint_rad), d)

    def direction_joints(self, direction_world: Sequence[float], pan_hint_rad: float = 0.0) -> tuple[float, float]:
        """``(pan, tilt)`` in radians of :meth:`inverse_direction` before clamping, without the
        aim error it reports: that costs a forward pass per call, most of a search's trajectory
        sampling, which needs the joints only."""
        d = np.asarray(direction_world, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d):
            raise JointCommandError(f"direction must be 3 finite numbers, not all zero; got {d.tolist()}")
        d_base = self.base2world[:3, :3].T @ d
        pan, tilt = direction_to_yaw_pitch(d_base, float(pan_hint_rad))
        pan, tilt = float(pan), float(tilt)
        if any(self.config.camera_mount_rpy_deg):
            want_pan, want_tilt = pan, tilt
            for _ in range(8):  # the mount error is small: each step shrinks the residual by its order
                got = self.base2world[:3, :3].T @ self.forward(pan, tilt)[:3, 2]
                got_pan, got_tilt = direction_to_yaw_pitch(got, pan)
                step_pan = math.remainder(want_pan - float(got_pan), 2 * math.pi)
                pan, tilt = pan + step_pan, min(max(tilt + want_tilt - float(got_tilt), -math.pi / 2), math.pi / 2)
                if abs(step_pan) + abs(want_tilt - float(got_tilt)) < 1e-13:
                    break
        return self._pick_pan(pan, float(pan_hint_rad)), tilt

    def inverse_look_at(
        self, target_world: Sequence[float], pan_hint_rad: float = 0.0, iterations: int = 50, tol_rad: float = 1e-12
    ) -> JointSolution:
        """Joints whose optical axis passes through ``target_world [3]``, lever arm included.

        Fixed-point iteration: aim from the current camera centre at the target, move the joints,
        recompute the centre. It converges while the target is farther than the lever arm; a
        target inside the arm has no exact solution and gives the best aim with a non-zero error.
        """
        p = np.asarray(target_world, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise JointCommandError(f"target must be 3 finite numbers, got {p.tolist()}")
        pivot = self.base2world[:3, :3] @ self.tilt_offset + self.base2world[:3, 3]
        sol = self.inverse_direction(p - pivot if np.any(p - pivot) else np.array([1.0, 0, 0]), pan_hint_rad)
        pan, tilt = sol.pan_rad, sol.tilt_rad
        for _ in range(iterations):
            centre = self.forward(pan, tilt)[:3, 3]
            if not np.any(p - centre):
                break
            nxt = self.inverse_direction(p - centre, pan)
            converged = abs(nxt.pan_rad - pan) + abs(nxt.tilt_rad - tilt) < tol_rad
            pan, tilt = nxt.pan_rad, nxt.tilt_rad
            if converged:
                break
        c2w = self.forward(pan, tilt)
        aim = p - c2w[:3, 3]
        err = _angle_between(c2w[:3, 2], aim) if np.any(aim) else math.pi
        return JointSolution(pan, tilt, self.within_limits(pan, tilt) and err < 1e-6, err)

    def _solution(self, pan: float, tilt: float, desired_dir: np.ndarray) -> JointSolution:
        cpan, ctilt = self.clamp(pan, tilt)
        reachable = self.within_limits(pan, tilt)
        achieved = self.forward(cpan, ctilt)[:3, 2]
        return JointSolution(cpan, ctilt, reachable, _angle_between(achieved, desired_dir))

    def view_of(self, pan_rad: float, tilt_rad: float) -> np.ndarray:
        """5-DoF view ``[5]`` of the camera at these joints."""
        return cam2world_to_view(self.forward(pan_rad, tilt_rad))

    def sweep(self, n: int, margin: float = 0.1) -> np.ndarray:
        """``n`` joint pairs ``[n, 2]`` along a left-to-right sweep of the range.

        Pan steps evenly from one limit to the other (``margin`` of the range in from each);
        tilt zig-zags a quarter of the tilt range above and below its middle, so consecutive
        views overlap and the set covers both directions. ``n = 1`` is the centre.
        """
        if n < 1:
            raise ValueError(f"sweep needs n >= 1 views, got {n}")
        (plo, phi), (tlo, thi) = self.pan_limits_rad, self.tilt_limits_rad
        pm = (phi - plo) * margin
        pans = np.linspace(plo + pm, phi - pm, n) if n > 1 else np.array([(plo + phi) / 2])
        mid, quarter = (tlo + thi) / 2, (thi - tlo) / 4
        tilts = mid + quarter * np.where(np.arange(n) % 2 == 0, 1.0, -1.0) if n > 1 else np.array([mid])
        return np.stack([pans, tilts], axis=-1)

    def joint_grid(self, n_pan: int, n_tilt: int, margin: float = 0.1) -> np.ndarray:
        """Joint pairs ``[n_pan * n_tilt, 2]`` spread over the range, ``margin`` (fraction) in from each limit."""
        (plo, phi), (tlo, thi) = self.pan_limits_rad, self.tilt_limits_rad

        def span(lo, hi, n):
            if n == 1:
                return np.array([(lo + hi) / 2])
            m = (hi - lo) * margin
            return np.linspace(lo + m, hi - m, n)

        pans, tilts = np.meshgrid(span(plo, phi, n_pan), span(tlo, thi, n_tilt), indexing="xy")
        return np.stack([pans.ravel(), tilts.ravel()], axis=-1)


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    # atan2 of |a x b| and a.b is accurate at small and large angles alike
    return float(math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b))))
