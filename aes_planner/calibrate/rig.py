"""The pan-tilt rig's kinematic parameters by least squares on the board's reprojection error.

Model (:mod:`aes_planner.geometry.pantilt`, the same chain every part of the package runs)::

    cam2world(pan, tilt) = base @ Rz(pan) @ T(tilt_offset) @ Ry(-tilt) @ T(lever_arm) @ R(mount) @ optical @ Rz(roll)
    pixel = K * world2cam(pan, tilt) * board2world * corner

Every view sees one board that does not move; its pose (6 numbers) is a nuisance estimated with
the rig. The joint angles are those the gimbal reports. What one board seen by a turning camera
can and cannot tell (each fixed as said, and listed in the report):

* ``tilt_offset_m[2]`` (the tilt axis' height above the pan origin) moves every view alike, as
  moving the board would: held at the drawing's value.
* ``tilt_offset_m[1]`` and ``lever_arm_m[1]`` both lie along the tilt axis: only their sum shows;
  ``tilt_offset_m[1]`` is held at the drawing's value and the sum is carried by ``lever_arm_m[1]``.
* The pan joint's zero turns the whole rig about the pan axis, as turning the board would:
  unobservable without a reference in the world; held at 0 (set the base's yaw for it).
* The tilt joint's zero is exactly a rotation of the camera mount and the lever arm about the tilt
  axis: it is carried by ``camera_mount_rpy_deg[1]`` and the lever arm (the forward kinematics are
  the same); :func:`rezero_tilt` moves it into the driver's ``tilt_zero_offset_ticks`` instead,
  defining tilt 0 as "optical axis level with the pan plane".

Free: ``tilt_offset_m[0]``, ``lever_arm_m`` (3), ``camera_mount_rpy_deg`` (3), and the board's
pose. Levenberg-Marquardt in float64 with the Jacobian by forward-mode autodiff (``torch.func``)
through :func:`~aes_planner.geometry.pantilt.chain_forward`; standard deviations from
``sigma^2 (J^T J)^-1`` at the solution, with ``sigma`` the residual's RMS.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.pantilt import PanTilt, chain_forward, rpy_matrix_torch
from aes_planner.geometry.poses import BODY_TO_OPTICAL
from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.geometry.rotations import matrix_to_rpy, rot_y

log = logging.getLogger(__name__)

__all__ = [
    "FREE_PARAMETERS",
    "RigCalibrationError",
    "RigObservations",
    "RigSolution",
    "UNOBSERVABLE",
    "fit_board_pose",
    "reprojection_rms",
    "rezero_tilt",
    "solve_rig",
]

TICKS_PER_RAD = 4096 / (2 * math.pi)

#: The estimated kinematic parameters, in the order of the solution vector (units: m, deg at the edge).
FREE_PARAMETERS = (
    "tilt_offset_m[0]",
    "lever_arm_m[0]",
    "lever_arm_m[1]",
    "lever_arm_m[2]",
    "camera_mount_rpy_deg[0]",
    "camera_mount_rpy_deg[1]",
    "camera_mount_rpy_deg[2]",
)
_N_KIN = len(FREE_PARAMETERS)

#: What the data cannot separate and how it is fixed (copied into every report).
UNOBSERVABLE = [
    {
        "combination": "tilt_offset_m[2] with the board's position along the pan axis",
        "fixed": "tilt_offset_m[2] held at the nominal rig's value",
    },
    {
        "combination": "tilt_offset_m[1] + lever_arm_m[1] (both along the tilt axis; only the sum shows)",
        "fixed": "tilt_offset_m[1] held at the nominal value; the sum is carried by lever_arm_m[1]",
    },
    {
        "combination": "pan zero offset with the board's bearing about the pan axis (the base's yaw)",
        "fixed": "pan zero offset 0 (driver's pan_zero_offset_ticks unchanged); set base_rpy_deg[2] from a world reference",
    },
    {
        "combination": "tilt zero offset with camera_mount_rpy_deg[1] and the lever arm turned about the tilt axis",
        "fixed": "carried by camera_mount_rpy_deg[1] and lever_arm_m (same kinematics); --zero-offsets joints moves it "
        "into the driver's tilt_zero_offset_ticks (tilt 0 = optical axis level with the pan plane)",
    },
]


class RigCalibrationError(AesPlannerError, ValueError):
    """Rig-calibration data that cannot determine the rig (too few views, no spread...)."""


@dataclass
class RigObservations:
    """Board corners seen from joint poses.

    * ``pan_rad``, ``tilt_rad``: ``[V]`` joint angles (as the gimbal reports them) of each view.
    * ``view``: ``[M]`` view index of each observed corner; ``object_points``: ``[M, 3]`` the corner
      on the board (metres, board frame); ``image_points``: ``[M, 2]`` where it was seen, OpenCV
      pixels (centres at integers), **undistorted**.
    * ``K``: ``[3, 3]`` the camera matrix in OpenCV's pixel convention.
    """

    pan_rad: np.ndarray
    tilt_rad: np.ndarray
    view: np.ndarray
    object_points: np.ndarray
    image_points: np.ndarray
    K: np.ndarray

    @property
    def n_views(self) -> int:
        return len(self.pan_rad)

    def subset(self, keep: np.ndarray) -> RigObservations:
        """Only the views ``keep`` (indices), renumbered."""
        keep = np.asarray(keep, dtype=np.int64)
        new_index = -np.ones(self.n_views, np.int64)
        new_index[keep] = np.arange(len(keep))
        sel = np.isin(self.view, keep)
        return RigObservations(
            self.pan_rad[keep],
            self.tilt_rad[keep],
            new_index[self.view[sel]],
            self.object_points[sel],
            self.image_points[sel],
            self.K,
        )


@dataclass
class RigSolution:
    """The calibrated rig and how well it fits."""

    config: PanTiltConfig
    board2world: np.ndarray  # [4, 4]
    std: dict[str, float]  # per FREE_PARAMETERS entry, in mm or deg
    rms_before_px: float
    rms_after_px: float
    per_view_rms_px: list[float]
    iterations: int
    dropped_views: list[int] = field(default_factory=list)


# ------------------------------------------------------------------------------- model
def _rodrigues(w: Tensor) -> Tensor:  # [3] -> [3, 3], safe at 0
    theta2 = (w * w).sum()
    small = theta2 < 1e-12
    t2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(t2)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / t2)
    zero = torch.zeros_like(w[0])
    k = torch.stack([zero, -w[2], w[1], w[2], zero, -w[0], -w[1], w[0], zero]).reshape(3, 3)
    return torch.eye(3, dtype=w.dtype) + a * k + b * (k @ k)


class _Problem:
    """Residuals of the observations as a function of the parameter vector
    ``x = [kinematic (7: m, rad), board rotation increment (3), board translation (3)]``."""

    def __init__(self, obs: RigObservations, nominal: PanTiltConfig, board_r0: np.ndarray):
        kw = dict(dtype=torch.float64)
        self.obs = obs
        self.nominal = nominal
        kin = PanTilt(nominal)
        self.base_r = torch.as_tensor(kin.base2world[:3, :3], **kw)
        self.base_t = torch.as_tensor(kin.base2world[:3, 3], **kw)
        roll = math.radians(nominal.camera_roll_deg)
        c, s = math.cos(roll), math.sin(roll)
        self.optical = torch.as_tensor(BODY_TO_OPTICAL @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), **kw)
        self.offset_yz = torch.as_tensor(nominal.tilt_offset_m[1:], **kw)
        self.pan = torch.as_tensor(obs.pan_rad, **kw)
        self.tilt = torch.as_tensor(obs.tilt_rad, **kw)
        self.view = torch.as_tensor(obs.view)
        self.points = torch.as_tensor(obs.object_points, **kw)
        self.uv = torch.as_tensor(obs.image_points, **kw)
        self.K = torch.as_tensor(obs.K, **kw)
        self.board_r0 = torch.as_tensor(board_r0, **kw)

    def x_from(self, config: PanTiltConfig, board2world: np.ndarray) -> Tensor:
        kin = [config.tilt_offset_m[0], *config.lever_arm_m, *(math.radians(a) for a in config.camera_mount_rpy_deg)]
        r_delta = self.board_r0.numpy().T @ board2world[:3, :3]
        w = _log_rotation(r_delta)
        return torch.as_tensor([*kin, *w, *board2world[:3, 3]], dtype=torch.float64)

    def cam2world(self, x: Tensor, pan: Tensor, tilt: Tensor) -> Tensor:  # -> [V, 4, 4]
        offset = torch.cat([x[0:1], self.offset_yz])
        body_to_camera = rpy_matrix_torch(x[4:7]) @ self.optical
        return chain_forward(pan, tilt, offset, x[1:4], body_to_camera, self.base_r, self.base_t)

    def board2world(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self.board_r0 @ _rodrigues(x[7:10]), x[10:13]

    def residuals(self, x: Tensor) -> Tensor:  # [13] -> [2 M]
        c2w = self.cam2world(x, self.pan, self.tilt)
        r_b, t_b = self.board2world(x)
        world = self.points @ r_b.T + t_b  # [M, 3]
        r = c2w[self.view, :3, :3]  # [M, 3, 3]
        c = c2w[self.view, :3, 3]
        pc = ((world - c).unsqueeze(-2) @ r).squeeze(-2)  # R^T (p - c): [M, 3]
        z = pc[:, 2].clamp_min(1e-6)
        u = self.K[0, 0] * pc[:, 0] / z + self.K[0, 2]
        v = self.K[1, 1] * pc[:, 1] / z + self.K[1, 2]
        return (torch.stack([u, v], -1) - self.uv).reshape(-1)

    def config_from(self, x: Tensor) -> PanTiltConfig:
        v = x.detach().numpy()
        return replace(
            self.nominal,
            tilt_offset_m=(float(v[0]), *self.nominal.tilt_offset_m[1:]),
            lever_arm_m=(float(v[1]), float(v[2]), float(v[3])),
            camera_mount_rpy_deg=tuple(float(math.degrees(a)) for a in v[4:7]),
        )


def _log_rotation(r: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(r, dtype=np.float64))[0].reshape(3)


def _levenberg_marquardt(fun, x: Tensor, free: np.ndarray, max_iter: int = 60) -> tuple[Tensor, Tensor, int]:
    """Minimise ``|fun(x)|^2`` over the entries ``free`` of ``x``; returns ``x``, the Jacobian of the
    free entries at the solution ``[2M, F]`` and the iterations run."""
    from torch.func import jacfwd

    idx = torch.as_tensor(np.flatnonzero(free))

    def sub(y: Tensor) -> Tensor:
        full = x.clone()
        full[idx] = y
        return fun(full)

    y = x[idx].clone()
    r = sub(y)
    cost = float(r @ r)
    lam = 1e-3
    it = 0
    jac = jacfwd(sub)(y)
    for it in range(1, max_iter + 1):  # noqa: B007 (reported)
        a = jac.T @ jac
        g = jac.T @ r
        diag = torch.diag(torch.diag(a).clamp_min(1e-12))
        improved = False
        for _ in range(12):
            step = torch.linalg.solve(a + lam * diag, -g)
            r_new = sub(y + step)
            cost_new = float(r_new @ r_new)
            if math.isfinite(cost_new) and cost_new < cost:
                y, r = y + step, r_new
                converged = cost - cost_new < 1e-12 * max(cost, 1e-30) or float(step.abs().max()) < 1e-12
                cost = cost_new
                lam = max(lam / 3, 1e-12)
                improved = True
                break
            lam *= 5
        jac = jacfwd(sub)(y)
        if not improved or converged:
            break
    out = x.clone()
    out[idx] = y
    return out, jac, it


def _rms(r: Tensor) -> float:
    return float(torch.sqrt((r.reshape(-1, 2) ** 2).sum(-1).mean()))


def _per_view_rms(problem: _Problem, x: Tensor, n_views: int) -> np.ndarray:
    r = problem.residuals(x).reshape(-1, 2).detach().numpy()
    sq = (r**2).sum(-1)
    view = problem.obs.view
    return np.sqrt(np.bincount(view, sq, minlength=n_views) / np.maximum(np.bincount(view, minlength=n_views), 1))


def _initial_board_pose(obs: RigObservations, nominal: PanTiltConfig, board_in_camera: list[np.ndarray]) -> np.ndarray:
    """board2world ``[4, 4]``: the per-view PnP poses through the nominal kinematics, averaged."""
    kin = PanTilt(nominal)
    poses = [kin.forward(p, t) @ b2c for p, t, b2c in zip(obs.pan_rad, obs.tilt_rad, board_in_camera)]
    rotations = np.stack([p[:3, :3] for p in poses])
    u, _, vt = np.linalg.svd(rotations.sum(0))
    r = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt  # chordal mean
    out = np.eye(4)
    out[:3, :3] = r
    out[:3, 3] = np.mean([p[:3, 3] for p in poses], axis=0)
    return out


def solve_pnp(obs: RigObservations) -> list[np.ndarray]:
    """board2camera ``[4, 4]`` of each view (OpenCV's iterative PnP on the undistorted corners)."""
    import cv2

    out = []
    for v in range(obs.n_views):
        sel = obs.view == v
        ok, rvec, tvec = cv2.solvePnP(obs.object_points[sel], obs.image_points[sel], obs.K, None)
        if not ok:
            raise RigCalibrationError(f"view {v}: PnP failed on its corners; drop the view or retake it")
        t = np.eye(4)
        t[:3, :3] = cv2.Rodrigues(rvec)[0]
        t[:3, 3] = tvec.reshape(3)
        out.append(t)
    return out


def check_spread(obs: RigObservations, min_views: int = 8, min_span_deg: float = 8.0) -> None:
    """Refuse data that cannot determine the rig, saying what to capture instead."""
    if obs.n_views < min_views:
        raise RigCalibrationError(
            f"only {obs.n_views} views saw the whole board; the rig needs at least {min_views} (30 or more is "
            "better): move the board nearer or into the middle of the joint range, or use a larger board"
        )
    for name, angles in (("pan", obs.pan_rad), ("tilt", obs.tilt_rad)):
        span = math.degrees(float(np.ptp(angles)))
        if span < min_span_deg:
            raise RigCalibrationError(
                f"every view is at one {name} angle (the views span {span:.1f} deg of {name}); the lever arm and "
                f"the mount need views spread over at least {min_span_deg:g} deg of {name}: put the board farther "
                "away or use a smaller one so it stays in view while the joints turn"
            )


def fit_board_pose(obs: RigObservations, config: PanTiltConfig) -> tuple[np.ndarray, float, np.ndarray]:
    """The board's pose with the rig held at ``config``: ``(board2world [4, 4], rms_px, per-view rms [V])``."""
    b2c = solve_pnp(obs)
    b2w = _initial_board_pose(obs, config, b2c)
    problem = _Problem(obs, config, b2w[:3, :3])
    x0 = problem.x_from(config, b2w)
    free = np.zeros(13, bool)
    free[_N_KIN:] = True
    x, _, _ = _levenberg_marquardt(problem.residuals, x0, free)
    r_b, t_b = problem.board2world(x)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r_b.detach().numpy(), t_b.detach().numpy()
    return out, _rms(problem.residuals(x).detach()), _per_view_rms(problem, x, obs.n_views)


def reprojection_rms(obs: RigObservations, config: PanTiltConfig, board2world: np.ndarray) -> tuple[float, np.ndarray]:
    """RMS reprojection error (px) of ``obs`` with the rig and the board's pose both held fixed,
    overall and per view ``[V]``."""
    problem = _Problem(obs, config, board2world[:3, :3])
    x = problem.x_from(config, board2world)
    return _rms(problem.residuals(x).detach()), _per_view_rms(problem, x, obs.n_views)


def solve_rig(obs: RigObservations, nominal: PanTiltConfig, outlier_factor: float = 5.0) -> RigSolution:
    """Calibrate the rig from ``obs``, starting at ``nominal`` (see the module docstring)."""
    check_spread(obs)
    board2world, rms_before, _ = fit_board_pose(obs, nominal)
    dropped: list[int] = []
    keep = np.arange(obs.n_views)
    for _ in range(3):
        sub = obs.subset(keep)
        problem = _Problem(sub, nominal, board2world[:3, :3])
        x0 = problem.x_from(nominal, board2world)
        x, jac, iterations = _levenberg_marquardt(problem.residuals, x0, np.ones(13, bool))
        per_view = _per_view_rms(problem, x, sub.n_views)
        bad = per_view > outlier_factor * max(float(np.median(per_view)), 0.05)
        if not bad.any():
            break
        dropped += [int(v) for v in keep[bad]]
        log.info("dropping %d views whose reprojection error is over %g x the median", int(bad.sum()), outlier_factor)
        keep = keep[~bad]
        check_spread(obs.subset(keep))
    r = problem.residuals(x).detach()
    if not (bool(torch.isfinite(x).all()) and bool(torch.isfinite(r).all())):
        raise RigCalibrationError(
            "the least squares diverged (non-finite parameters); check that --rig is the rig's drawing (lengths in "
            "metres, angles in degrees) and that the board spec matches the board"
        )
    dof = max(r.numel() - x.numel(), 1)
    sigma2 = float(r @ r) / dof
    try:
        cov = torch.linalg.inv(jac.T @ jac) * sigma2
        std = torch.sqrt(torch.diag(cov).clamp_min(0)).numpy()
    except RuntimeError:  # singular: the data cannot tell some parameter at all
        std = np.full(13, math.inf)
    scale = [1000.0] * 4 + [math.degrees(1.0)] * 3  # m -> mm, rad -> deg
    std_named = {name: float(s * k) for name, s, k in zip(FREE_PARAMETERS, std[:_N_KIN], scale)}
    r_b, t_b = problem.board2world(x)
    b2w = np.eye(4)
    b2w[:3, :3], b2w[:3, 3] = r_b.detach().numpy(), t_b.detach().numpy()
    return RigSolution(
        config=problem.config_from(x),
        board2world=b2w,
        std=std_named,
        rms_before_px=rms_before,
        rms_after_px=_rms(r),
        per_view_rms_px=[float(v) for v in per_view],
        iterations=iterations,
        dropped_views=dropped,
    )


def tilt_level_offset_rad(config: PanTiltConfig) -> float:
    """Elevation of the optical axis above the pan plane at tilt 0 (radians, positive up)."""
    axis = PanTilt(replace(config, base_rpy_deg=(0.0, 0.0, 0.0)))
    forward = axis.forward(0.0, 0.0)[:3, 2]
    return math.atan2(forward[2], math.hypot(forward[0], forward[1]))


def rezero_tilt(config: PanTiltConfig, tilt_direction: int = 1) -> tuple[PanTiltConfig, int]:
    """Move the camera's pitch at tilt 0 into the tilt joint's zero: the equivalent rig for a driver
    whose ``tilt_zero_offset_ticks`` change by the returned ticks (whole ticks; the rest stays in the
    mount). New angle = old angle + e: ``Ry(-(t_new - e)) T(L) R = Ry(-t_new) T(Ry(e) L) Ry(e) R``."""
    e = tilt_level_offset_rad(config)
    ticks = -tilt_direction * round(e * TICKS_PER_RAD)
    e_whole = -tilt_direction * ticks / TICKS_PER_RAD
    ry = rot_y(e_whole)
    lever = ry @ np.asarray(config.lever_arm_m)
    mount = (
        ry
        @ PanTilt(config).body_to_camera
        @ np.linalg.inv(PanTilt(replace(config, camera_mount_rpy_deg=(0, 0, 0))).body_to_camera)
    )
    rpy = tuple(math.degrees(a) for a in matrix_to_rpy(mount))
    return replace(config, lever_arm_m=tuple(float(v) for v in lever), camera_mount_rpy_deg=rpy), ticks


def compare_kinematics(estimate: PanTiltConfig, truth: PanTiltConfig, n: int = 15) -> dict:
    """Forward kinematics of ``estimate`` against ``truth`` over an ``n x n`` grid of the truth's
    joint range, after the rigid motion that best aligns them (the base pose is a free gauge):
    rotation the chordal mean of ``R_true R_est^T``, then the mean translation. Position and angle
    errors' RMS and max, in mm and degrees."""
    kin_t, kin_e = PanTilt(truth), PanTilt(estimate)
    joints = kin_t.joint_grid(n, n, margin=0.0)
    t = kin_t.forward(joints[:, 0], joints[:, 1])
    e = kin_e.forward(joints[:, 0], joints[:, 1])
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", t[:, :3, :3], e[:, :3, :3]))
    r = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    shift = (t[:, :3, 3] - e[:, :3, 3] @ r.T).mean(0)
    pos = np.linalg.norm(e[:, :3, 3] @ r.T + shift - t[:, :3, 3], axis=1) * 1000
    rel = np.einsum("nji,jk,nkl->nil", t[:, :3, :3], r, e[:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return {
        "position_rms_mm": float(np.sqrt((pos**2).mean())),
        "position_max_mm": float(pos.max()),
        "angle_rms_deg": float(np.sqrt((ang**2).mean())),
        "angle_max_deg": float(ang.max()),
    }


def seen_joints(
    config: PanTiltConfig,
    board2world: np.ndarray,
    K: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    start: tuple[float, float],
) -> tuple[float, float, float]:
    """The joint angles ``(pan, tilt)`` at which the rig ``config`` sees the board (at
    ``board2world``) where it was seen (``image_points [N, 2]``, OpenCV pixels, undistorted), and the
    RMS left in pixels: Gauss-Newton on the reprojection error from ``start``. Better conditioned
    than a single view's PnP orientation (the board's image shift fixes the joints directly)."""
    from torch.func import jacfwd

    kin = PanTilt(config)
    kw = dict(dtype=torch.float64)
    world = torch.as_tensor(object_points @ board2world[:3, :3].T + board2world[:3, 3], **kw)
    uv = torch.as_tensor(image_points, **kw)
    k = torch.as_tensor(K, **kw)

    def residual(q: Tensor) -> Tensor:
        c2w = kin.forward(q[0], q[1])
        pc = (world - c2w[:3, 3]) @ c2w[:3, :3]
        z = pc[:, 2].clamp_min(1e-6)
        proj = torch.stack([k[0, 0] * pc[:, 0] / z + k[0, 2], k[1, 1] * pc[:, 1] / z + k[1, 2]], -1)
        return (proj - uv).reshape(-1)

    q = torch.as_tensor(start, **kw)
    jac = jacfwd(residual)
    for _ in range(10):
        r = residual(q)
        step = torch.linalg.lstsq(jac(q), -r.unsqueeze(-1)).solution.squeeze(-1)
        q = q + step
        if float(step.abs().max()) < 1e-7:  # 1e-7 rad: far below a pixel
            break
    return float(q[0]), float(q[1]), _rms(residual(q).detach())
