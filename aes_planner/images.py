"""Image files in and out: bounded reading (every image file the package reads goes through
:func:`imread_bounded`), images to score, contact sheets to look at.

Decoding a small compressed file can allocate gigabytes (a "decompression bomb": a 40 kB PNG
of 100000 x 100000 pixels). :func:`imread_bounded` reads the image size from the file header
before decoding and refuses images above :data:`MAX_CAMERA_PIXELS`; formats whose header it does
not read are refused too (OpenCV's own ``CV_IO_MAX_IMAGE_PIXELS`` check allows 2^30 pixels, and
not for every codec).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import MAX_CAMERA_PIXELS, MAX_CAMERA_SIDE_PX, Intrinsics
from aes_planner.messages import PosedFrame

__all__ = [
    "MAX_CAMERA_PIXELS",
    "MAX_CAMERA_SIDE_PX",
    "ImageError",
    "check_image_size",
    "image_size",
    "write_image",
    "MAX_WORKING_SIDE_PX",
    "downscale_frame",
    "downscale_parts",
    "imread_bounded",
    "read_image",
    "write_contact_sheet",
]


class ImageError(AesPlannerError, ValueError):
    """An image file that is missing, unreadable, of an unsupported format or too large."""


def check_image_size(width: int, height: int, what: str) -> None:
    """Raise :class:`ImageError` unless ``width x height`` is within :data:`MAX_CAMERA_PIXELS` and
    :data:`MAX_CAMERA_SIDE_PX` (checked before anything of that size is allocated)."""
    if width > MAX_CAMERA_SIDE_PX or height > MAX_CAMERA_SIDE_PX or width * height > MAX_CAMERA_PIXELS:
        raise ImageError(
            f"{what} is {width}x{height} pixels; at most {MAX_CAMERA_SIDE_PX} per side and {MAX_CAMERA_PIXELS} "
            "in all are supported; downscale it"
        )


def _jpeg_size(f) -> tuple[int, int] | None:
    f.seek(2)
    while True:
        byte = f.read(1)
        while byte and byte != b"\xff":
            byte = f.read(1)
        while byte == b"\xff":
            byte = f.read(1)
        if not byte:
            return None
        marker = byte[0]
        if marker in (0x01, *range(0xD0, 0xD9)):  # standalone markers
            continue
        raw = f.read(2)
        if len(raw) < 2:
            return None
        length = struct.unpack(">H", raw)[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            data = f.read(5)
            if len(data) < 5:
                return None
            h, w = struct.unpack(">HH", data[1:5])
            return w, h
        if length < 2:
            return None
        f.seek(length - 2, 1)


def _tiff_size(f, head: bytes) -> tuple[int, int] | None:
    end = "<" if head[:2] == b"II" else ">"
    f.seek(4)
    (offset,) = struct.unpack(end + "I", f.read(4))
    f.seek(offset)
    raw = f.read(2)
    if len(raw) < 2:
        return None
    (count,) = struct.unpack(end + "H", raw)
    dims = {}
    for _ in range(min(count, 1000)):
        entry = f.read(12)
        if len(entry) < 12:
            break
        tag, typ = struct.unpack(end + "HH", entry[:4])
        if tag in (256, 257):
            dims[tag] = struct.unpack(end + ("H" if typ == 3 else "I"), entry[8:10] if typ == 3 else entry[8:12])[0]
    return (dims[256], dims[257]) if len(dims) == 2 else None


def image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` from the header of a PNG, JPEG, BMP, TIFF, WebP, PNM or GIF file, without
    decoding it; None when the format is none of these or the header is damaged."""
    try:
        with Path(path).open("rb") as f:
            head = f.read(32)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                return struct.unpack(">II", head[16:24])
            if head[:2] == b"\xff\xd8":
                return _jpeg_size(f)
            if head[:2] == b"BM" and len(head) >= 26:
                w, h = struct.unpack("<ii", head[18:26])
                return abs(w), abs(h)
            if head[:4] in (b"II*\x00", b"MM\x00*"):
                return _tiff_size(f, head)
            if head[:6] in (b"GIF87a", b"GIF89a"):
                return struct.unpack("<HH", head[6:10])
            if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
                chunk = head[12:16]
                if chunk == b"VP8X":
                    return 1 + int.from_bytes(head[24:27], "little"), 1 + int.from_bytes(head[27:30], "little")
                if chunk == b"VP8L":
                    b = int.from_bytes(head[21:25], "little")
                    return 1 + (b & 0x3FFF), 1 + ((b >> 14) & 0x3FFF)
                if chunk == b"VP8 ":
                    more = head + f.read(8)
                    w, h = struct.unpack("<HH", more[26:30])
                    return w & 0x3FFF, h & 0x3FFF
                return None
            if head[:1] == b"P" and head[1:2] in b"123456":
                tokens = head[2:].split(b"#")[0].split()
                return (int(tokens[0]), int(tokens[1])) if len(tokens) >= 2 else None
    except (OSError, struct.error, ValueError, IndexError):
        return None
    return None


def imread_bounded(path: str | Path, flags: int, what: str, error: type[AesPlannerError] = ImageError) -> np.ndarray:
    """``cv2.imread(path, flags)`` after checking that the file exists, is a format whose size can be
    read from its header (PNG, JPEG, BMP, TIFF, WebP, PNM, GIF) and is within :data:`MAX_CAMERA_PIXELS`.
    Errors are ``error`` (an :class:`AesPlannerError` subclass) and start with ``what``."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{what}: image file {path} not found")
    size = image_size(path)
    if size is None:
        raise error(
            f"{what}: {path} is not an image OpenCV can read here (PNG, JPEG, BMP, TIFF, WebP, PNM or GIF, "
            "with an intact header)"
        )
    try:
        check_image_size(int(size[0]), int(size[1]), f"{path}")
    except ImageError as exc:
        raise error(f"{what}: {exc}") from None
    try:
        img = cv2.imread(str(path), flags)
    except cv2.error as exc:
        raise error(f"{what}: OpenCV cannot decode {path} ({str(exc).strip().splitlines()[-1][:120]})") from None
    if img is None or img.size == 0:
        raise error(f"{what}: {path} is not an image OpenCV can read (damaged or truncated?)")
    return img


def read_image(path: str | Path):  # -> Tensor [3, H, W] float in [0, 1]
    """An image file as RGB float in [0, 1]; grey is repeated, alpha dropped, 16 bit kept."""
    import torch

    path = Path(path)
    if path.is_dir():
        raise ImageError(f"{path}: is a folder; give image files (e.g. {path / '*.png'})")
    if not path.is_file():
        raise ImageError(f"{path}: no such image file")
    raw = imread_bounded(path, cv2.IMREAD_UNCHANGED, str(path))
    if raw.dtype == np.uint8:
        arr = raw.astype(np.float32) / 255.0
    elif raw.dtype == np.uint16:
        arr = raw.astype(np.float32) / 65535.0
    elif raw.dtype in (np.float32, np.float64):
        arr = np.clip(np.nan_to_num(raw.astype(np.float32)), 0.0, 1.0)
    else:
        raise AesPlannerError(f"{path}: unsupported pixel type {raw.dtype}; save it as 8- or 16-bit PNG")
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    elif arr.shape[2] == 4:
        arr = arr[..., [2, 1, 0]]  # BGRA -> RGB, alpha dropped
    elif arr.shape[2] == 3:
        arr = arr[..., ::-1]
    else:
        raise AesPlannerError(f"{path}: {arr.shape[2]} channels; expected grey, RGB or RGBA")
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1).contiguous()


def write_contact_sheet(frames: Sequence[PosedFrame], path: str | Path) -> Path:
    """RGB on top, colour-mapped depth below, one column per frame; returns ``path``."""
    path = Path(path)
    cols = []
    for f in frames:
        rgb = cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR)
        d = f.depth_m if f.depth_m is not None else np.zeros(f.image.shape[:2], np.float32)
        valid = d > 0
        scale = np.percentile(d[valid], 98) if valid.any() else 1.0
        d8 = np.where(valid, 255 - np.clip(d / scale * 255, 0, 255), 0).astype(np.uint8)
        cols.append(np.vstack([rgb, cv2.applyColorMap(d8, cv2.COLORMAP_VIRIDIS)]))
    sheet = np.hstack([np.pad(c, ((2, 2), (2, 2), (0, 0)), constant_values=255) for c in cols])
    return write_image(path, sheet, "the contact sheet")


def write_image(path: str | Path, bgr: np.ndarray, what: str = "the image") -> Path:
    """``cv2.imwrite`` that raises :class:`ImageError` when nothing was written (``imwrite`` only
    returns False: a folder in the way, no permission, an unknown extension)."""
    path = Path(path)
    try:
        ok = cv2.imwrite(str(path), bgr)
    except cv2.error:
        ok = False
    if not ok or not path.is_file():
        raise ImageError(f"{path}: could not write {what}; check that it is a file name in a writable folder")
    return path


#: The largest side, in pixels, of a frame the field, the reconstruction and the search work on:
#: the field encodes its input views on the reconstruction's stride grid (about 128 px across),
#: the teachers look at 224 px or less and the search renders at 32-64 px. A photo is downscaled to
#: this on the way in (:func:`downscale_frame`): a 12 MP photo held at full size costs 84 MB with
#: its depth, and its plane-sweep stereo grows with its pixels (8 views of 640x480: 170 s and
#: 3.1 GB; of 320x240: 3.5 s and 0.5 GB), for nothing the field can see.
MAX_WORKING_SIDE_PX = 320


def downscale_parts(
    image: np.ndarray,  # [H, W, 3] uint8
    depth: np.ndarray | None,  # [H, W] metres
    intrinsics: Intrinsics,
    max_side_px: int = MAX_WORKING_SIDE_PX,
) -> tuple[np.ndarray, np.ndarray | None, Intrinsics]:
    """The image area-averaged to at most ``max_side_px`` a side, the depth sampled (nearest: no
    depth mixed across an edge) and the intrinsics scaled with them (same field of view); as they
    are when already that small."""
    h, w = image.shape[:2]
    if max(h, w) <= max_side_px:
        return image, depth, intrinsics
    s = max_side_px / max(h, w)
    nw, nh = max(1, round(w * s)), max(1, round(h * s))
    image = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
    if depth is not None:
        depth = cv2.resize(depth, (nw, nh), interpolation=cv2.INTER_NEAREST)
    return image, depth, intrinsics.scaled(nw, nh)


def downscale_frame(frame: PosedFrame, max_side_px: int = MAX_WORKING_SIDE_PX) -> PosedFrame:
    """``frame`` with its longer side at most ``max_side_px`` (:func:`downscale_parts`); the pose,
    stamp, ids and joints kept. A frame already that small is returned as is."""
    if max(frame.image.shape[:2]) <= max_side_px:
        return frame
    image, depth, k = downscale_parts(frame.image, frame.depth_m, frame.intrinsics, max_side_px)
    return PosedFrame(
        image,
        k,
        frame.cam2world,
        frame.stamp_s,
        depth,
        frame.frame_id,
        dict(frame.extras),
        frame.sequence,
        frame.pan_rad,
        frame.tilt_rad,
    )
