"""The posed-frame dataset folder: images + one ``cameras.json`` (+ optional depth files).

Layout::

    DIR/
      cameras.json          # intrinsics, cam2world and stamp of every frame (format below)
      images/00000.png      # RGB, any format OpenCV reads (written as PNG)
      depth/00000.npy       # optional z-depth, float32 metres, 0 = no measurement
                            # (16-bit PNG in millimetres is read too: "depth_png_scale_m")

``cameras.json``::

    {"format": "aes-planner/posed-frames", "version": 1,
     "meta": {...free-form, e.g. the scene the frames came from...},
     "frames": [{"image": "images/00000.png", "width": 128, "height": 96,
                 "fx": 110.8, "fy": 110.8, "cx": 64.0, "cy": 48.0,
                 "cam2world": [[r00, r01, r02, tx], [...], [...], [0, 0, 0, 1]],
                 "stamp_s": 0.0, "depth": "depth/00000.npy", "frame_id": "00000",
                 "meta": {...free-form per frame, e.g. joint angles...}}]}

Poses follow :mod:`aes_planner.geometry`: OpenCV camera axes, REP-103 world (z up), metres,
written as float64 with full precision (JSON floats round-trip exactly). Paths are relative to
``DIR``. Reading never executes anything: JSON, images through OpenCV, ``.npy`` with
``allow_pickle=False``.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from aes_planner.config import short_repr
from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError
from aes_planner.geometry.plausible import intrinsics_problem
from aes_planner.geometry.poses import PoseError, validate_cam2world
from aes_planner.images import ImageError, check_image_size, downscale_parts, image_size, imread_bounded
from aes_planner.messages import MessageError, PosedFrame
from aes_planner.paths import OutputPathError, PathOutsideError, output_in, resolve_inside

log = logging.getLogger(__name__)

__all__ = ["DatasetError", "PosedDataset", "save_dataset", "load_dataset", "read_rgb", "read_depth"]

FORMAT = "aes-planner/posed-frames"
VERSION = 1


class DatasetError(AesPlannerError, ValueError):
    """A dataset file is missing, malformed or inconsistent; the message names the field."""


@dataclass
class PosedDataset:
    """Frames read from (or to be written to) a dataset folder."""

    frames: list[PosedFrame]
    meta: dict[str, Any] = field(default_factory=dict)
    root: Path | None = None
    #: ``{(width, height) as stored: frames downscaled from that size}`` by ``load_dataset(max_side_px=)``
    downscaled: dict[tuple[int, int], int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)

    def cam2worlds(self) -> np.ndarray:
        """Poses ``[N, 4, 4]`` float64."""
        return np.stack([f.cam2world for f in self.frames]) if self.frames else np.zeros((0, 4, 4))


#: ``cv2.imread`` flags that decode at 1/2, 1/4 or 1/8 of the stored size (a JPEG is decoded so by
#: libjpeg's DCT scaling, without ever holding the full-size image), largest reduction first.
_REDUCED_COLOR = ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4), (2, cv2.IMREAD_REDUCED_COLOR_2))


def read_rgb(path: Path, key: str, max_side_px: int | None = None) -> np.ndarray:
    """An image file -> ``[H, W, 3]`` uint8 RGB; errors name ``key``.

    ``max_side_px``: decode at the largest of 1/8, 1/4, 1/2 of the stored size that still keeps the
    longer side at least this long (the caller resamples the rest of the way): a 24 MP photo read for
    a 320 px working size never sits in memory whole. Without it, or when no reduction fits, the
    image is decoded at its stored size."""
    if not path.is_file():
        raise DatasetError(f"{key}: image file {path} not found; check the path (relative to the dataset folder)")
    flags = cv2.IMREAD_COLOR
    stored = image_size(path) if max_side_px is not None else None
    if stored is not None:
        flags = next((f for r, f in _REDUCED_COLOR if max(stored) // r >= max_side_px), flags)
    img = imread_bounded(path, flags, key, DatasetError)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _stored_size(path: Path, image: np.ndarray) -> tuple[int, int]:
    """``(width, height)`` of the image file as ``read_rgb`` turned it (upright by its EXIF
    orientation), whatever reduction it was decoded at."""
    w, h = image_size(path) or image.shape[1::-1]
    if w != h and (w > h) != (image.shape[1] > image.shape[0]):  # EXIF said rotate a quarter turn
        w, h = h, w
    return int(w), int(h)


def read_depth(path: Path, key: str, png_scale_m: float = 0.001) -> np.ndarray:
    """A depth file (``.npy`` float metres, or 16-bit PNG scaled by ``png_scale_m``) -> float32 ``[H, W]``."""
    if not path.is_file():
        raise DatasetError(f"{key}: depth file {path} not found")
    if path.suffix == ".npy":
        d = _load_npy(path, key)
    else:
        d = imread_bounded(path, cv2.IMREAD_UNCHANGED, key, DatasetError)
        if d.ndim != 2 or d.dtype != np.uint16:
            raise DatasetError(f"{key}: {path} must be a .npy array or a single-channel 16-bit PNG")
        d = d.astype(np.float32) * np.float32(png_scale_m)
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.number):
        raise DatasetError(f"{key}: depth must be a 2D numeric array, got shape {d.shape} dtype {d.dtype}")
    d = d.astype(np.float32)
    if not np.all(np.isfinite(d)):
        raise DatasetError(f"{key}: depth contains NaN or Inf; mark missing depth with 0")
    return d


def _load_npy(path: Path, key: str) -> np.ndarray:
    """A ``.npy`` array, its header checked first (shape within the image bounds, the data all there),
    so that a header claiming a huge shape never allocates it; never unpickles."""
    try:
        with path.open("rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, _, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise ValueError(f"unknown .npy version {version}")
            data_bytes = path.stat().st_size - f.tell()
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise DatasetError(f"{key}: {path} is not a plain numeric .npy array ({str(exc)[:120]})") from None
    if dtype.hasobject:
        raise DatasetError(f"{key}: {path} is not a plain numeric .npy array (it holds Python objects)")
    if len(shape) != 2 or not (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)):
        raise DatasetError(f"{key}: depth must be a 2D numeric array, got shape {shape} dtype {dtype}")
    try:
        check_image_size(int(shape[1]), int(shape[0]), f"{key}: depth {path}")
    except ImageError as exc:
        raise DatasetError(str(exc)) from None
    if data_bytes < shape[0] * shape[1] * dtype.itemsize:
        raise DatasetError(f"{key}: {path} is truncated ({data_bytes} bytes of data for shape {shape} {dtype})")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DatasetError(f"{key}: {path} is not a plain numeric .npy array ({str(exc)[:120]})") from None


def _writable(root: Path, name: str) -> Path:
    """``root / name`` to write, refused when a symlink (left in the folder) would redirect it."""
    try:
        return output_in(root, name)
    except OutputPathError as exc:
        raise DatasetError(str(exc)) from None


def _write_rgb(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise DatasetError(f"could not write {path}")


def _jsonable(obj: Any, key: str) -> Any:
    """Check that ``obj`` is plain JSON data with finite numbers (numpy scalars/arrays converted)."""
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        raise DatasetError(f"{key}: {obj} is not a finite number; JSON metadata must be finite")
    if isinstance(obj, dict):
        return {str(k): _jsonable(v, f"{key}.{k}") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, f"{key}[{i}]") for i, v in enumerate(obj)]
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise DatasetError(f"{key}: {type(obj).__name__} cannot be stored in cameras.json")


def save_dataset(
    out_dir: str | Path,
    frames: Iterable[PosedFrame],
    meta: dict[str, Any] | None = None,
    frame_meta: list[dict[str, Any]] | None = None,
) -> Path:
    """Write frames as a dataset folder; returns the path of ``cameras.json``.

    ``frame_meta`` (optional, one dict per frame) is stored with each frame. Existing files of
    the same names are overwritten; other files in the folder are left alone.
    """
    root = check_output_folder(out_dir)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"{root}: cannot create the output folder ({exc.strerror or exc}); choose another") from None
    try:
        return _save(root, frames, meta, frame_meta)
    except OSError as exc:
        raise DatasetError(
            f"{root}: writing the dataset failed ({exc.strerror or exc}); check space and permissions"
        ) from None


def check_output_folder(out_dir: str | Path) -> Path:
    """``out_dir`` as a Path if a dataset can be written there: not an existing file, and none of
    the names a dataset writes (``cameras.json``, ``images/``, ``depth/``) a symlink that would send
    the writes elsewhere."""
    if not str(out_dir).strip():
        raise DatasetError("the output folder is an empty path; give a folder name (e.g. --out renders/scene1)")
    root = Path(out_dir)
    if root.exists() and not root.is_dir():
        raise DatasetError(f"{root}: exists and is not a folder; choose a new or existing folder for the output")
    for name in ("cameras.json", "images", "depth", "contact_sheet.png"):
        if (root / name).is_symlink():
            raise DatasetError(f"{root / name}: is a symlink; the output folder must not redirect its writes elsewhere")
    return root


def _save(root: Path, frames, meta, frame_meta) -> Path:
    entries = []
    frames = list(frames)
    if frame_meta is not None and len(frame_meta) != len(frames):
        raise DatasetError(f"frame_meta has {len(frame_meta)} entries for {len(frames)} frames")
    for i, f in enumerate(frames):  # every name checked before the first write
        _writable(root, f"images/{i:05d}.png")
        if f.depth_m is not None:
            _writable(root, f"depth/{i:05d}.npy")
    for i, f in enumerate(frames):
        name = f"{i:05d}"
        k = f.intrinsics
        entry: dict[str, Any] = {
            "image": f"images/{name}.png",
            "width": k.width,
            "height": k.height,
            "fx": k.fx,
            "fy": k.fy,
            "cx": k.cx,
            "cy": k.cy,
            "cam2world": np.asarray(f.cam2world, dtype=np.float64).tolist(),
            "stamp_s": f.stamp_s,
            "frame_id": f.frame_id or name,
        }
        _write_rgb(_writable(root, entry["image"]), f.image)
        if f.depth_m is not None:
            entry["depth"] = f"depth/{name}.npy"
            (root / "depth").mkdir(exist_ok=True)
            np.save(_writable(root, entry["depth"]), f.depth_m.astype(np.float32), allow_pickle=False)
        if frame_meta is not None and frame_meta[i]:
            entry["meta"] = _jsonable(frame_meta[i], f"frames[{i}].meta")
        entries.append(entry)
    doc = {"format": FORMAT, "version": VERSION, "meta": _jsonable(meta or {}, "meta"), "frames": entries}
    path = root / "cameras.json"
    path.write_text(json.dumps(doc, indent=1) + "\n")
    log.info("wrote %d frames to %s", len(entries), root)
    return path


_MISSING = object()


def finite_number(entry: dict, name: str, key: str, default: Any = _MISSING) -> Any:
    """``entry[name]`` as a float; missing -> ``default`` (an error when none is given)."""
    if name not in entry or entry[name] is None:
        if default is _MISSING:
            raise DatasetError(f"{key}.{name}: missing")
        return default
    v = entry[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise DatasetError(f"{key}.{name}: expected a finite number, got {v!r}")
    return float(v)


def pixel_count(entry: dict, name: str, key: str, default: int | None) -> int | None:
    """``entry[name]`` as a whole number of pixels; missing -> ``default``."""
    v = entry.get(name)
    if v is None:
        return default
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v) or v < 1:
        raise DatasetError(f"{key}.{name}: expected a whole number of pixels, got {v!r}")
    return int(v)


#: Largest JSON file read (``cameras.json`` of 100k frames is about 50 MB).
JSON_MAX_BYTES = 256 << 20


def read_json(path: Path, hint: str) -> Any:
    """Parse a JSON file; a missing, huge, malformed or too deeply nested file raises :class:`DatasetError`."""
    if not path.is_file():
        raise DatasetError(f"{path}: not found; {hint}")
    if path.stat().st_size > JSON_MAX_BYTES:
        raise DatasetError(f"{path}: larger than {JSON_MAX_BYTES} bytes; {hint}")
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not valid JSON (not UTF-8 text); {hint}") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise DatasetError(f"{path}: not valid JSON here (nested too deeply)") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise DatasetError(f"{path}: not valid JSON here ({str(exc)[:120]})") from None


def _matrix(value: Any, key: str) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{key}: expected a 4x4 list of numbers") from None
    try:
        return validate_cam2world(m, key)
    except PoseError as exc:
        raise DatasetError(str(exc)) from None


def _inside(root: Path, entry: str, key: str, allow_outside: bool) -> Path:
    try:
        return resolve_inside(root, entry, key, allow_outside)
    except PathOutsideError as exc:
        raise DatasetError(str(exc)) from None


def check_intrinsics(k: Intrinsics, key: str) -> Intrinsics:
    """Refuse intrinsics no real camera has (:func:`aes_planner.geometry.plausible.intrinsics_problem`:
    the same bounds as frames arriving on topics)."""
    problem = intrinsics_problem(k)
    if problem is not None:
        raise DatasetError(f"{key}.{problem}")
    return k


def check_depth_scale(scale: float, key: str) -> None:
    """A depth unit (metres per stored unit) must be a positive, plausible number."""
    if not (1e-9 <= scale <= 1e3):
        raise DatasetError(f"{key}: {scale!r} metres per depth unit; expected a positive scale such as 0.001 (mm)")


def frame_from_parts(
    key: str,
    image: np.ndarray,
    intrinsics: Intrinsics,
    cam2world: np.ndarray,
    stamp_s: float = 0.0,
    depth_m: np.ndarray | None = None,
    frame_id: str = "",
) -> PosedFrame:
    """Build a :class:`PosedFrame`, turning its validation errors into :class:`DatasetError` naming ``key``."""
    try:
        return PosedFrame(image, intrinsics, cam2world, stamp_s, depth_m, frame_id)
    except (MessageError, IntrinsicsError) as exc:
        raise DatasetError(f"{key}: {exc}") from None


def load_dataset(
    path: str | Path, load_depth: bool = True, allow_outside: bool = False, max_side_px: int | None = None
) -> PosedDataset:
    """Read a dataset folder (or its ``cameras.json``) into :class:`PosedFrame` records.

    ``max_side_px``: downscale each frame as it is read to at most this many pixels a side
    (:func:`aes_planner.images.downscale_parts`, intrinsics scaled with it), so that a folder of
    full-resolution photos never sits in memory at full size.

    Image and depth paths must lead to files inside the folder (:func:`aes_planner.paths.resolve_inside`);
    ``allow_outside=True`` lifts that for a ``cameras.json`` you trust."""
    path = Path(path)
    cameras = path / "cameras.json" if path.is_dir() else path
    root = cameras.parent
    doc = read_json(cameras, "a dataset folder holds images and a cameras.json")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DatasetError(
            f"{cameras}: 'format' must be {FORMAT!r}; for nerfstudio or RealEstate10K files use the importers"
        )
    if doc.get("version") != VERSION:
        raise DatasetError(f"{cameras}: version {doc.get('version')!r} is not supported (this package reads {VERSION})")
    entries = doc.get("frames")
    if not isinstance(entries, list):
        raise DatasetError(f"{cameras}: 'frames' must be a list")
    frames = []
    frame_meta = []
    downscaled: dict[tuple[int, int], int] = {}
    for i, e in enumerate(entries):
        key = f"frames[{i}]"
        if not isinstance(e, dict):
            raise DatasetError(f"{key}: expected an object")
        if "image" not in e or not isinstance(e["image"], str):
            raise DatasetError(f"{key}.image: missing (a path relative to {root})")
        image_path = _inside(root, e["image"], f"{key}.image", allow_outside)
        image = read_rgb(image_path, f"{key}.image", max_side_px)
        stored_wh = _stored_size(image_path, image)
        width, height = (pixel_count(e, name, key, size) for name, size in zip(("width", "height"), stored_wh))
        if (width, height) != tuple(stored_wh):
            raise DatasetError(
                f"{key}: width/height say {width}x{height} but {e['image']} is {stored_wh[0]}x{stored_wh[1]}"
            )
        try:
            fx, fy, cx, cy = (finite_number(e, name, key) for name in ("fx", "fy", "cx", "cy"))
            k = check_intrinsics(Intrinsics(fx, fy, cx, cy, width, height), key)
        except IntrinsicsError as exc:
            raise DatasetError(f"{key}.{exc.problem}" if exc.problem else f"{key}: {exc}") from None
        if (image.shape[1], image.shape[0]) != (width, height):  # decoded at 1/2..1/8 of its stored size
            k = k.scaled(image.shape[1], image.shape[0])
        if "cam2world" not in e:
            raise DatasetError(f"{key}.cam2world: missing (a 4x4 camera-to-world matrix, OpenCV axes)")
        c2w = _matrix(e["cam2world"], f"{key}.cam2world")
        stamp = finite_number(e, "stamp_s", key, 0.0)
        depth = None
        if load_depth and e.get("depth"):
            if not isinstance(e["depth"], str):
                raise DatasetError(f"{key}.depth: expected a path relative to {root}, got {short_repr(e['depth'])}")
            scale = finite_number(e, "depth_png_scale_m", key, 0.001)
            check_depth_scale(scale, f"{key}.depth_png_scale_m")
            depth = read_depth(_inside(root, e["depth"], f"{key}.depth", allow_outside), f"{key}.depth", scale)
        if depth is not None and image.shape[:2] != (height, width) and depth.shape == (height, width):
            # the image was decoded reduced: its depth follows it (a depth of another size is refused below)
            depth = cv2.resize(depth, image.shape[1::-1], interpolation=cv2.INTER_NEAREST)
        if max_side_px is not None and max(width, height) > max_side_px:  # a 24 MP photo is over a frame's cap
            downscaled[(width, height)] = downscaled.get((width, height), 0) + 1
            image, depth, k = downscale_parts(image, depth, k, max_side_px)
        frames.append(frame_from_parts(key, image, k, c2w, stamp, depth, str(e.get("frame_id", i))))
        frames[-1].extras["image_name"] = e["image"]  # as cameras.json names it (suggest --keep FRAME:...)
        frames[-1].extras["stored_size"] = (width, height)  # before any downscale: the pixels boxes are given in
        frame_meta.append(e.get("meta", {}))
    for f, m in zip(frames, frame_meta):
        f.extras["meta"] = m
    meta = doc.get("meta", {})
    if not isinstance(meta, dict):
        raise DatasetError(f"{cameras}: 'meta' must be an object")
    return PosedDataset(frames, meta, root, downscaled)
