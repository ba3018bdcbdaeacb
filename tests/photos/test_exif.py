"""EXIF camera tags (make, model, focal lengths) read from a JPEG's APP1, and photos grouped by camera."""

from __future__ import annotations

import struct

import cv2
import numpy as np

from aes_planner.photos.exif import read_camera_tags
from aes_planner.photos.sfm import _prepare


def _exif(make: str, model: str, focal: tuple[int, int], focal35: int) -> bytes:
    """A little-endian TIFF block: IFD0 (Make, Model, ExifIFD pointer), Exif IFD (FocalLength, 35 mm)."""
    make_b, model_b = make.encode() + b"\0", model.encode() + b"\0"
    ifd0_at = 8
    ifd0_size = 2 + 3 * 12 + 4
    data_at = ifd0_at + ifd0_size
    make_at, model_at = data_at, data_at + len(make_b)
    exif_at = model_at + len(model_b)
    exif_size = 2 + 2 * 12 + 4
    rational_at = exif_at + exif_size
    out = b"II*\x00" + struct.pack("<I", ifd0_at)
    out += struct.pack("<H", 3)
    out += struct.pack("<HHII", 0x010F, 2, len(make_b), make_at)
    out += struct.pack("<HHII", 0x0110, 2, len(model_b), model_at)
    out += struct.pack("<HHII", 0x8769, 4, 1, exif_at)
    out += struct.pack("<I", 0) + make_b + model_b
    out += struct.pack("<H", 2)
    out += struct.pack("<HHII", 0x920A, 5, 1, rational_at)
    out += struct.pack("<HHI", 0xA405, 3, 1) + struct.pack("<HH", focal35, 0)
    out += struct.pack("<I", 0) + struct.pack("<II", *focal)
    return out


def _jpeg_with_exif(path, tiff: bytes, seed: int) -> None:
    img = np.random.default_rng(seed).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    ok, jpg = cv2.imencode(".jpg", img)
    assert ok
    body = b"Exif\x00\x00" + tiff
    app1 = b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body
    path.write_bytes(jpg.tobytes()[:2] + app1 + jpg.tobytes()[2:])


def test_tags_are_read(tmp_path):
    _jpeg_with_exif(tmp_path / "a.jpg", _exif("Canon", "EOS 80D", (50, 1), 80), 0)
    tags = read_camera_tags(tmp_path / "a.jpg")
    assert (tags.make, tags.model, tags.focal_mm, tags.focal_35mm) == ("Canon", "EOS 80D", 50.0, 80.0)
    decoded = cv2.imread(str(tmp_path / "a.jpg"))
    assert decoded is not None and decoded.shape == (48, 64, 3)  # still a valid JPEG


def test_missing_or_damaged_exif_reads_as_nothing(tmp_path):
    cv2.imwrite(str(tmp_path / "plain.png"), np.zeros((8, 8, 3), np.uint8))
    assert not read_camera_tags(tmp_path / "plain.png").known
    _jpeg_with_exif(tmp_path / "bad.jpg", b"II*\x00" + struct.pack("<I", 10**9), 1)  # IFD beyond the block
    assert not read_camera_tags(tmp_path / "bad.jpg").known
    (tmp_path / "cut.jpg").write_bytes(b"\xff\xd8\xff\xe1\x00")
    assert not read_camera_tags(tmp_path / "cut.jpg").known


def test_photos_are_grouped_by_camera(tmp_path):
    files = []
    for i, model in enumerate(["Model A", "Model A", "Model B", "Model A"]):  # > 4 bytes: stored at an offset
        files.append(tmp_path / f"p{i}.jpg")
        _jpeg_with_exif(files[-1], _exif("Make", model, (24, 1), 36), i)
    photos, groups = _prepare(files, tmp_path / "work", 1024)
    assert groups == [[0, 1, 3], [2]]
    assert [p.group for p in photos] == [0, 0, 1, 0]
