"""Bad-input sweep: image headers read before decoding, images that cannot be written, frames
downscaled with their camera (aes_planner.images), and paths kept inside their folder
(aes_planner.paths)."""

import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.images import ImageError, image_size, imread_bounded, read_image, write_contact_sheet
from aes_planner.paths import PathOutsideError, resolve_inside


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tiff", ".webp", ".ppm", ".pgm"])
def test_header_sizes_match_what_opencv_decodes(tmp_path, ext):
    img = np.random.default_rng(0).integers(0, 255, (13, 21, 3), dtype=np.uint8)
    path = tmp_path / f"x{ext}"
    if ext == ".pgm":
        img = img[..., 0]
    assert cv2.imwrite(str(path), img)
    assert image_size(path) == (21, 13)
    assert imread_bounded(path, cv2.IMREAD_UNCHANGED, "x").shape[:2] == (13, 21)


def test_webp_lossless_and_16_bit_png_headers(tmp_path):
    img = np.zeros((7, 300, 3), np.uint8)
    assert cv2.imwrite(str(tmp_path / "l.webp"), img, [cv2.IMWRITE_WEBP_QUALITY, 101])
    assert image_size(tmp_path / "l.webp") == (300, 7)
    assert cv2.imwrite(str(tmp_path / "d.png"), np.zeros((5, 6), np.uint16))
    assert image_size(tmp_path / "d.png") == (6, 5)


def _png(width, height):
    chunk = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))


@pytest.mark.parametrize(
    "data, match",
    [
        (_png(100000, 100000), "100000x100000"),
        (_png(40000, 10), "40000x10"),
        (_png(9000, 9000), "9000x9000"),
        (b"\xff\xd8\xff\xc0\x00\x11\x08" + struct.pack(">HH", 60000, 60000) + b"\0" * 20, "60000x60000"),
        (b"P6 100000 100000 255\n", "100000x100000"),
        (b"RIFF\0\0\0\0WEBPVP8X" + b"\0" * 8 + (20000).to_bytes(3, "little") * 2, "20001x20001"),
        (b"", "not an image"),
        (b"hello", "not an image"),
        (b"\x00\x00\x00\x0cjP  \r\n\x87\n", "not an image"),  # JPEG 2000: size not read, so refused
        (_png(10, 10) + b"garbage", "not an image OpenCV can read"),
    ],
)
def test_bombs_and_junk_are_refused_before_decoding(tmp_path, data, match, clean_error):
    (tmp_path / "x").write_bytes(data)
    clean_error(imread_bounded, tmp_path / "x", cv2.IMREAD_COLOR, "x", match=match, seconds=10)
    clean_error(read_image, tmp_path / "x", match=match, seconds=10)


@given(st.binary(max_size=200))
def test_any_bytes_as_an_image_is_an_image_error(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("img") / "x.png"
    path.write_bytes(data)
    try:
        imread_bounded(path, cv2.IMREAD_COLOR, "x")
    except ImageError as exc:
        assert "\n" not in str(exc)


def test_contact_sheet_to_an_unwritable_place(tmp_path, clean_error):
    from aes_planner.sim import SimCamera, SimCameraConfig, load_scene

    frame = SimCamera(load_scene("indoor:3"), SimCameraConfig(width=8, height=6)).capture_joints(0.0, 0.0)
    (tmp_path / "file").write_text("x")
    clean_error(write_contact_sheet, [frame], tmp_path / "file" / "sheet.png", match="could not write")
    assert write_contact_sheet([frame], tmp_path / "sheet.png").is_file()


def test_resolve_inside(tmp_path, clean_error):
    root = tmp_path / "root"
    (root / "sub").mkdir(parents=True)
    (root / "sub" / "a.png").write_text("x")
    (tmp_path / "secret").write_text("x")
    (root / "out_link").symlink_to(tmp_path / "secret")
    (root / "in_link").symlink_to(root / "sub" / "a.png")
    (root / "dir_link").symlink_to(tmp_path)
    assert resolve_inside(root, "sub/a.png", "k") == (root / "sub" / "a.png").resolve()
    assert resolve_inside(root, "sub/../sub/a.png", "k") == (root / "sub" / "a.png").resolve()
    assert resolve_inside(root, "in_link", "k") == (root / "sub" / "a.png").resolve()
    for bad in (
        "../secret",
        "/etc/passwd",
        str(tmp_path / "secret"),
        "out_link",
        "dir_link/secret",
        "sub/../../secret",
    ):
        err = clean_error(resolve_inside, root, bad, "frames[3].image", match="leads outside")
        assert isinstance(err, PathOutsideError) and str(err).startswith("frames[3].image:")
    clean_error(resolve_inside, root, "a\x00b", "k", match="NUL")
    assert resolve_inside(root, "../secret", "k", allow_outside=True) == (tmp_path / "secret").resolve()
    assert (
        resolve_inside(root, str(tmp_path / "secret"), "k", also_inside=[tmp_path]) == (tmp_path / "secret").resolve()
    )


def test_a_report_that_cannot_be_written_is_an_error(tmp_path, clean_error):
    from aes_planner.images import write_image

    (tmp_path / "r.png").mkdir()
    clean_error(write_image, tmp_path / "r.png", np.zeros((4, 4, 3), np.uint8), match="could not write")
    clean_error(write_image, tmp_path / "r.unknown", np.zeros((4, 4, 3), np.uint8), match="could not write")


def test_downscale_frame_keeps_the_camera():
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.images import downscale_frame
    from aes_planner.messages import PosedFrame

    k = Intrinsics(3000.0, 3000.0, 2000.0, 1500.0, 4000, 3000)
    depth = np.full((3000, 4000), 2.0, np.float32)
    depth[:, :2000] = 0.0  # unknown on the left: never averaged into the known half
    frame = PosedFrame(np.zeros((3000, 4000, 3), np.uint8), k, np.eye(4), 1.0, depth, "f", pan_rad=0.1, tilt_rad=0.2)
    small = downscale_frame(frame, 320)
    assert small.image.shape == (240, 320, 3) and small.depth_m.shape == (240, 320)
    assert small.intrinsics.hfov_rad == pytest.approx(k.hfov_rad) and small.intrinsics.cx == pytest.approx(160.0)
    assert set(np.unique(small.depth_m)) == {0.0, 2.0} and (small.pan_rad, small.frame_id) == (0.1, "f")
    tiny = downscale_frame(small, 320)
    assert tiny is small
