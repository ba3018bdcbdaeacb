"""Bad-input sweep: dataset folders (cameras.json), nerfstudio and RealEstate10K imports,
and writing datasets. Every case is a DatasetError with one line naming the field, or the documented
result; no path in a file reaches outside its folder unless allowed; nothing is written outside --out.
"""

import json
import math
import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.dataset import DatasetError, import_nerfstudio, import_re10k, load_dataset, save_dataset
from aes_planner.geometry import Intrinsics, view_to_cam2world, world2cam
from aes_planner.messages import PosedFrame

W, H = 16, 12


def frames(n=2):
    rng = np.random.default_rng(0)
    return [
        PosedFrame(
            image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
            intrinsics=Intrinsics(20.0, 20.0, W / 2, H / 2, W, H),
            cam2world=view_to_cam2world(np.array([i * 0.3, 0.0, 1.5, 0.2 * i, 0.0])),
            stamp_s=float(i),
            depth_m=rng.uniform(1, 5, (H, W)).astype(np.float32),
        )
        for i in range(n)
    ]


def png_header(width, height):
    chunk = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk)) + b"\0" * 64


def npy_header(shape):
    header = repr({"descr": "<f4", "fortran_order": False, "shape": shape}).encode()
    header += b" " * (63 - (10 + len(header)) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "ds"
    save_dataset(root, frames())
    (tmp_path / "secret.png").write_bytes((root / "images" / "00000.png").read_bytes())
    (root / "bomb.png").write_bytes(png_header(100000, 100000))
    (root / "depth" / "huge.npy").write_bytes(npy_header((100000, 100000)))
    (root / "depth" / "short.npy").write_bytes(npy_header((H, W)) + b"\0" * 10)
    (root / "depth" / "cube.npy").write_bytes(npy_header((2, 2, 2)) + b"\0" * 32)
    cv2.imwrite(str(root / "depth" / "eight.png"), np.zeros((H, W), np.uint8))
    (root / "images" / "link.png").symlink_to(tmp_path / "secret.png")
    doc = json.loads((root / "cameras.json").read_text())

    def write(mutate=None, text=None):
        d = json.loads(json.dumps(doc))
        if mutate is not None:
            mutate(d)
        (root / "cameras.json").write_text(text if text is not None else json.dumps(d))
        return root

    return write


def _f(key, value, i=0):
    return lambda d: d["frames"][i].__setitem__(key, value)


CAMERAS_CASES = [
    (_f("fx", 1e300), "frames[0].fx", "field of view"),
    (_f("fx", 1e-300), "frames[0].fx", "field of view"),
    (_f("fy", 1e-3), "frames[0].fy", "field of view"),
    (_f("cx", 1e6), "frames[0].cx", "principal point"),
    (_f("cy", -1e4), "frames[0].cy", "principal point"),
    (_f("fx", "20"), "frames[0].fx", "finite number"),
    (_f("fx", True), "frames[0].fx", "finite number"),
    (_f("fx", [20]), "frames[0].fx", "finite number"),
    (_f("fx", None), "frames[0].fx", "missing"),
    (_f("stamp_s", "noon"), "frames[0].stamp_s", "finite number"),
    (_f("stamp_s", 1e400), "frames[0].stamp_s", "finite number"),
    (_f("image", "/etc/hostname"), "frames[0].image", "leads outside"),
    (_f("image", "../secret.png"), "frames[0].image", "leads outside"),
    (_f("image", "images/link.png"), "frames[0].image", "leads outside"),
    (_f("image", "images/\x00.png"), "frames[0].image", "NUL"),
    (_f("image", 7), "frames[0].image", "missing"),
    (_f("image", "bomb.png"), "frames[0].image", "100000x100000"),
    (_f("image", "cameras.json"), "frames[0].image", "not an image"),
    (_f("depth", "../secret.png"), "frames[0].depth", "leads outside"),
    (_f("depth", ["x"]), "frames[0].depth", "expected a path"),
    (_f("depth", "depth/huge.npy"), "frames[0].depth", "100000"),
    (_f("depth", "depth/short.npy"), "frames[0].depth", "truncated"),
    (_f("depth", "depth/cube.npy"), "frames[0].depth", "2D numeric"),
    (_f("depth", "depth/eight.png"), "frames[0].depth", "16-bit"),
    (_f("depth", "images/00000.png"), "frames[0].depth", "16-bit"),
    (_f("depth_png_scale_m", 0), "depth_png_scale_m", "positive scale"),
    (_f("depth_png_scale_m", "mm"), "depth_png_scale_m", "finite number"),
    (_f("cam2world", [[0] * 4] * 4), "frames[0].cam2world", ""),
    (_f("cam2world", [["a"] * 4] * 4), "frames[0].cam2world", "4x4"),
    (_f("cam2world", {"a": 1}), "frames[0].cam2world", "4x4"),
    (_f("width", "16"), "frames[0].width", "whole number of pixels, got '16'"),  # said "16x12 but ... is 16x12"
    (lambda d: d["frames"].__setitem__(0, []), "frames[0]", "expected an object"),
    (lambda d: d.__setitem__("frames", {}), "frames", "must be a list"),
    (lambda d: d.__setitem__("meta", []), "meta", "must be an object"),
    (lambda d: d.__setitem__("version", "1"), "version", "not supported"),
]


@pytest.mark.parametrize("mutate, key, match", CAMERAS_CASES, ids=range(len(CAMERAS_CASES)))
def test_bad_cameras_json_names_the_field(dataset, clean_error, mutate, key, match):
    err = clean_error(load_dataset, dataset(mutate), match=match)
    assert key in str(err)


def test_outside_paths_load_only_when_allowed(dataset, clean_error):
    root = dataset(_f("image", "../secret.png"))
    clean_error(load_dataset, root, match="leads outside")
    assert len(load_dataset(root, allow_outside=True)) == 2


@pytest.mark.parametrize(
    "text, match",
    [
        ("[" * 100000 + "]" * 100000, "nested too deeply"),
        ('{"frames": [' + "1" * 5000 + "]}", "not valid JSON here"),
        ("\xff\xfe garbage", "not valid JSON"),
        ("", "not valid JSON"),
        ("null", "'format' must be"),
    ],
)
def test_cameras_json_that_is_not_json(dataset, clean_error, text, match):
    root = dataset()
    (root / "cameras.json").write_bytes(text.encode("latin-1"))
    clean_error(load_dataset, root, match=match)


def test_writing_never_goes_outside_the_output_folder(tmp_path, clean_error):
    (tmp_path / "file").write_text("x")
    clean_error(save_dataset, tmp_path / "file", frames(), match="not a folder")
    clean_error(save_dataset, tmp_path / "file" / "sub", frames(), match="cannot create")
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "images").symlink_to(elsewhere)
    clean_error(save_dataset, out, frames(), match="symlink")
    assert list(elsewhere.iterdir()) == []
    for k, name in enumerate(("images/00001.png", "depth/00000.npy")):  # a file's link, inside the folders
        folder, victim = tmp_path / f"out{k}", tmp_path / f"victim{k}"
        (folder / name).parent.mkdir(parents=True)
        (folder / name).symlink_to(victim)
        clean_error(save_dataset, folder, frames(), match=f"{name}: is a symlink")
        assert not victim.exists() and not (folder / "images" / "00000.png").exists()  # nothing written
    clean_error(save_dataset, tmp_path / "m", frames(), meta={"x": float("nan")}, match="finite")
    clean_error(save_dataset, tmp_path / "m", frames(), meta={"x": object()}, match="cannot be stored")


# ------------------------------------------------------------------------------- nerfstudio
@pytest.fixture
def nerf(tmp_path):
    folder = tmp_path / "ns"
    (folder / "images").mkdir(parents=True)
    cv2.imwrite(str(folder / "images" / "a.png"), np.zeros((H, W, 3), np.uint8))
    (tmp_path / "secret.png").write_bytes((folder / "images" / "a.png").read_bytes())
    base = {
        "fl_x": 20.0,
        "w": W,
        "h": H,
        "frames": [{"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}],
    }

    def write(mutate=None):
        d = json.loads(json.dumps(base))
        if mutate is not None:
            mutate(d)
        (folder / "transforms.json").write_text(json.dumps(d))
        return folder / "transforms.json"

    return write


def _top(key, value):
    return lambda d: d.__setitem__(key, value)


def _fr(key, value):
    return lambda d: d["frames"][0].__setitem__(key, value)


NERF_CASES = [
    (lambda d: (d.pop("fl_x"), d.__setitem__("camera_angle_x", math.pi)), "camera_angle_x", "field of view in radians"),
    (lambda d: (d.pop("fl_x"), d.__setitem__("camera_angle_x", 0.0)), "camera_angle_x", "field of view in radians"),
    (lambda d: (d.pop("fl_x"), d.__setitem__("camera_angle_x", -1.0)), "camera_angle_x", "field of view in radians"),
    (lambda d: (d.pop("fl_x"), d.__setitem__("camera_angle_x", "wide")), "camera_angle_x", "finite number"),
    (_top("fl_x", 1e300), "fx", "field of view"),
    (_top("fl_x", 1e-300), "fx", "field of view"),
    (_top("cx", 1e9), "cx", "principal point"),
    (_top("frames", []), "frames", "nothing to import"),
    (_top("frames", "all"), "frames", "'frames' list"),
    (_top("k1", "x"), "k1", "finite number"),
    (lambda d: d.update(k1=0.1, camera_model="EQUIRECTANGULAR"), "frames[0]", "not undistorted here"),
    (lambda d: d.update(k4=0.01), "frames[0]", "not undistorted here"),  # OPENCV's k4 is not nerfstudio's
    (lambda d: d.update(p1=0.01, camera_model="OPENCV_FISHEYE"), "frames[0]", "not undistorted here"),
    (lambda d: d.update(k1=0.1, camera_model=["OPENCV"]), "frames[0]", "not undistorted here"),
    (_top("w", 99), "frames[0]", "w/h say 99"),
    (_fr("file_path", "/etc/hostname"), "file_path", "leads outside"),
    (_fr("file_path", "../secret.png"), "file_path", "leads outside"),
    (_fr("file_path", None), "file_path", "missing"),
    (_fr("transform_matrix", "eye"), "transform_matrix", "4x4"),
    (_fr("transform_matrix", (np.eye(4) * 2).tolist()), "transform_matrix", ""),
    (lambda d: d["frames"][0].update(depth_file_path="../secret.png"), "depth_file_path", "leads outside"),
    (lambda d: d["frames"][0].update(depth_file_path=3), "depth_file_path", "expected a path"),
    (
        lambda d: (d["frames"][0].update(depth_file_path="images/a.png"), d.update(depth_unit_scale_factor=0)),
        "depth_unit_scale_factor",
        "positive scale",
    ),
]


@pytest.mark.parametrize("mutate, key, match", NERF_CASES, ids=range(len(NERF_CASES)))
def test_bad_transforms_json_names_the_field(nerf, clean_error, mutate, key, match):
    err = clean_error(import_nerfstudio, nerf(mutate), match=match)
    assert key in str(err)


@pytest.mark.parametrize("model, coefficients", [("OPENCV", {"k1": -0.2, "p2": 0.01}), ("OPENCV_FISHEYE", {"k1": 0.1})])
def test_nerfstudio_distortion_is_undistorted_not_ignored(tmp_path, model, coefficients):
    # Imported as if undistorted, every ray off the image centre would point the wrong way.
    rng = np.random.default_rng(0)
    raw = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), raw[..., ::-1])
    doc = {"fl_x": 20.0, "w": W, "h": H, "camera_model": model, **coefficients}
    doc["frames"] = [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    frame = import_nerfstudio(tmp_path).frames[0]
    K = frame.intrinsics.K
    if model == "OPENCV":
        dist = np.array([coefficients.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
        expected = cv2.undistort(raw, K, dist)
    else:
        dist = np.array([coefficients.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")])
        expected = cv2.fisheye.undistortImage(raw, K, dist, Knew=K)
    assert not np.array_equal(frame.image, raw)
    assert np.abs(frame.image.astype(int) - expected.astype(int)).mean() < 2.0


def test_nerfstudio_outside_paths_only_when_allowed(nerf, clean_error):
    path = nerf(_fr("file_path", "../secret.png"))
    clean_error(import_nerfstudio, path, match="leads outside")
    assert len(import_nerfstudio(path, allow_outside=True)) == 1


# --------------------------------------------------------------------------- RealEstate10K
@pytest.fixture
def clip(tmp_path):
    frames_dir = tmp_path / "frames"
    frames_dir.mkdir()
    cv2.imwrite(str(frames_dir / "1000.png"), np.zeros((H, W, 3), np.uint8))
    (tmp_path / "secret.png").write_bytes((frames_dir / "1000.png").read_bytes())
    k = Intrinsics(20.0, 20.0, W / 2, H / 2, W, H)
    w2c = world2cam(np.eye(4))[:3].reshape(-1)
    fields = ["1000", *(repr(float(v)) for v in (*k.to_normalized(), 0.0, 0.0, *w2c))]

    def write(edit=None, text=None):
        f = list(fields)
        if edit is not None:
            edit(f)
        path = tmp_path / "clip.txt"
        if text is None:
            path.write_text("https://example.invalid/v\n" + " ".join(f) + "\n")
        else:
            path.write_bytes(text)
        return path, frames_dir

    return write


def _field(i, value):
    return lambda f: f.__setitem__(i, value)


RE10K_CASES = [
    (_field(0, "../secret"), "timestamp"),
    (_field(0, "/etc/x"), "timestamp"),
    (_field(0, "1e3"), "timestamp"),
    (_field(1, "1e300"), "field of view"),
    (_field(1, "1e-300"), "field of view"),
    (_field(3, "1e6"), "principal point"),
    (_field(2, "nan"), "NaN or Inf"),
    (_field(5, "x"), "not all fields are numbers"),
    (lambda f: f.pop(), "expected 19 numbers"),
]


@pytest.mark.parametrize("edit, match", RE10K_CASES, ids=range(len(RE10K_CASES)))
def test_bad_re10k_lines(clip, clean_error, edit, match):
    path, frames_dir = clip(edit)
    clean_error(import_re10k, path, frames_dir, match=match)


def test_bad_re10k_files(clip, clean_error, tmp_path):
    path, frames_dir = clip(text=bytes(range(256)) * 8)
    clean_error(import_re10k, path, frames_dir, match="not a text file")
    path, _ = clip(text=b"https://example.invalid/v\n\n")
    clean_error(import_re10k, path, frames_dir, match="nothing to import")
    path, _ = clip(text=b"")
    clean_error(import_re10k, path, frames_dir, match="empty file")
    path, _ = clip()
    clean_error(import_re10k, path, tmp_path / "nowhere", match="not a folder")
    for every in (0, -3, 1.5, True):
        clean_error(import_re10k, path, frames_dir, every=every, match="every")
    # a frame that is a symlink out of the frames folder
    (frames_dir / "1000.png").unlink()
    (frames_dir / "1000.png").symlink_to(tmp_path / "secret.png")
    clean_error(import_re10k, path, frames_dir, match="leads outside")
    assert len(import_re10k(path, frames_dir, allow_outside=True)) == 1


@given(st.binary(max_size=400))
def test_any_bytes_as_an_re10k_file_is_a_clean_error(tmp_path_factory, data):
    folder = tmp_path_factory.mktemp("re10k")
    (folder / "clip.txt").write_bytes(data)
    try:
        import_re10k(folder / "clip.txt", folder)
    except DatasetError as exc:
        assert "\n" not in str(exc)


@given(
    st.recursive(
        st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=8),
        lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
        max_leaves=20,
    )
)
def test_any_json_value_as_cameras_json_is_a_clean_error(tmp_path_factory, doc):
    folder = tmp_path_factory.mktemp("cams")
    for frame_doc in ({"format": "aes-planner/posed-frames", "version": 1, "frames": [doc]}, doc):
        (folder / "cameras.json").write_text(json.dumps(frame_doc))
        try:
            load_dataset(folder)
        except DatasetError as exc:
            assert "\n" not in str(exc)
