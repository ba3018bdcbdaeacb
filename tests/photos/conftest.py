"""Photo sets rendered once per session: a photographer walking an arc around a textured scene
(parallax), poses withheld from the pose step and kept here as the truth."""

from __future__ import annotations

import numpy as np
import pytest

from aes_planner.bench.photos import render_photo_set
from aes_planner.geometry.poses import look_at
from aes_planner.photos.simscene import SUBJECT_M


@pytest.fixture(scope="session")
def arc_set(tmp_path_factory):
    """Ten 320 x 240 views on an 80 deg arc (hand jitter included): ``(images_dir, truth [10, 4, 4])``."""
    root = tmp_path_factory.mktemp("arc")
    images, truth, _ = render_photo_set(root, n=10, size=(320, 240), seed=0, supersample=1)
    return images, truth


@pytest.fixture(scope="session")
def rotation_only_set(tmp_path_factory):
    """Six 320 x 240 views from one spot, turning 50 deg (a pan-tilt rig's sweep): no parallax."""
    root = tmp_path_factory.mktemp("turn")
    eye = np.array([0.0, 0.0, 1.5])
    poses = []
    for yaw in np.radians(np.linspace(-25, 25, 6)):
        target = np.asarray(SUBJECT_M) + np.array([0.0, 3.0 * np.tan(yaw), 0.0])
        poses.append(look_at(eye, target))
    images, truth, _ = render_photo_set(root, n=6, size=(320, 240), seed=0, supersample=1, poses=np.stack(poses))
    return images, truth
