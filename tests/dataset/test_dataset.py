"""Dataset folder round trips, importers (nerfstudio, RealEstate10K) and malformed files."""

import json
import math

import cv2
import numpy as np
import pytest

from aes_planner.dataset import (
    DatasetError,
    align_up_to_cameras,
    import_nerfstudio,
    import_re10k,
    load_dataset,
    save_dataset,
)
from aes_planner.dataset.importers import OPENGL_TO_OPENCV
from aes_planner.geometry import Intrinsics, view_to_cam2world, world2cam
from aes_planner.messages import PosedFrame


def make_frames(n=3, w=16, h=12, depth=True, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        view = np.array([rng.uniform(-1e5, 1e5), rng.uniform(-5, 5), 1.5, rng.uniform(-3, 3), rng.uniform(-1.5, 1.5)])
        frames.append(
            PosedFrame(
                image=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
                intrinsics=Intrinsics(20.0 + i, 21.5, w / 2 + 0.25, h / 2 - 0.5, w, h),
                cam2world=view_to_cam2world(view),
                stamp_s=0.1 * i + 1e9,
                depth_m=rng.uniform(0, 10, (h, w)).astype(np.float32) if depth else None,
                frame_id=f"f{i}",
            )
        )
    return frames


def test_round_trip_is_exact(tmp_path):
    frames = make_frames()
    save_dataset(
        tmp_path / "ds",
        frames,
        meta={"scene": "indoor:3"},
        frame_meta=[{"joints_rad": [0.1 * i, 0.0]} for i in range(3)],
    )
    ds = load_dataset(tmp_path / "ds")
    assert len(ds) == 3 and ds.meta == {"scene": "indoor:3"}
    for a, b in zip(frames, ds.frames):
        np.testing.assert_array_equal(a.cam2world, b.cam2world)  # float64 survives JSON exactly
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
        assert a.intrinsics == b.intrinsics and a.stamp_s == b.stamp_s and a.frame_id == b.frame_id
    assert ds.frames[2].extras["meta"] == {"joints_rad": [0.2, 0.0]}
    # loading the cameras.json path works too, and depth can be skipped
    assert load_dataset(tmp_path / "ds" / "cameras.json", load_depth=False).frames[0].depth_m is None


def write_doc(root, mutate):
    save_dataset(root, make_frames(2))
    doc = json.loads((root / "cameras.json").read_text())
    mutate(doc)
    (root / "cameras.json").write_text(json.dumps(doc))


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d["frames"][1]["cam2world"][2].pop(), r"frames\[1\].cam2world: expected a 4x4"),
        (
            lambda d: d["frames"][1]["cam2world"][0].__setitem__(0, 3.0),
            r"frames\[1\].cam2world: rotation is not orthonormal",
        ),
        (lambda d: d["frames"][0]["cam2world"][1].__setitem__(3, float("nan")), r"frames\[0\].cam2world: contains NaN"),
        (lambda d: d["frames"][0].__setitem__("fx", float("nan")), r"frames\[0\].fx: expected a finite number"),
        (lambda d: d["frames"][0].__setitem__("fx", -3.0), r"frames\[0\].*focal lengths must be positive"),
        (
            lambda d: d["frames"][1].__setitem__("image", "images/missing.png"),
            r"frames\[1\].image: image file .*missing.png not found",
        ),
        (lambda d: d["frames"][1].__setitem__("width", 99), r"frames\[1\]: width/height say 99x12"),
        (lambda d: d["frames"][0].pop("cam2world"), r"frames\[0\].cam2world: missing"),
        (lambda d: d.__setitem__("format", "other"), r"'format' must be"),
        (lambda d: d.__setitem__("version", 7), r"version 7 is not supported"),
    ],
)
def test_malformed_files_name_the_field(tmp_path, mutate, match):
    write_doc(tmp_path, mutate)
    with pytest.raises(DatasetError, match=match):
        load_dataset(tmp_path)


def test_bad_depth_files(tmp_path):
    save_dataset(tmp_path, make_frames(1))
    np.save(tmp_path / "depth" / "00000.npy", np.full((12, 16), np.nan, np.float32))
    with pytest.raises(DatasetError, match=r"frames\[0\].depth: depth contains NaN"):
        load_dataset(tmp_path)
    np.save(tmp_path / "depth" / "00000.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DatasetError, match="plain numeric .npy"):
        load_dataset(tmp_path)  # object arrays are never unpickled
    np.save(tmp_path / "depth" / "00000.npy", np.ones((3, 3), np.float32))
    with pytest.raises(DatasetError, match=r"frames\[0\].*depth_m must be \[12, 16\]"):
        load_dataset(tmp_path)


def test_missing_and_invalid_json(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        load_dataset(tmp_path)
    (tmp_path / "cameras.json").write_text("{not json")
    with pytest.raises(DatasetError, match="not valid JSON"):
        load_dataset(tmp_path)


def write_image(path, w=16, h=12, value=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((h, w, 3), value, np.uint8))


def test_nerfstudio_opengl_axes_become_opencv(tmp_path):
    frames = make_frames(2, depth=False)
    doc = {"fl_x": 20.0, "fl_y": 21.5, "cx": 8.25, "cy": 5.5, "w": 16, "h": 12, "frames": []}
    for i, f in enumerate(frames):
        write_image(tmp_path / "images" / f"frame_{i:05d}.png")
        doc["frames"].append(
            {"file_path": f"images/frame_{i:05d}.png", "transform_matrix": (f.cam2world @ OPENGL_TO_OPENCV).tolist()}
        )
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    ds = import_nerfstudio(tmp_path / "transforms.json")
    for a, b in zip(frames, ds.frames):
        np.testing.assert_allclose(b.cam2world, a.cam2world, atol=1e-9)
        assert b.intrinsics == Intrinsics(20.0, 21.5, 8.25, 5.5, 16, 12)
    # The OpenGL camera looks along its -z: the imported optical axis (+z) is that direction.
    gl = np.asarray(doc["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(ds.frames[0].cam2world[:3, 2], -gl[:3, 2], atol=1e-12)


def test_nerfstudio_camera_angle_and_errors(tmp_path, caplog):
    caplog.set_level("INFO")
    write_image(tmp_path / "a.png")
    pose = np.eye(4).tolist()
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {"camera_angle_x": math.pi / 2, "k1": 0.1, "frames": [{"file_path": "a.png", "transform_matrix": pose}]}
        )
    )
    ds = import_nerfstudio(tmp_path)
    assert ds.frames[0].intrinsics.fx == pytest.approx(8.0)
    assert "undistorted (OPENCV k1=0.1)" in caplog.text
    (tmp_path / "transforms.json").write_text(
        json.dumps({"frames": [{"file_path": "a.png", "transform_matrix": pose}]})
    )
    with pytest.raises(DatasetError, match=r"frames\[0\]: no focal length"):
        import_nerfstudio(tmp_path)
    (tmp_path / "transforms.json").write_text(
        json.dumps(
            {"fl_x": 5, "frames": [{"file_path": "a.png", "transform_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]}
        )
    )
    with pytest.raises(DatasetError, match=r"frames\[0\].transform_matrix: expected a 4x4"):
        import_nerfstudio(tmp_path)


def re10k_line(stamp, k: Intrinsics, c2w):
    w2c = world2cam(c2w)[:3].reshape(-1)
    nums = [*k.to_normalized(), 0.0, 0.0, *w2c]
    return f"{stamp} " + " ".join(repr(float(v)) for v in nums)


def test_re10k_import(tmp_path):
    frames = make_frames(3, depth=False)
    lines = ["https://www.youtube.com/watch?v=xxxxxxxxxxx"]
    for i, f in enumerate(frames):
        stamp = 1000000 * (i + 1)
        write_image(tmp_path / "frames" / f"{stamp}.png")
        lines.append(re10k_line(stamp, f.intrinsics, f.cam2world))
    (tmp_path / "clip.txt").write_text("\n".join(lines) + "\n")
    ds = import_re10k(tmp_path / "clip.txt", tmp_path / "frames", up="keep")
    for a, b in zip(frames, ds.frames):
        np.testing.assert_allclose(b.cam2world, a.cam2world, rtol=1e-12, atol=1e-9 * 1e5)
        np.testing.assert_allclose(b.intrinsics.K, a.intrinsics.K, atol=1e-12)
    assert [f.stamp_s for f in ds.frames] == [1.0, 2.0, 3.0]
    assert len(import_re10k(tmp_path / "clip.txt", tmp_path / "frames", up="keep", every=2)) == 2

    bad = lines[:2] + [" ".join(lines[2].split()[:-1])]
    (tmp_path / "bad.txt").write_text("\n".join(bad))
    with pytest.raises(DatasetError, match=r"bad.txt:3: expected 19 numbers"):
        import_re10k(tmp_path / "bad.txt", tmp_path / "frames")
    fields = lines[1].split()
    fields[7] = "2.0"  # scale the rotation: not orthonormal
    (tmp_path / "bad.txt").write_text(lines[0] + "\n" + " ".join(fields))
    with pytest.raises(DatasetError, match=r"bad.txt:2 world-to-camera: rotation is not orthonormal"):
        import_re10k(tmp_path / "bad.txt", tmp_path / "frames")
    (tmp_path / "bad.txt").write_text(lines[0] + "\n" + lines[1].replace("1000000", "42", 1))
    with pytest.raises(DatasetError, match="no image 42.png"):
        import_re10k(tmp_path / "bad.txt", tmp_path / "frames")


def test_up_alignment_puts_camera_up_on_z():
    # level cameras in a world whose up is -y (the OpenCV camera convention, as RE10K tends to be)
    tilt = np.eye(4)
    tilt[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # z-up world -> y-down world
    poses = np.stack([tilt @ view_to_cam2world(np.array([0, 0, 0, y, 0.0])) for y in (0.0, 1.0, 2.0)])
    r = align_up_to_cameras(poses)
    aligned = r @ poses
    np.testing.assert_allclose(-aligned[:, :3, 1], np.tile([0, 0, 1.0], (3, 1)), atol=1e-12)


def test_cli_import_and_info(tmp_path, capsys):
    from aes_planner.cli import main

    frames = make_frames(2, depth=False)
    doc = {"fl_x": 20.0, "w": 16, "h": 12, "frames": []}
    for i, f in enumerate(frames):
        write_image(tmp_path / f"{i}.png")
        doc["frames"].append({"file_path": f"{i}.png", "transform_matrix": (f.cam2world @ OPENGL_TO_OPENCV).tolist()})
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    assert (
        main(["dataset", "import", "nerfstudio", str(tmp_path / "transforms.json"), "--out", str(tmp_path / "out")])
        == 0
    )
    assert main(["dataset", "info", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "2 frames" in out and "16x12" in out
    assert main(["dataset", "info", str(tmp_path / "nothing")]) == 2
    assert "not found" in capsys.readouterr().err


@pytest.mark.parametrize("side_px", [2400, 1200, 320, 100])
def test_large_photos_are_decoded_reduced_and_match_a_full_decode(tmp_path, side_px):
    """``load_dataset(max_side_px=)`` decodes a JPEG at 1/2..1/8 of its size where that still covers
    the working size: the frame it gives (pixels, intrinsics, depth) is the one a full decode then
    downscale gives, to within resampling noise, and the stored size is still what cameras.json says."""
    w, h = 2400, 1600
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack([(xx * 255 // w), (yy * 255 // h), ((xx + yy) // 40 % 2) * 255], -1).astype(np.uint8)
    k = Intrinsics(2000.0, 2000.0, 1190.0, 805.0, w, h)
    frame = PosedFrame(img, k, view_to_cam2world(np.array([0.0, 0, 1.5, 0.3, -0.2])), 0.0, None, "f0")
    save_dataset(tmp_path / "ds", [frame])
    doc = json.loads((tmp_path / "ds" / "cameras.json").read_text())
    png = doc["frames"][0]["image"]
    jpg = png.replace(".png", ".jpg")
    cv2.imwrite(str(tmp_path / "ds" / jpg), cv2.imread(str(tmp_path / "ds" / png)), [cv2.IMWRITE_JPEG_QUALITY, 95])
    doc["frames"][0]["image"] = jpg
    depth = np.full((h, w), 2.5, np.float32)
    depth[:, : w // 2] = 4.0
    np.save(tmp_path / "ds" / "d.npy", depth)
    doc["frames"][0]["depth"] = "d.npy"
    (tmp_path / "ds" / "cameras.json").write_text(json.dumps(doc))

    got = load_dataset(tmp_path / "ds", max_side_px=side_px)
    f = got.frames[0]
    full = cv2.cvtColor(cv2.imread(str(tmp_path / "ds" / jpg)), cv2.COLOR_BGR2RGB)
    scale = min(1.0, side_px / w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    want = cv2.resize(full, size, interpolation=cv2.INTER_AREA) if scale < 1 else full
    assert f.image.shape == want.shape and f.extras["stored_size"] == (w, h)
    assert np.abs(f.image.astype(int) - want.astype(int)).mean() < 4.0  # JPEG DCT scaling vs area average
    assert f.intrinsics.width == size[0] and f.intrinsics.height == size[1]
    assert f.intrinsics.fx == pytest.approx(k.fx * size[0] / w) and f.intrinsics.cy == pytest.approx(k.cy * size[1] / h)
    assert f.depth_m.shape == want.shape[:2] and set(np.unique(f.depth_m)) == {2.5, 4.0}
    assert got.downscaled == ({(w, h): 1} if scale < 1 else {})
