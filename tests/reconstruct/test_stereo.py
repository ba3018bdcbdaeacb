"""Plane-sweep stereo on analytically rendered textured planes (independent of the simulator)."""

import numpy as np
import pytest

from aes_planner.geometry import Intrinsics, look_at, view_to_cam2world
from aes_planner.messages import PosedFrame
from aes_planner.reconstruct import StereoConfig, expected_disparity_px, plane_sweep_depth


def texture(y, z):
    """A smooth random-looking pattern on the plane (values in [0, 1])."""
    t = (
        0.5
        + 0.18 * np.sin(7.1 * y + 2.3 * z)
        + 0.14 * np.sin(3.3 * z - 11.7 * y + 1.0)
        + 0.12 * np.sin(17.0 * z + 5.0 * y)
    )
    return np.clip(t, 0, 1)


def render_plane(c2w, k: Intrinsics, plane_x: float, slope: float = 0.0):
    """The plane x = plane_x + slope * y, textured by (y, z), seen from c2w; returns image and z-depth."""
    d_cam = k.pixel_directions()  # [H, W, 3]
    d = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    # o + t d on x - slope y = plane_x
    t = (plane_x - (o[0] - slope * o[1])) / (d[..., 0] - slope * d[..., 1])
    p = o + t[..., None] * d
    g = texture(p[..., 1], p[..., 2])
    img = (np.repeat(g[..., None], 3, -1) * 255).round().astype(np.uint8)
    return img, t.astype(np.float32)  # t is the z-depth because d_cam has z = 1


def frames_for(plane_x, slope=0.0, baseline=0.25, size=64):
    k = Intrinsics.from_fov(size, size, 60.0)
    frames = []
    for dy in (0.0, -baseline, baseline):
        c2w = view_to_cam2world(np.array([0.0, dy, 1.0, 0.0, 0.0]))
        img, depth = render_plane(c2w, k, plane_x, slope)
        frames.append((PosedFrame(img, k, c2w), depth))
    return frames


@pytest.mark.parametrize("plane_x", [1.5, 4.0])
def test_fronto_parallel_plane_depth(plane_x):
    (ref, gt), *nbs = frames_for(plane_x)
    res = plane_sweep_depth(ref, [f for f, _ in nbs], StereoConfig(num_planes=96, min_depth_m=0.5, max_depth_m=20))
    valid = res.depth_m > 0
    assert valid.mean() > 0.8
    rel = np.abs(res.depth_m[valid] - gt[valid]) / gt[valid]
    assert np.median(rel) < 0.02
    assert np.all(res.confidence[valid] > 0) and np.all(res.confidence[~valid] == 0)


def test_slanted_plane_depth_follows_the_slope():
    (ref, gt), *nbs = frames_for(3.0, slope=0.6)
    res = plane_sweep_depth(ref, [f for f, _ in nbs], StereoConfig(num_planes=96, min_depth_m=0.5, max_depth_m=20))
    valid = res.depth_m > 0
    assert valid.mean() > 0.7
    assert np.median(np.abs(res.depth_m[valid] - gt[valid]) / gt[valid]) < 0.03
    # left and right halves sit at clearly different depths, as the slope says
    assert np.median(res.depth_m[:, :20][valid[:, :20]]) > np.median(res.depth_m[:, -20:][valid[:, -20:]])


def test_textureless_and_unseen_pixels_have_no_depth():
    k = Intrinsics.from_fov(32, 32, 60.0)
    flat = np.full((32, 32, 3), 128, np.uint8)
    a = PosedFrame(flat, k, view_to_cam2world(np.array([0, 0, 1.0, 0, 0])))
    b = PosedFrame(flat, k, view_to_cam2world(np.array([0, 0.3, 1.0, 0, 0])))
    res = plane_sweep_depth(a, [b])
    assert np.all(res.depth_m == 0) and np.all(res.confidence == 0)
    assert np.all(plane_sweep_depth(a, []).depth_m == 0)
    # a neighbour looking the other way sees nothing of the reference view
    c = PosedFrame(flat, k, look_at(np.array([0, 0, 1.0]), np.array([-5.0, 0, 1.0])))
    assert np.all(plane_sweep_depth(a, [c]).depth_m == 0)


def test_expected_disparity_tells_rotation_from_translation():
    k = Intrinsics.from_fov(128, 128, 60.0)
    img = np.zeros((128, 128, 3), np.uint8)
    rot = [PosedFrame(img, k, view_to_cam2world(np.array([0, 0, 1.0, yaw, 0]))) for yaw in (0.0, 0.3, 0.6)]
    trans = [PosedFrame(img, k, view_to_cam2world(np.array([0, y, 1.0, 0, 0]))) for y in (0.0, 0.3)]
    assert expected_disparity_px(rot, 3.0) == 0.0
    assert expected_disparity_px(trans, 3.0) == pytest.approx(k.fx * 0.3 / 3.0)
    assert expected_disparity_px(rot[:1], 3.0) == 0.0
