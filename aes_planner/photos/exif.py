"""The few EXIF tags that say which camera took a photo: make, model, focal length (and its 35 mm
equivalent), read from a JPEG's APP1 segment or a TIFF header without decoding the image.

Only plain reads of bounded size: the header walk stops at the first image data, at most
:data:`MAX_SEGMENTS` segments, and every offset is checked against the segment's length.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CameraTags", "read_camera_tags"]

MAX_SEGMENTS = 64
_MAKE, _MODEL, _EXIF_IFD, _FOCAL, _FOCAL35 = 0x010F, 0x0110, 0x8769, 0x920A, 0xA405


@dataclass(frozen=True)
class CameraTags:
    """What a photo's EXIF says of its camera; empty strings / None where it says nothing."""

    make: str = ""
    model: str = ""
    focal_mm: float | None = None
    focal_35mm: float | None = None

    @property
    def known(self) -> bool:
        return bool(self.make or self.model or self.focal_mm)


def read_camera_tags(path: str | Path) -> CameraTags:
    """The :class:`CameraTags` of a JPEG or TIFF file (an empty one for other formats, no EXIF, or
    a damaged header: the tags only group photos by camera, they are never required)."""
    try:
        with Path(path).open("rb") as f:
            head = f.read(4)
            if head[:2] == b"\xff\xd8":
                tiff = _jpeg_app1(f)
            elif head in (b"II*\x00", b"MM\x00*"):
                f.seek(0)
                tiff = f.read(1 << 16)
            else:
                return CameraTags()
    except OSError:
        return CameraTags()
    if not tiff:
        return CameraTags()
    try:
        return _parse_tiff(tiff)
    except (struct.error, ValueError, IndexError, UnicodeDecodeError):
        return CameraTags()


def _jpeg_app1(f) -> bytes | None:
    f.seek(2)
    for _ in range(MAX_SEGMENTS):
        marker = f.read(2)
        if len(marker) < 2 or marker[0] != 0xFF or marker[1] in (0xD9, 0xDA):  # end, or image data
            return None
        raw = f.read(2)
        if len(raw) < 2:
            return None
        length = struct.unpack(">H", raw)[0]
        if length < 2:
            return None
        if marker[1] == 0xE1:
            body = f.read(length - 2)
            if body[:6] == b"Exif\x00\x00":
                return body[6:]
        else:
            f.seek(length - 2, 1)
    return None


def _parse_tiff(data: bytes) -> CameraTags:
    end = "<" if data[:2] == b"II" else ">"
    if data[:2] not in (b"II", b"MM"):
        return CameraTags()
    (ifd0,) = struct.unpack(end + "I", data[4:8])
    tags = _ifd(data, ifd0, end)
    if _EXIF_IFD in tags:
        tags.update(_ifd(data, int(tags[_EXIF_IFD]), end))

    def text(tag: int) -> str:
        v = tags.get(tag)
        return v.strip() if isinstance(v, str) else ""

    def number(tag: int) -> float | None:
        v = tags.get(tag)
        return float(v) if isinstance(v, (int, float)) and 0 < v < 1e4 else None

    return CameraTags(text(_MAKE), text(_MODEL), number(_FOCAL), number(_FOCAL35))


def _ifd(data: bytes, offset: int, end: str) -> dict:
    """The tags of the IFD at ``offset`` that this module reads: ASCII, SHORT, LONG, RATIONAL."""
    out: dict = {}
    if not 0 <= offset <= len(data) - 2:
        return out
    (count,) = struct.unpack(end + "H", data[offset : offset + 2])
    for i in range(min(count, 512)):
        e = offset + 2 + 12 * i
        if e + 12 > len(data):
            break
        tag, typ, n = struct.unpack(end + "HHI", data[e : e + 8])
        if tag not in (_MAKE, _MODEL, _EXIF_IFD, _FOCAL, _FOCAL35):
            continue
        value = data[e + 8 : e + 12]
        if typ == 2:  # ASCII
            raw = value[:n] if n <= 4 else data[struct.unpack(end + "I", value)[0] :][:n]
            out[tag] = raw.split(b"\x00")[0].decode("ascii", "replace")[:64]
        elif typ == 3:  # SHORT
            out[tag] = struct.unpack(end + "H", value[:2])[0]
        elif typ == 4:  # LONG
            out[tag] = struct.unpack(end + "I", value)[0]
        elif typ == 5:  # RATIONAL
            at = struct.unpack(end + "I", value)[0]
            if at + 8 <= len(data):
                num, den = struct.unpack(end + "II", data[at : at + 8])
                if den:
                    out[tag] = num / den
    return out
