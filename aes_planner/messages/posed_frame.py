"""``PosedFrame``: one image with its intrinsics, pose, optional depth and time stamp."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.messages.codec import Message, MessageError, Reader, Writer, register_message
from aes_planner.messages.fields import check_optional_finite, check_pose, check_sequence, check_text

__all__ = ["MessageError", "PosedFrame", "MAX_IMAGE_SIDE_PX", "MAX_IMAGE_PIXELS"]

MAX_IMAGE_SIDE_PX = 8192
MAX_IMAGE_PIXELS = 4096 * 3072  # 12.6 MP: 38 MB of RGB + 50 MB of depth
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@register_message
@dataclass
class PosedFrame(Message):
    """An RGB image taken from a known pose.

    * ``image``: ``[H, W, 3]`` uint8 RGB, at most ``MAX_IMAGE_SIDE_PX`` a side and
      ``MAX_IMAGE_PIXELS`` in all.
    * ``intrinsics``: pinhole intrinsics in pixels; its size must be the image's.
    * ``cam2world``: ``[4, 4]`` float64, OpenCV camera axes (see :mod:`aes_planner.geometry`).
    * ``depth_m``: optional ``[H, W]`` float32 z-depth in metres; ``0`` marks pixels without a
      measurement (sky, holes). Never NaN or Inf.
    * ``stamp_s``: capture time in seconds (the sensor's clock; sim time in the simulator).
    * ``frame_id``: a name for the frame (file stem, camera name), printable, <= 256 chars.
    * ``extras``: in-process side data (the simulator's instance ids); never serialised.
    * ``sequence``: the camera's frame counter (>= 0).
    * ``pan_rad``, ``tilt_rad``: the gimbal joint angles the frame was taken at, when on a rig
      (both or neither).

    Construction validates every field and raises :class:`MessageError` naming it.
    Wire format: see :mod:`aes_planner.messages.codec`; ``encode(image_format="png")`` stores
    the image losslessly compressed (for recordings).
    """

    TYPE_NAME: ClassVar[str] = "PosedFrame"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 96 << 20

    image: np.ndarray
    intrinsics: Intrinsics
    cam2world: np.ndarray
    stamp_s: float = 0.0
    depth_m: np.ndarray | None = None
    frame_id: str = ""
    extras: dict = field(default_factory=dict)
    sequence: int = 0
    pan_rad: float | None = None
    tilt_rad: float | None = None

    def __post_init__(self):
        img = self.image
        if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] != 3:
            raise MessageError(f"PosedFrame.image must be an [H, W, 3] array, got {getattr(img, 'shape', type(img))}")
        if img.dtype != np.uint8:
            raise MessageError(
                f"PosedFrame.image must be uint8 RGB, got {img.dtype}; convert with (img * 255).round().astype(np.uint8)"
            )
        h, w = img.shape[:2]
        if h < 1 or w < 1 or max(h, w) > MAX_IMAGE_SIDE_PX or h * w > MAX_IMAGE_PIXELS:
            raise MessageError(
                f"PosedFrame.image is {w}x{h}; images must be non-empty, at most {MAX_IMAGE_SIDE_PX} px a side "
                f"and {MAX_IMAGE_PIXELS} px in all; downscale it"
            )
        if not isinstance(self.intrinsics, Intrinsics):
            raise MessageError(f"PosedFrame.intrinsics must be an Intrinsics, got {type(self.intrinsics).__name__}")
        if (self.intrinsics.width, self.intrinsics.height) != (w, h):
            raise MessageError(
                f"PosedFrame.intrinsics are for {self.intrinsics.width}x{self.intrinsics.height} but the image is {w}x{h}; "
                "rescale them with Intrinsics.scaled(width, height)"
            )
        self.cam2world = check_pose(self.cam2world, "PosedFrame.cam2world")
        if (
            isinstance(self.stamp_s, bool)
            or not isinstance(self.stamp_s, (int, float, np.integer, np.floating))
            or not math.isfinite(self.stamp_s)
        ):
            raise MessageError(f"PosedFrame.stamp_s must be a finite number of seconds, got {self.stamp_s!r}")
        self.stamp_s = float(self.stamp_s)
        if self.depth_m is not None:
            d = np.asarray(self.depth_m)
            if d.shape != (h, w):
                raise MessageError(f"PosedFrame.depth_m must be [{h}, {w}] like the image, got {d.shape}")
            if not np.issubdtype(d.dtype, np.floating):
                raise MessageError(f"PosedFrame.depth_m must be float metres, got {d.dtype}")
            d = d.astype(np.float32, copy=False)
            if not np.all(np.isfinite(d)) or (d < 0).any():
                raise MessageError("PosedFrame.depth_m must be finite and >= 0 (0 = no measurement)")
            self.depth_m = d
        self.frame_id = check_text(self.frame_id, "PosedFrame.frame_id")
        self.sequence = check_sequence(self.sequence, "PosedFrame.sequence")
        self.pan_rad = check_optional_finite(self.pan_rad, "PosedFrame.pan_rad")
        self.tilt_rad = check_optional_finite(self.tilt_rad, "PosedFrame.tilt_rad")
        if (self.pan_rad is None) != (self.tilt_rad is None):
            raise MessageError("PosedFrame.pan_rad and tilt_rad must be given together (or neither)")

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def height(self) -> int:
        return self.image.shape[0]

    # -- wire format ---------------------------------------------------------------------------

    def _write(self, w: Writer, image_format: str = "raw") -> None:
        w.f64(self.stamp_s)
        w.u64(self.sequence)
        w.str(self.frame_id)
        k = self.intrinsics
        for v in (k.fx, k.fy, k.cx, k.cy):
            w.f64(float(v))
        w.array(self.cam2world, "f8")
        w.opt_f64(self.pan_rad)
        w.opt_f64(self.tilt_rad)
        if image_format == "raw":
            w.u8(0)
            w.array(self.image, "u1")
        elif image_format == "png":
            import cv2

            ok, png = cv2.imencode(".png", np.ascontiguousarray(self.image[..., ::-1]))
            if not ok:  # pragma: no cover - cv2 encodes any uint8 image
                raise MessageError("PosedFrame: PNG encoding failed")
            w.u8(1)
            w.u32(self.width)
            w.u32(self.height)
            w.raw(png.tobytes())
        else:
            raise MessageError(f"PosedFrame image_format must be 'raw' or 'png', got {image_format!r}")
        w.bool(self.depth_m is not None)
        if self.depth_m is not None:
            w.array(self.depth_m, "f4")

    @classmethod
    def _read(cls, r: Reader, version: int) -> PosedFrame:
        stamp_s = r.f64("stamp_s")
        sequence = r.u64("sequence")
        frame_id = r.str("frame_id")
        fx, fy, cx, cy = (r.f64(n) for n in ("intrinsics.fx", "intrinsics.fy", "intrinsics.cx", "intrinsics.cy"))
        cam2world = r.array("cam2world", "f8", 2, (4, 4))
        pan = r.opt_f64("pan_rad")
        tilt = r.opt_f64("tilt_rad")
        kind = r.u8("image format")
        side = (MAX_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX, 3)
        if kind == 0:
            image = r.array("image", "u1", 3, side)
        elif kind == 1:
            width, height = r.u32("image width"), r.u32("image height")
            png = r.raw("image png", cls.MAX_BYTES)
            image = _decode_png(png, width, height)
        else:
            raise MessageError(f"PosedFrame: unknown image format code {kind}")
        h, w = image.shape[:2]
        if h * w > MAX_IMAGE_PIXELS:
            raise MessageError(f"PosedFrame.image {w}x{h} exceeds the cap of {MAX_IMAGE_PIXELS} pixels")
        depth = r.array("depth_m", "f4", 2, side[:2]) if r.bool("has depth") else None
        return cls(
            image=image,
            intrinsics=Intrinsics(fx, fy, cx, cy, w, h),
            cam2world=cam2world,
            stamp_s=stamp_s,
            depth_m=depth,
            frame_id=frame_id,
            sequence=sequence,
            pan_rad=pan,
            tilt_rad=tilt,
        )


def _decode_png(png: bytes, width: int, height: int) -> np.ndarray:
    """Decode an RGB PNG whose declared size (checked before decoding: no decompression bombs)
    must be ``width x height``."""
    if len(png) < 24 or png[:8] != _PNG_SIGNATURE or png[12:16] != b"IHDR":
        raise MessageError("PosedFrame.image: not a PNG stream")
    pw, ph = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    if (pw, ph) != (width, height):
        raise MessageError(f"PosedFrame.image: PNG is {pw}x{ph} but the message says {width}x{height}")
    if not (1 <= pw <= MAX_IMAGE_SIDE_PX and 1 <= ph <= MAX_IMAGE_SIDE_PX) or pw * ph > MAX_IMAGE_PIXELS:
        raise MessageError(f"PosedFrame.image: PNG of {pw}x{ph} exceeds the image caps")
    import cv2

    bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None or bgr.shape[:2] != (ph, pw) or bgr.dtype != np.uint8:
        raise MessageError("PosedFrame.image: corrupt PNG data")
    return np.ascontiguousarray(bgr[..., ::-1])
