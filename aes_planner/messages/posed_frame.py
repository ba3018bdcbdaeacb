"""``PosedFrame``: one image with its intrinsics, pose, optional depth and time stamp."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.plausible import (
    FOV_RANGE_DEG,
    MAX_COORDINATE_M,
    MAX_JOINT_RAD,
    intrinsics_problem,
    joint_problem,
    position_problem,
)
from aes_planner.messages.codec import (
    Array,
    Bytes,
    Message,
    MessageError,
    Optional,
    Scalar,
    Str,
    Union,
    register_message,
    text_cap,
)
from aes_planner.messages.fields import check_optional_finite, check_pose, check_sequence, check_text

__all__ = ["MessageError", "PosedFrame", "MAX_FRAME_SIDE_PX", "MAX_FRAME_PIXELS"]

MAX_FRAME_SIDE_PX = 8192
#: Largest image a PosedFrame carries (12.6 MP: 38 MB of RGB + 50 MB of depth fit one message);
#: cameras and image files may be larger (:data:`aes_planner.geometry.camera.MAX_CAMERA_PIXELS`).
MAX_FRAME_PIXELS = 4096 * 3072
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_SIDE = (MAX_FRAME_SIDE_PX, MAX_FRAME_SIDE_PX)
IMAGE_FORMATS = ("raw", "png")


class ImageField(Union):
    """The image, in one of two formats (the tag byte): ``0`` raw (an ``[H, W, 3]`` uint8 RGB
    array) or ``1`` PNG (width, height, then a PNG stream of an 8-bit RGB image of that size,
    lossless; for recordings: ``encode(frame, image_format="png")``)."""

    def __init__(self) -> None:
        super().__init__(
            "image",
            {
                0: ("raw", (Array("pixels", "u1", (*_SIDE, 3), exact=(False, False, True)),)),
                1: ("png", (Scalar("width", "u32"), Scalar("height", "u32"), Bytes("png", 96 << 20))),
            },
            doc="RGB rows top to bottom. **raw**: the pixels. **png**: a PNG stream (writers write 8-bit RGB, "
            "colour type 2; a reader converts any PNG colour type OpenCV reads to 8-bit RGB) of exactly "
            "`width` x `height`, checked against its IHDR before it is decompressed. The bus carries raw "
            "images; recordings carry PNG",
        )

    def value_of(self, msg, options: dict):
        return msg.image

    def to_wire(self, image: np.ndarray, options: dict) -> tuple[int, dict]:
        image_format = options.get("image_format", "raw")
        if image_format == "raw":
            return 0, {"pixels": image}
        if image_format == "png":
            import cv2

            ok, png = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
            if not ok:  # pragma: no cover - cv2 encodes any uint8 image
                raise MessageError("PosedFrame: PNG encoding failed")
            return 1, {"width": image.shape[1], "height": image.shape[0], "png": png.tobytes()}
        raise MessageError(f"PosedFrame image_format must be 'raw' or 'png', got {image_format!r}")

    def from_wire(self, tag: int, values: dict) -> np.ndarray:
        if tag == 0:
            return values["pixels"]
        return _decode_png(values["png"], values["width"], values["height"])

    def json(self, image: np.ndarray) -> dict:
        return {"width": image.shape[1], "height": image.shape[0], "mean_rgb": image.reshape(-1, 3).mean(0).tolist()}


@register_message
@dataclass
class PosedFrame(Message):
    """An RGB image taken from a known pose.

    * ``image``: ``[H, W, 3]`` uint8 RGB, at most ``MAX_FRAME_SIDE_PX`` a side and
      ``MAX_FRAME_PIXELS`` in all.
    * ``intrinsics``: pinhole intrinsics in pixels; its size must be the image's.
    * ``cam2world``: ``[4, 4]`` float64, OpenCV camera axes (see :mod:`aes_planner.geometry`).
    * ``depth_m``: optional ``[H, W]`` float32 z-depth in metres; ``0`` marks pixels without a
      measurement (sky, holes). Never NaN or Inf.
    * ``stamp_s``: capture time in seconds (the sensor's clock; sim time in the simulator).
    * ``frame_id``: a name for the frame (file stem, camera name), printable, at most 4096 bytes of UTF-8.
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
    OPTIONS: ClassVar[tuple[str, ...]] = ("image_format",)
    FIELDS = (
        Scalar(
            "stamp_s",
            "f64",
            doc="capture time (when the image was taken: the sensor's clock; sim time in the simulator)",
        ),
        Scalar("sequence", "u64", doc="the camera's frame counter: 1 for its first frame, +1 for each published"),
        Str("frame_id", 4096, doc="a name for this image (`sim_camera/000012`), not a tf frame"),
        Scalar("intrinsics.fx", "f64", doc="pinhole focal length in pixels, > 0"),
        Scalar("intrinsics.fy", "f64", doc="> 0"),
        Scalar(
            "intrinsics.cx",
            "f64",
            doc="principal point in pixels, pixel centres at +0.5; the image size is the image's",
        ),
        Scalar("intrinsics.cy", "f64"),
        Array("cam2world", "f8", (4, 4), exact=True, doc="the camera's pose"),
        Optional(Scalar("pan_rad", "f64", doc="the gimbal's joints at capture, on a rig (both or neither)")),
        Optional(Scalar("tilt_rad", "f64")),
        ImageField(),
        Optional(Array("depth_m", "f4", _SIDE, doc="z-depth in metres, the image's `[H, W]`; `0` = no measurement")),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        f"an image with no rows or columns, more than {MAX_FRAME_SIDE_PX:,} pixels a side or more than "
        f"{MAX_FRAME_PIXELS:,} pixels in all (raw or PNG)",
        "a PNG stream that is not one (no PNG signature, or no IHDR chunk first), whose IHDR size is not "
        "`width` x `height`, or that does not decode",
        "`depth_m` of another size than the image, or with a negative value",
        "`fx` or `fy` <= 0, or giving a field of view (2 atan(W / 2 fx), 2 atan(H / 2 fy)) outside "
        f"{FOV_RANGE_DEG[0]} to {FOV_RANGE_DEG[1]} degrees; `cx` outside [-0.5 W, 1.5 W] or `cy` outside [-0.5 H, 1.5 H]",
        "a `cam2world` that is not rigid (the last row not `0 0 0 1` within 1e-4, the rotation not orthonormal "
        "within 1e-4 or with determinant -1) or places the camera more than "
        f"{MAX_COORDINATE_M:,.0f} m from the world origin along an axis",
        f"`pan_rad` without `tilt_rad` (or the reverse), or a joint beyond 4 pi = {MAX_JOINT_RAD!r} rad (two turns)",
    )
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
        if h < 1 or w < 1 or max(h, w) > MAX_FRAME_SIDE_PX or h * w > MAX_FRAME_PIXELS:
            raise MessageError(
                f"PosedFrame.image is {w}x{h}; images must be non-empty, at most {MAX_FRAME_SIDE_PX} px a side "
                f"and {MAX_FRAME_PIXELS} px in all; downscale it"
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
        self.frame_id = check_text(self.frame_id, "PosedFrame.frame_id", text_cap(self.FIELDS, "frame_id"))
        self.sequence = check_sequence(self.sequence, "PosedFrame.sequence")
        self.pan_rad = check_optional_finite(self.pan_rad, "PosedFrame.pan_rad")
        self.tilt_rad = check_optional_finite(self.tilt_rad, "PosedFrame.tilt_rad")
        if (self.pan_rad is None) != (self.tilt_rad is None):
            raise MessageError("PosedFrame.pan_rad and tilt_rad must be given together (or neither)")
        problem = (  # the dataset importers' bounds: no real camera has these
            intrinsics_problem(self.intrinsics)
            or position_problem(self.cam2world)
            or joint_problem("pan_rad", self.pan_rad)
            or joint_problem("tilt_rad", self.tilt_rad)
        )
        if problem is not None:
            raise MessageError(f"PosedFrame.{problem}")

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def height(self) -> int:
        return self.image.shape[0]

    # -- wire format (FIELDS) -------------------------------------------------------------------

    @classmethod
    def _from_wire(cls, values: dict, version: int) -> PosedFrame:
        image = values["image"]
        h, w = image.shape[:2]
        if h * w > MAX_FRAME_PIXELS:
            raise MessageError(f"PosedFrame.image {w}x{h} exceeds the cap of {MAX_FRAME_PIXELS} pixels")
        k = [values[f"intrinsics.{n}"] for n in ("fx", "fy", "cx", "cy")]
        return cls(
            image=image,
            intrinsics=Intrinsics(*k, w, h),
            cam2world=values["cam2world"],
            stamp_s=values["stamp_s"],
            depth_m=values["depth_m"],
            frame_id=values["frame_id"],
            sequence=values["sequence"],
            pan_rad=values["pan_rad"],
            tilt_rad=values["tilt_rad"],
        )


def _decode_png(png: bytes, width: int, height: int) -> np.ndarray:
    """Decode an RGB PNG whose declared size (checked before decoding: no decompression bombs)
    must be ``width x height``."""
    if len(png) < 24 or png[:8] != _PNG_SIGNATURE or png[12:16] != b"IHDR":
        raise MessageError("PosedFrame.image: not a PNG stream")
    pw, ph = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    if (pw, ph) != (width, height):
        raise MessageError(f"PosedFrame.image: PNG is {pw}x{ph} but the message says {width}x{height}")
    if not (1 <= pw <= MAX_FRAME_SIDE_PX and 1 <= ph <= MAX_FRAME_SIDE_PX) or pw * ph > MAX_FRAME_PIXELS:
        raise MessageError(f"PosedFrame.image: PNG of {pw}x{ph} exceeds the image caps")
    import cv2

    bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None or bgr.shape[:2] != (ph, pw) or bgr.dtype != np.uint8:
        raise MessageError("PosedFrame.image: corrupt PNG data")
    return np.ascontiguousarray(bgr[..., ::-1])
