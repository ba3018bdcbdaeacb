"""Synthetic board images and rig observations for the calibration tests (no renderer)."""

from __future__ import annotations

import cv2
import numpy as np

from aes_planner.calibrate.board import BoardSpec, pattern
from aes_planner.calibrate.capture import CameraModel, plan_views
from aes_planner.calibrate.rig import RigObservations
from aes_planner.geometry.pantilt import PanTilt


def board_image(spec: BoardSpec, K: np.ndarray, rvec, tvec, size=(640, 480), px: int = 40) -> np.ndarray:
    """The board (one white square of margin) seen by a pinhole ``K`` (OpenCV convention) at
    board2camera ``rvec, tvec``, on a grey background: gray ``[H, W]`` uint8."""
    pat = pattern(spec, px, 1)
    s = spec.square_m
    a = np.array([[px / s, 0, 2 * px - 0.5], [0, px / s, 2 * px - 0.5], [0, 0, 1.0]])  # board (x, y) -> pattern pixel
    r = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    h = K @ np.column_stack([r[:, 0], r[:, 1], np.asarray(tvec, np.float64)])
    warp = h @ np.linalg.inv(a)
    blurred = cv2.GaussianBlur(pat, (0, 0), 0.6)
    return cv2.warpPerspective(blurred, warp, size, flags=cv2.INTER_LINEAR, borderValue=110)


def rig_observations(
    truth, nominal, spec, board2world, camera: CameraModel, n_views, pixel_sigma=0.0, joint_sigma_deg=0.0, seed=0
):
    """Corners the ``truth`` rig sees at the joints the ``nominal`` rig plans (as a real run would)."""
    rng = np.random.default_rng(seed)
    joints = plan_views(camera, nominal, spec, board2world, n_views)
    kin = PanTilt(truth)
    obj = spec.object_points()
    world = obj @ board2world[:3, :3].T + board2world[:3, 3]
    views, uvs = [], []
    for v, (p, t) in enumerate(joints):
        c2w = kin.forward(p, t)
        pc = (world - c2w[:3, 3]) @ c2w[:3, :3]
        uvs.append(camera.project(pc) + rng.normal(0, pixel_sigma, (len(obj), 2)))
        views.append(np.full(len(obj), v))
    noise = np.radians(rng.normal(0, joint_sigma_deg, joints.shape)) if joint_sigma_deg else 0.0
    reported = joints + noise
    return RigObservations(
        reported[:, 0],
        reported[:, 1],
        np.concatenate(views),
        np.tile(obj, (len(joints), 1)),
        np.concatenate(uvs),
        camera.K,
    )
