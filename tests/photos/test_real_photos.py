"""The coordinator's check, on our own renders: ten hand-held-like 640 x 480 views of a scene textured
with real photographs (the six CC0 ones the package ships, sim/assets/photos), poses withheld, a printed board in view. Slow
(a minute of rendering and structure from motion): run by `make bench`."""

from __future__ import annotations

import numpy as np
import pytest

from aes_planner.bench.photos import render_photo_set
from aes_planner.geometry.board import parse_board
from aes_planner.photos import PoseConfig, pose_errors, pose_images
from aes_planner.photos.simscene import cc0_photos

ASSETS = cc0_photos()
BOARD = "chessboard:9x6:0.06"


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_ten_photos_of_real_photographs_pose_within_the_targets_in_metres(tmp_path, seed):
    assert len(ASSETS) == 6
    images, truth, _ = render_photo_set(tmp_path / "set", 10, (640, 480), seed=seed, textures=ASSETS, board=BOARD)
    result = pose_images(images, tmp_path / "posed", PoseConfig(board=parse_board(BOARD)))
    assert len(result.registered) == 10
    assert result.metric and result.unit == "m"
    errors = pose_errors(result.cam2world, truth)
    assert errors.rotation_deg.max() < 1.0, errors.rotation_deg
    assert errors.centre_frac.max() < 0.02, errors.centre_frac
    assert errors.scale == pytest.approx(1.0, rel=0.02)  # the board's metres
    up_error_deg = np.degrees(np.arccos(np.clip(errors.rotation[2, 2], -1, 1)))
    assert up_error_deg < 3.0
