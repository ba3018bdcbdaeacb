"""The pose step on renders with parallax (poses withheld) and on folders that are not photo sets."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from aes_planner.bench.photos import render_photo_set
from aes_planner.cli import main
from aes_planner.dataset import import_nerfstudio, load_dataset
from aes_planner.photos import PoseConfig, pose_errors, pose_images


@pytest.fixture(scope="module")
def posed(arc_set, tmp_path_factory):
    images, truth = arc_set
    out = tmp_path_factory.mktemp("posed") / "posed"
    return pose_images(images, out), truth


def _truth_of(result, truth):
    return truth[[int(name[4:8]) for name in result.registered]]


def test_every_photo_registers_as_one_camera(posed):
    result, truth = posed
    assert result.registered == [f"IMG_{i:04d}.jpg" for i in range(len(truth))]
    assert result.unregistered == [] and result.total == len(truth)
    assert result.cameras == 1  # one size, no EXIF: one shared camera
    assert 0 < result.mean_reprojection_px < 1.0


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # a second scene in `make bench`
def test_ten_640x480_photos_pose_within_1_deg_and_2_percent_after_a_similarity(seed, tmp_path):
    """The issue's figure, at the issue's size: ten 640 x 480 photos walking an arc. (At 320 x 240
    SIFT does not pin the shared focal length down -- 2-3 % off on some arcs -- and the largest
    rotation error after the centres' similarity reaches 1.6-2.7 deg: docs/guides/photos.md.)"""
    images, truth, _ = render_photo_set(tmp_path / "set", n=10, size=(640, 480), seed=seed, supersample=1)
    result = pose_images(images, tmp_path / "posed")
    assert result.registered == [f"IMG_{i:04d}.jpg" for i in range(len(truth))]
    errors = pose_errors(result.cam2world, _truth_of(result, truth))
    assert errors.rotation_deg.max() < 1.0, errors.rotation_deg
    assert errors.centre_frac.max() < 0.02, errors.centre_frac


def test_the_frame_is_levelled_and_starts_at_the_first_photo(posed):
    result, truth = posed
    errors = pose_errors(result.cam2world, _truth_of(result, truth))
    # the similarity onto the (z-up) truth is a turn about z: the recovered world's up is the true up
    up_error_deg = math.degrees(math.acos(np.clip(errors.rotation[2, 2], -1, 1)))
    assert up_error_deg < 3.0  # the hand's roll jitter (+-3 deg) is what is left
    np.testing.assert_allclose(result.cam2world[0][:3, 3], 0.0, atol=1e-9)
    forward = result.cam2world[0][:3, 2]
    assert abs(forward[1]) < 1e-9 and forward[0] > 0  # x along the first photo's levelled view


def test_without_a_scale_the_unit_is_stated_everywhere(posed):
    result, _ = posed
    assert not result.metric
    assert "IMG_0000.jpg" in result.unit and "IMG_0001.jpg" in result.unit
    d = np.linalg.norm(result.cam2world[0][:3, 3] - result.cam2world[1][:3, 3])
    assert d == pytest.approx(1.0)
    cameras = json.loads((result.out_dir / "cameras.json").read_text())
    assert cameras["meta"]["unit"] == result.unit and cameras["meta"]["metric"] is False
    transforms = json.loads((result.out_dir / "transforms.json").read_text())
    assert transforms["aes_planner"]["unit"] == result.unit


def test_cameras_json_and_transforms_json_hold_the_same_frames(posed):
    result, _ = posed
    ours = load_dataset(result.out_dir)
    theirs = import_nerfstudio(result.out_dir / "transforms.json", up="keep")
    assert len(ours) == len(theirs) == len(result.registered)
    for a, b, c2w in zip(ours.frames, theirs.frames, result.cam2world):
        np.testing.assert_allclose(a.cam2world, c2w, atol=1e-12)
        np.testing.assert_allclose(b.cam2world, c2w, atol=1e-12)
        assert a.intrinsics == b.intrinsics
        np.testing.assert_array_equal(a.image, b.image)
    doc = json.loads((result.out_dir / "transforms.json").read_text())
    # OpenGL axes in the file: the camera's y and z flipped against cameras.json
    gl = np.asarray(doc["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(gl[:3, 1], -result.cam2world[0][:3, 1], atol=1e-12)
    np.testing.assert_allclose(gl[:3, 2], -result.cam2world[0][:3, 2], atol=1e-12)


def test_the_posed_folder_carries_the_hand_held_platform(posed):
    from aes_planner.platform import HandHeldPlatform, platform_from_meta

    result, _ = posed
    data = load_dataset(result.out_dir)
    platform = platform_from_meta(data.meta, data.frames[0].intrinsics)
    assert isinstance(platform, HandHeldPlatform)
    assert platform.margin_m == pytest.approx(result.margin)
    assert bool(platform.contains(result.cam2world[:, :3, 3]).all())
    assert data.meta["photos"] == result.registered


def test_scale_from_two_photos_gives_metres(arc_set, tmp_path):
    images, truth = arc_set
    metres = float(np.linalg.norm(truth[0][:3, 3] - truth[5][:3, 3]))
    cfg = PoseConfig(scale_from=("IMG_0000.jpg", "IMG_0005.jpg", metres))
    result = pose_images(images, tmp_path / "metric", cfg)
    assert result.metric and result.unit == "m"
    errors = pose_errors(result.cam2world, truth)
    # already metric: no scale left to find beyond the two centres' own error (the check's 2 % of the spread;
    # 1.3 % on the 320 x 240 renders of the CC0 photographs)
    assert errors.scale == pytest.approx(1.0, rel=0.02)


def test_cli_pose_writes_the_folder_and_the_report(arc_set, tmp_path, capsys):
    images, _ = arc_set
    code = main(["pose", str(images), "--out", str(tmp_path / "out"), "--json", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert code == 0
    assert "posed 10 of 10 photos" in out and "mean reprojection error" in out and "unit:" in out
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["registered"] == 10 and report["total"] == 10 and report["metric"] is False
    assert (tmp_path / "out" / "cameras.json").is_file() and (tmp_path / "out" / "transforms.json").is_file()


# ---------------------------------------------------------------- garbage folders
def _refused(args, capsys) -> str:
    code = main(["pose", *map(str, args)])
    err = capsys.readouterr().err.split("\r")[-1].strip()  # what a terminal shows once the progress bar is cleared
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    return err


def test_an_empty_folder_is_refused(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    err = _refused([tmp_path / "empty", "--out", tmp_path / "o"], capsys)
    assert "no image files" in err


def test_text_files_named_jpg_are_refused(tmp_path, capsys):
    folder = tmp_path / "text"
    folder.mkdir()
    for i in range(4):
        (folder / f"IMG_{i}.jpg").write_text("not a photo\n")
    err = _refused([folder, "--out", tmp_path / "o"], capsys)
    assert "not an image" in err and "IMG_0.jpg" in err


def test_one_photo_is_refused(arc_set, tmp_path, capsys):
    images, _ = arc_set
    folder = tmp_path / "one"
    folder.mkdir()
    shutil.copy(images / "IMG_0000.jpg", folder)
    err = _refused([folder, "--out", tmp_path / "o"], capsys)
    assert "at least 3" in err


def test_copies_of_one_photo_are_refused(arc_set, tmp_path, capsys):
    images, _ = arc_set
    folder = tmp_path / "copies"
    folder.mkdir()
    for i in range(5):
        shutil.copy(images / "IMG_0002.jpg", folder / f"copy_{i}.jpg")
    err = _refused([folder, "--out", tmp_path / "o"], capsys)
    assert "copy_0.jpg" in err and "copy_1.jpg" in err and "same photo" in err
    assert not (tmp_path / "o" / "cameras.json").exists()


def test_views_from_one_spot_are_refused_with_the_rig_named(rotation_only_set, tmp_path, capsys):
    images, _ = rotation_only_set
    err = _refused([images, "--out", tmp_path / "o"], capsys)
    assert "parallax" in err and "kinematics" in err
    assert not (tmp_path / "o" / "cameras.json").exists()


def test_bad_scale_options_are_refused_before_any_work(arc_set, tmp_path, capsys):
    images, _ = arc_set
    err = _refused([images, "--out", tmp_path / "o", "--scale-from", "IMG_0000.jpg,IMG_0001.jpg"], capsys)
    assert "IMG_A,IMG_B,METRES" in err
    err = _refused([images, "--out", tmp_path / "o", "--scale-from", "IMG_0000.jpg,nope.jpg,1.0"], capsys)
    assert "nope.jpg" in err
    err = _refused([images, "--out", tmp_path / "o", "--board", "chessboard:9x6"], capsys)
    assert "board" in err


def test_to_true_maps_estimated_poses_onto_the_truth_through_the_similarity():
    """Poses made from the truth by a known similarity come back onto the truth exactly."""
    rng = np.random.default_rng(3)
    truth = np.tile(np.eye(4), (5, 1, 1))  # [5, 4, 4]
    truth[:, :3, 3] = rng.normal(size=(5, 3)) * 2.0
    for i, yaw in enumerate(rng.uniform(-math.pi, math.pi, 5)):
        c, s = math.cos(yaw), math.sin(yaw)
        truth[i, :3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    est = truth.copy()
    est[:, :3, 3] = 0.5 * truth[:, :3, 3] @ turn.T + [1.0, -2.0, 0.3]  # a frame 2x smaller, turned, moved
    est[:, :3, :3] = turn @ truth[:, :3, :3]
    errors = pose_errors(est, truth)
    assert errors.rotation_deg.max() < 1e-6 and errors.centre_frac.max() < 1e-9
    for e, t in zip(est, truth):
        np.testing.assert_allclose(errors.to_true(e), t, atol=1e-9)
