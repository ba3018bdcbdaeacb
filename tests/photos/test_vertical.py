"""Levelling from the scene's vertical vanishing direction: on drawn lines of known cameras, on
photos with no straight lines (the cameras' up kept, and said), and on renders whose cameras all
lean the same way (where the cameras' up is wrong by the lean)."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from aes_planner.bench.photos import render_photo_set
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import look_at
from aes_planner.photos import pose_errors, pose_images
from aes_planner.photos.sfm import gravity_up
from aes_planner.photos.simscene import arc_poses
from aes_planner.photos.vertical import vertical_from_lines

K = Intrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)


def _lean(poses: np.ndarray, roll_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """The same roll (about the optical axis) and pitch (about the camera's x) added to every camera:
    a camera held the same crooked way all along."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    roll = np.array([[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), -math.sin(p)], [0.0, math.sin(p), math.cos(p)]])
    out = np.array(poses, np.float64)
    out[:, :3, :3] = out[:, :3, :3] @ pitch @ roll
    return out


def _angle_deg(a, b) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b)))))


def _draw_posts(c2w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A grey photo with the images of vertical posts (world z) standing 2-5 m in front of the
    camera, and a few random non-vertical strokes."""
    img = np.full((K.height, K.width, 3), 128, np.uint8)
    w2c = np.linalg.inv(c2w)
    for _ in range(12):
        base = c2w[:3, 3] + c2w[:3, 2] * rng.uniform(2, 5) + c2w[:3, 0] * rng.uniform(-1.5, 1.5)
        ends = [base + [0, 0, z] for z in (-0.5, 0.5)]
        px = []
        for e in ends:
            p = w2c[:3, :3] @ e + w2c[:3, 3]
            px.append((K.fx * p[0] / p[2] + K.cx - 0.5, K.fy * p[1] / p[2] + K.cy - 0.5))
        cv2.line(img, *[(round(x * 16), round(y * 16)) for x, y in px], (20, 20, 20), 2, cv2.LINE_AA, 4)
    for _ in range(4):
        a, b = rng.uniform([0, 0], [K.width, K.height], (2, 2))
        cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (230, 230, 230), 2, cv2.LINE_AA)
    return img


def test_drawn_vertical_posts_give_up_where_the_cameras_lean():
    rng = np.random.default_rng(3)
    poses = _lean(arc_poses(6, seed=1), roll_deg=7.0, pitch_deg=-10.0)
    images = [_draw_posts(m, rng) for m in poses]
    prior = gravity_up(poses)
    assert _angle_deg(prior, [0, 0, 1]) > 5.0  # the cameras' up leans with them
    found = vertical_from_lines(images, [K] * len(images), poses, prior)
    assert found.confident, found.text()
    assert _angle_deg(found.up, [0, 0, 1]) < 0.5
    assert found.up[2] > 0  # signed by the cameras' up
    assert found.off_cameras_deg == pytest.approx(_angle_deg(found.up, prior), abs=1e-6)


def test_photos_without_straight_lines_keep_the_cameras_up():
    rng = np.random.default_rng(0)
    poses = np.stack([look_at([0.0, y, 1.5], [3.0, 0.0, 1.0]) for y in (-0.5, 0.0, 0.5, 1.0)])
    images = []
    for _ in poses:  # blurred noise: texture without straight edges
        noise = rng.integers(0, 256, (K.height, K.width, 3), dtype=np.uint8)
        images.append(cv2.GaussianBlur(noise, (0, 0), 3))
    prior = gravity_up(poses)
    found = vertical_from_lines(images, [K] * len(images), poses, prior)
    assert not found.confident
    assert np.all(np.isfinite(found.up))
    blank = [np.zeros((K.height, K.width, 3), np.uint8)] * len(poses)
    nothing = vertical_from_lines(blank, [K] * len(poses), poses, prior)
    assert not nothing.confident and nothing.segments == 0
    np.testing.assert_allclose(nothing.up, prior)
    assert json.dumps(nothing.to_json())  # no Inf in the report


@pytest.fixture(scope="module")
def leaning_set(tmp_path_factory):
    """Ten 320 x 240 views on the arc, every camera rolled 8 deg the same way."""
    root = tmp_path_factory.mktemp("leaning")
    poses = _lean(arc_poses(10, seed=0), roll_deg=8.0)
    images, truth, _ = render_photo_set(root, n=10, size=(320, 240), seed=0, supersample=1, poses=poses)
    return images, truth


def test_renders_with_every_camera_rolled_are_levelled_by_the_scene(leaning_set, tmp_path):
    images, truth = leaning_set
    result = pose_images(images, tmp_path / "posed")
    errors = pose_errors(result.cam2world, truth)
    up_error_deg = math.degrees(math.acos(np.clip(errors.rotation[2, 2], -1, 1)))
    assert up_error_deg < 1.5, result.gravity
    report = result.to_json()
    assert report["gravity_source"] == "vertical lines" and report["vertical_lines"]["confident"]
    assert report["vertical_lines"]["off_cameras_deg"] > 5.0  # the cameras' up would have been that far off
    meta = json.loads((result.out_dir / "cameras.json").read_text())["meta"]
    assert "vertical lines" in meta["gravity"] and "vertical lines" in meta["frame"]
