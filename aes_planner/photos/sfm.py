"""The pose step: a folder of photos -> the package's posed-frame folder, by structure from motion
with pycolmap (COLMAP's own bindings: SIFT features, exhaustive matching, incremental mapping with
bundle adjustment, undistortion). No SfM of our own: this module prepares the inputs, calls
pycolmap's pipeline, and turns its model into our conventions.

Steps (:func:`pose_images`):

1. **Inputs at the boundary**: every file is checked to be an image from its header
   (:func:`aes_planner.images.image_size`) and read bounded; photos larger than
   ``max_side_px`` are downscaled as they are copied into the work folder, so memory stays
   bounded whatever the camera. Photos are grouped by camera: one shared camera when the size and
   the EXIF make, model and focal length agree (one group per camera otherwise). EXIF's 35 mm
   focal length, when there, is the focal length's starting value.
2. **pycolmap**: ``extract_features`` (one camera per group, ``SIMPLE_RADIAL``),
   ``match_exhaustive``, ``incremental_mapping`` (its bundle adjustment refines the focal length
   and the radial distortion); the largest model is kept, the others reported.
3. **Refusals**, each naming what to do: fewer than :data:`MIN_REGISTERED` photos registered;
   views without parallax (taken from one spot, a pan-tilt rig's turns: the matches fit
   homographies, or the registered cameras sit within :data:`MIN_PARALLAX` of the scene's depth);
   files that are not images.
4. **Undistortion** with ``pycolmap.undistort_images`` (pinhole cameras, the images resampled).
5. **Frame**: COLMAP's frame has an arbitrary origin, rotation and scale. It is levelled: world +z
   is the scene's vertical vanishing direction when the photos' straight lines say it confidently
   (:func:`aes_planner.photos.vertical.vertical_from_lines`: right whatever way the camera was
   held), else the cameras' up (:func:`gravity_up`: perpendicular to their right axes, right for
   photos held level; their mean up where they all face one way); the outputs say which. Its
   origin is put at the first registered photo's camera and its x
   axis along that photo's levelled viewing direction (REP-103: x forward, y left, z up). Scale:
   metres from ``scale_from`` (two photos and the distance between their cameras) or from a
   calibration board seen in two or more photos (``board``); otherwise the unit is the distance
   between the first two registered photos' cameras, and every output says so.
6. **Outputs**: the posed-frame folder (:mod:`aes_planner.dataset.folder`: ``images/``,
   ``cameras.json`` whose meta carries the unit, the photos' names and the hand-held platform) and a
   nerfstudio ``transforms.json`` beside it (OpenGL camera axes, the same images and poses:
   :func:`aes_planner.dataset.import_nerfstudio` reads it back into the same frames).
"""

from __future__ import annotations

import hashlib
import logging
import math
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from aes_planner.calibrate.board import BoardSpec, detect
from aes_planner.config import require
from aes_planner.dataset import save_dataset
from aes_planner.dataset.exporters import write_nerfstudio
from aes_planner.dataset.folder import check_output_folder, frame_from_parts
from aes_planner.dataset.importers import rotation_to_z
from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import Intrinsics
from aes_planner.images import ImageError, image_size, imread_bounded
from aes_planner.photos.exif import CameraTags, read_camera_tags
from aes_planner.photos.vertical import VerticalLines, vertical_from_lines
from aes_planner.platform import HandHeldPlatform

log = logging.getLogger(__name__)

__all__ = ["MIN_REGISTERED", "PoseConfig", "PoseError", "PoseResult", "pose_images", "list_images"]

#: Fewest photos that must register for a posed folder to be written.
MIN_REGISTERED = 3
#: The registered cameras' spread over the scene's median depth below which the views count as
#: taken from one spot (no parallax: depth and pose are not determined).
MIN_PARALLAX = 0.02
#: ... and this, when most photo pairs were explained by a rotation (see :func:`_check_parallax`).
PANORAMIC_PARALLAX = 0.2
#: Fewest photos the pose step takes, and most (exhaustive matching grows with their square).
MIN_IMAGES, MAX_IMAGES = 3, 500
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp", ".pgm", ".ppm", ".pnm")


def import_pycolmap():
    """pycolmap, imported where used (``import aes_planner`` works without it), always after OpenCV:
    pycolmap's wheel bundles its own zlib, and OpenCV loaded after it writes PNGs through that
    zlib's symbols and crashes ("double free" in ``deflateEnd``: measured with pycolmap 4.2.1 and
    opencv-contrib-python-headless 5.0). This module imports cv2 at its top, so here it is loaded."""
    assert "cv2" in sys.modules
    import pycolmap

    return pycolmap


class PoseError(AesPlannerError, ValueError):
    """Photos that cannot be posed (too few registered, no parallax, not images...)."""


@dataclass(frozen=True)
class PoseConfig:
    """Settings of :func:`pose_images`.

    * ``max_side_px``: photos are downscaled to this on the way in (SIFT at 1024 px is plenty for
      the field, which works at 320 px; a 24 MP photo would cost 30x the memory and time).
    * ``scale_from``: ``(photo_a, photo_b, metres)``: the distance between two photos' cameras.
    * ``board``: a calibration board seen in two or more photos gives metres instead.
    * ``margin_m``: the hand-held search region's margin around the registered cameras, in the
      written frame's unit; ``None``: a quarter of the cameras' spread.
    * ``max_features``: SIFT features kept per photo (COLMAP's default is 8192 for photos up to 3200
      px; at 1024 px 4096 register as well and match four times faster).
    * ``threads``: pycolmap's threads (-1: all cores).
    """

    max_side_px: int = 1024
    scale_from: tuple[str, str, float] | None = None
    board: BoardSpec | None = None
    margin_m: float | None = None
    max_features: int = 4096
    threads: int = -1
    seed: int = 0

    def __post_init__(self):
        require(
            isinstance(self.max_side_px, int) and 160 <= self.max_side_px <= 8192,
            "max_side_px",
            f"must be an integer in [160, 8192] pixels, got {self.max_side_px!r}",
        )
        if self.scale_from is not None:
            require(
                len(self.scale_from) == 3 and math.isfinite(self.scale_from[2]) and self.scale_from[2] > 0,
                "scale_from",
                f"must be (photo_a, photo_b, metres > 0), got {self.scale_from!r}",
            )
            require(self.scale_from[0] != self.scale_from[1], "scale_from", "needs two different photos")
        require(self.scale_from is None or self.board is None, "scale_from", "give scale_from or board, not both")
        if self.margin_m is not None:
            require(
                math.isfinite(self.margin_m) and self.margin_m > 0, "margin_m", f"must be > 0, got {self.margin_m!r}"
            )
        require(
            isinstance(self.max_features, int) and 256 <= self.max_features <= 65536,
            "max_features",
            f"must be an integer in [256, 65536], got {self.max_features!r}",
        )
        require(isinstance(self.threads, int) and (self.threads == -1 or self.threads >= 1), "threads", "-1 or >= 1")


@dataclass
class PoseResult:
    """What :func:`pose_images` did: photos registered of total, their poses (written frame),
    the mean reprojection error, the unit, the time, and the folders written."""

    registered: list[str]  # photo names, in the written folder's order
    unregistered: list[str]
    total: int
    cam2world: np.ndarray  # [R, 4, 4] written frame
    intrinsics: list[Intrinsics]
    mean_reprojection_px: float
    unit: str  # "m", or what the unit is
    metric: bool
    scale_source: str
    time_s: float
    out_dir: Path
    cameras: int  # cameras estimated (groups of photos sharing one)
    other_models: list[int] = field(default_factory=list)  # sizes of the models left out
    timings_s: dict[str, float] = field(default_factory=dict)
    margin: float = 0.0
    distortion: str = ""
    gravity: str = ""  # where the frame's up came from, in words
    vertical: VerticalLines | None = None  # what the scene's vertical lines said

    def to_json(self) -> dict:
        return {
            "registered": len(self.registered),
            "total": self.total,
            "registered_photos": list(self.registered),
            "unregistered_photos": list(self.unregistered),
            "mean_reprojection_error_px": self.mean_reprojection_px,
            "unit": self.unit,
            "metric": self.metric,
            "scale_source": self.scale_source,
            "cameras": self.cameras,
            "distortion": self.distortion,
            "gravity": self.gravity,
            "gravity_source": "vertical lines" if self.vertical is not None and self.vertical.confident else "cameras",
            "vertical_lines": self.vertical.to_json() if self.vertical is not None else None,
            "other_models": list(self.other_models),
            "time_s": self.time_s,
            "timings_s": dict(self.timings_s),
            "posed_folder": str(self.out_dir),
            "cameras_json": str(self.out_dir / "cameras.json"),
            "transforms_json": str(self.out_dir / "transforms.json"),
            "search_margin": self.margin,
            "cam2world": {n: m.tolist() for n, m in zip(self.registered, self.cam2world)},
        }


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def list_images(images: str | Path | Sequence[str | Path]) -> list[Path]:
    """The photo files of a folder (its image-named files, natural order) or of a list of files.
    Refused: a missing path, a folder without images, a file that is not an image, fewer than
    :data:`MIN_IMAGES` or more than :data:`MAX_IMAGES` photos."""
    if isinstance(images, (str, Path)):
        root = Path(images)
        if not root.exists():
            raise PoseError(f"{root}: no such folder or file; give a folder of photos (or the photo files)")
        if root.is_dir():
            files = sorted(
                (p for p in root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                key=lambda p: _natural_key(p.name),
            )
            if not files:
                raise PoseError(
                    f"{root}: no image files (looked for {', '.join(IMAGE_SUFFIXES)}); give the folder of photos"
                )
        else:
            files = [root]
    else:
        files = [Path(p) for p in images]
    for p in files:
        if not p.is_file():
            raise PoseError(f"{p}: not found; give existing photo files")
        if image_size(p) is None:
            raise PoseError(
                f"{p}: not an image (PNG, JPEG, BMP, TIFF, WebP or PNM with an intact header); "
                "leave only photos in the folder"
            )
    names = [p.name for p in files]
    if len(set(names)) != len(names):
        raise PoseError("two photos share a file name; give photos with distinct names")
    if len(files) < MIN_IMAGES:
        raise PoseError(
            f"{len(files)} photo(s); the pose step needs at least {MIN_IMAGES} overlapping photos taken from "
            "different places (walk around the subject)"
        )
    if len(files) > MAX_IMAGES:
        raise PoseError(f"{len(files)} photos; at most {MAX_IMAGES} are matched exhaustively here: pick fewer")
    return files


@dataclass
class _Photo:
    path: Path
    name: str
    work_name: str  # file name in the work folder: group/index.png
    size: tuple[int, int]  # as stored in the work folder
    tags: CameraTags
    group: int = 0


def _prepare(files: list[Path], work: Path, max_side_px: int) -> tuple[list[_Photo], list[list[int]]]:
    """Copy the photos into ``work/input/gGG/`` (downscaled to ``max_side_px``), grouped by camera."""
    photos = []
    keys: dict[tuple, int] = {}
    groups: list[list[int]] = []
    seen: dict[str, str] = {}  # pixel digest -> photo name
    for i, p in enumerate(files):
        try:
            bgr = imread_bounded(p, cv2.IMREAD_COLOR, str(p), PoseError)
        except ImageError as exc:
            raise PoseError(str(exc)) from None
        digest = hashlib.sha1(bgr.tobytes()).hexdigest()
        if digest in seen:
            raise PoseError(
                f"{p.name} and {seen[digest]} are the same photo (identical pixels); structure from motion needs "
                "photos taken from different places: remove the copies"
            )
        seen[digest] = p.name
        h, w = bgr.shape[:2]
        tags = read_camera_tags(p)
        key = (w, h, tags.make, tags.model, tags.focal_mm)  # one camera: same size, same EXIF camera
        if key not in keys:
            keys[key] = len(groups)
            groups.append([])
        g = keys[key]
        groups[g].append(i)
        if max(h, w) > max_side_px:
            s = max_side_px / max(h, w)
            bgr = cv2.resize(bgr, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
        work_name = f"g{g:02d}/{i:05d}.png"
        (work / "input" / f"g{g:02d}").mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(work / "input" / work_name), bgr):
            raise PoseError(f"could not write the working copy of {p} under {work}; check the disk")
        photos.append(_Photo(p, p.name, work_name, (bgr.shape[1], bgr.shape[0]), tags, g))
        del bgr
    return photos, groups


def _reader_options(pycolmap, photo: _Photo):
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_RADIAL"
    if photo.tags.focal_35mm:  # EXIF's 35 mm equivalent: f_px = f35 / 36 mm x the longer side
        w, h = photo.size
        f = photo.tags.focal_35mm / 36.0 * max(w, h)
        reader.camera_params = f"{f:.3f},{w / 2:.3f},{h / 2:.3f},0"
    return reader


def _panoramic_share(pycolmap, db_path: Path) -> tuple[float, int]:
    """The share of verified photo pairs whose matches COLMAP explained by a rotation (or a plane
    it cannot tell from one), and how many pairs were verified."""
    db = pycolmap.Database.open(str(db_path))
    try:
        _, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    cfg = pycolmap.TwoViewGeometryConfiguration
    verified = [g for g in geometries if g.config not in (cfg.UNDEFINED, cfg.DEGENERATE) and len(g.inlier_matches)]
    if not verified:
        return 0.0, 0
    flat = sum(g.config in (cfg.PANORAMIC, cfg.PLANAR_OR_PANORAMIC) for g in verified)
    return flat / len(verified), len(verified)


def _no_parallax_error(n: int) -> PoseError:
    return PoseError(
        f"the {n} photos show no parallax: they were taken from one spot (turning in place, as a pan-tilt rig "
        "does), so structure from motion cannot find depth or poses; walk around the subject between photos, "
        "or for a rig's images use the rig's kinematics (`aes-planner sim render` / the rig's posed frames)"
    )


def _too_few_error(registered: int, total: int, names: list[str]) -> PoseError:
    left = ", ".join(names[:5]) + (" ..." if len(names) > 5 else "")
    return PoseError(
        f"only {registered} of {total} photos registered (at least {MIN_REGISTERED} must): the photos overlap too "
        f"little or look alike; take more photos of the same subject, each sharing most of the view with the "
        f"previous one, from places a step or two apart (not registered: {left})"
    )


def gravity_up(c2w: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [3] unit
    """The world's up direction from cameras held level (no roll), as nerfstudio's ``vertical``
    orientation does: the direction most nearly perpendicular to every camera's right axis (the
    smallest right singular vector of the right axes), signed by the cameras' mean up. When the
    cameras all face one way (their right axes span too little to fix it), the mean up with its
    component along their common right axis removed. The mean up alone leans with the cameras'
    common pitch (photos looking down at a subject: 15 deg off for a 15 deg downward look)."""
    right = c2w[:, :3, 0]  # [N, 3]
    mean_up = -c2w[:, :3, 1].mean(0)
    _, sing, vt = np.linalg.svd(right, full_matrices=False)
    if sing[1] > 0.17 * math.sqrt(len(right)):  # right axes spread over a plane: its normal is up
        up = vt[2] if vt[2] @ mean_up > 0 else -vt[2]
    else:
        up = mean_up - vt[0] * (vt[0] @ mean_up)
    return up / np.linalg.norm(up)


def level_up(
    images: Sequence[np.ndarray], ks: Sequence[Intrinsics], c2w: np.ndarray
) -> tuple[np.ndarray, str, VerticalLines]:  # -> up [3], where it came from, the lines' say
    """The world's up for photos ``images`` posed ``c2w [N, 4, 4]``: the scene's vertical vanishing
    direction when the lines say it confidently, else :func:`gravity_up` (the cameras' up)."""
    cameras = gravity_up(c2w)
    lines = vertical_from_lines(images, ks, c2w, cameras)
    if lines.confident:
        return lines.up, f"the scene's vertical lines ({lines.text()})", lines
    return cameras, f"the cameras' up (the scene's vertical lines were not conclusive: {lines.text()})", lines


def _leveller(c2w: np.ndarray, up_dir: np.ndarray) -> np.ndarray:  # [N, 4, 4], [3] -> [4, 4] world transform
    """Level (``up_dir`` -> +z), origin at the first camera, x along its levelled view."""
    up = rotation_to_z(up_dir)  # [4, 4] rotation
    levelled = up @ c2w[0]
    fwd = levelled[:3, 2].copy()
    fwd[2] = 0.0
    yaw = math.atan2(fwd[1], fwd[0]) if np.linalg.norm(fwd) > 1e-9 else 0.0
    c, s = math.cos(-yaw), math.sin(-yaw)
    turn = np.eye(4)
    turn[:2, :2] = [[c, -s], [s, c]]
    out = turn @ up
    out[:3, 3] = -(out[:3, :3] @ c2w[0][:3, 3])
    return out


def _board_scale(
    board: BoardSpec, images: list[np.ndarray], ks: list[Intrinsics], c2w: np.ndarray, names: list[str]
) -> float:
    """Metres per unit of ``c2w``'s frame from a board seen in two or more (undistorted) photos:
    each view's camera centre in the board's frame (``solvePnP``, metres) against the same cameras'
    centres in the SfM frame; the median ratio of their distances apart."""
    centres, which = [], []
    for i, (rgb, k) in enumerate(zip(images, ks)):
        found = detect(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), board)
        if found is None:
            continue
        kk = k.K.copy()
        kk[0, 2] -= 0.5  # the board's corners are in OpenCV's pixel convention (centres at integers)
        kk[1, 2] -= 0.5
        ok, rvec, tvec = cv2.solvePnP(found.object_points, found.image_points, kk, None)
        if not ok:
            continue
        r, _ = cv2.Rodrigues(rvec)
        centres.append((-r.T @ tvec).ravel())
        which.append(i)
    if len(which) < 2:
        raise PoseError(
            f"the board {board} was found in {len(which)} photo(s); metric scale needs it wholly in view in two or "
            "more (or give --scale-from PHOTO_A,PHOTO_B,METRES)"
        )
    ratios = []
    for a in range(len(which)):
        for b in range(a + 1, len(which)):
            d_sfm = np.linalg.norm(c2w[which[a], :3, 3] - c2w[which[b], :3, 3])
            d_m = np.linalg.norm(centres[a] - centres[b])
            if d_sfm > 1e-9 and d_m > 1e-3:
                ratios.append(d_m / d_sfm)
    if not ratios:
        raise PoseError(
            f"the photos that show the board {board} were taken from one spot; the scale needs the board seen "
            "from two places"
        )
    log.info("board %s seen in %s", board, ", ".join(names[i] for i in which))
    return float(np.median(ratios))


def pose_images(
    images: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    cfg: PoseConfig | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    work_dir: str | Path | None = None,
) -> PoseResult:
    """Pose the photos ``images`` (a folder or files) and write the posed-frame folder ``out_dir``
    (see the module docstring). ``progress(stage, done, total)`` is called as the work goes (a
    progress bar's hook). ``work_dir``: where pycolmap's database and models go (a temporary folder,
    removed after, by default)."""
    cfg = cfg or PoseConfig()
    pycolmap = import_pycolmap()  # COLMAP's bindings: only the pose step needs them

    t_start = time.perf_counter()
    report = progress or (lambda stage, done, total: None)
    files = list_images(images)
    root = check_output_folder(out_dir)
    if cfg.scale_from is not None:
        names = {p.name for p in files}
        for name in cfg.scale_from[:2]:
            if name not in names:
                raise PoseError(f"--scale-from: no photo named {name!r} among the inputs; give two of their file names")
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="aes-planner-pose-")
        work = Path(tmp.name)
    else:
        work = Path(work_dir)
        work.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    try:
        pycolmap.logging.minloglevel = 2  # COLMAP's own INFO lines would drown the progress bar
        t0 = time.perf_counter()
        report("reading photos", 0, len(files))
        photos, groups = _prepare(files, work, cfg.max_side_px)
        timings["read"] = time.perf_counter() - t0
        db_path = work / "database.db"
        if db_path.exists():
            db_path.unlink()
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = cfg.threads
        extraction.use_gpu = False
        extraction.sift.max_num_features = cfg.max_features
        t0 = time.perf_counter()
        for g, members in enumerate(groups):  # one camera per group: the photos say one camera took them
            report("features", sum(len(m) for m in groups[:g]), len(files))
            pycolmap.extract_features(
                db_path,
                work / "input",
                image_names=[photos[i].work_name for i in members],
                camera_mode=pycolmap.CameraMode.SINGLE,
                reader_options=_reader_options(pycolmap, photos[members[0]]),
                extraction_options=extraction,
                device=pycolmap.Device.cpu,
            )
        timings["features"] = time.perf_counter() - t0
        report("matching", 0, len(files))
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = cfg.threads
        matching.use_gpu = False
        t0 = time.perf_counter()
        pycolmap.match_exhaustive(db_path, matching_options=matching, device=pycolmap.Device.cpu)
        timings["matching"] = time.perf_counter() - t0
        flat_share, verified = _panoramic_share(pycolmap, db_path)
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = cfg.threads
        options.random_seed = cfg.seed
        options.extract_colors = False
        registered_count = [0]

        def next_image():
            registered_count[0] += 1
            report("mapping", min(registered_count[0], len(files)), len(files))

        (work / "sparse").mkdir(exist_ok=True)
        t0 = time.perf_counter()
        report("mapping", 0, len(files))
        models = pycolmap.incremental_mapping(
            db_path, work / "input", work / "sparse", options=options, next_image_callback=next_image
        )
        timings["mapping"] = time.perf_counter() - t0
        if not models:
            if verified and flat_share > 0.5:
                raise _no_parallax_error(len(files))
            raise _too_few_error(0, len(files), [p.name for p in photos])
        ordered = sorted(models.items(), key=lambda kv: -kv[1].num_reg_images())
        model_id, rec = ordered[0]
        distortion = "estimated (SIMPLE_RADIAL k)"
        if any(
            cam.has_bogus_params(
                options.min_focal_length_ratio, options.max_focal_length_ratio, options.max_extra_param
            )
            for cam in rec.cameras.values()
        ):  # the photos did not pin the distortion down (it traded against the focal length): map again without it
            log.warning("the distortion came out implausible (%s); mapping again with none", _camera_text(rec))
            options.ba_refine_extra_params = False
            (work / "sparse_pinhole").mkdir(exist_ok=True)
            t0 = time.perf_counter()
            again = pycolmap.incremental_mapping(db_path, work / "input", work / "sparse_pinhole", options=options)
            timings["mapping"] += time.perf_counter() - t0
            if again:
                best = max(again.items(), key=lambda kv: kv[1].num_reg_images())
                if best[1].num_reg_images() >= rec.num_reg_images():
                    ordered = sorted(again.items(), key=lambda kv: -kv[1].num_reg_images())
                    model_id, rec = best
                    (work / "sparse").rename(work / "sparse_bogus")
                    (work / "sparse_pinhole").rename(work / "sparse")
                    distortion = "not determined by these photos: none assumed"
        others = [m.num_reg_images() for _, m in ordered[1:]]
        by_work = {p.work_name: p for p in photos}
        reg_ids = sorted(rec.reg_image_ids(), key=lambda i: files.index(by_work[rec.images[i].name].path))
        reg_names = [by_work[rec.images[i].name].name for i in reg_ids]
        missing = [p.name for p in photos if p.name not in set(reg_names)]
        if len(reg_ids) < MIN_REGISTERED:
            if flat_share > 0.5:
                raise _no_parallax_error(len(files))
            raise _too_few_error(len(reg_ids), len(files), missing)
        _check_parallax(rec, reg_ids, len(files), flat_share)
        mean_err = float(rec.compute_mean_reprojection_error())

        # ---- undistortion (pycolmap's), then our frame
        t0 = time.perf_counter()
        report("undistorting", 0, len(reg_ids))
        und = work / "undistorted"
        if und.exists():
            shutil.rmtree(und)
        pycolmap.undistort_images(
            und, work / "sparse" / str(model_id), work / "input", num_threads=cfg.threads, output_type="COLMAP"
        )
        rec_u = pycolmap.Reconstruction(str(und / "sparse"))
        frames_rgb, ks, c2w_sfm = [], [], []
        for i in reg_ids:
            name = rec.images[i].name
            im = rec_u.find_image_with_name(name)
            cam = rec_u.cameras[im.camera_id]
            fx, fy, cx, cy = (float(v) for v in cam.params[:4]) if cam.model_name == "PINHOLE" else (0, 0, 0, 0)
            if cam.model_name != "PINHOLE":
                raise PoseError(f"pycolmap undistorted {name} to a {cam.model_name} camera, not a pinhole one")
            bgr = imread_bounded(und / "images" / name, cv2.IMREAD_COLOR, name, PoseError)
            frames_rgb.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            ks.append(Intrinsics(fx, fy, cx, cy, int(cam.width), int(cam.height)))
            w2c = np.vstack([im.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]])
            c2w_sfm.append(np.linalg.inv(w2c))
            report("undistorting", len(frames_rgb), len(reg_ids))
        timings["undistort"] = time.perf_counter() - t0
        c2w = np.stack(c2w_sfm)  # [R, 4, 4] COLMAP's frame, OpenCV camera axes
        up_dir, gravity, vertical = level_up(frames_rgb, ks, c2w)
        log.info("up: %s", gravity)
        world = _leveller(c2w, up_dir)
        c2w = np.einsum("ij,njk->nik", world, c2w)

        # ---- scale
        if cfg.scale_from is not None:
            a, b, metres = cfg.scale_from
            for name in (a, b):
                if name not in reg_names:
                    raise PoseError(f"--scale-from: {name} did not register; pick two registered photos")
            d = np.linalg.norm(c2w[reg_names.index(a), :3, 3] - c2w[reg_names.index(b), :3, 3])
            if d < 1e-9:
                raise PoseError(f"--scale-from: {a} and {b} were taken from one spot; pick two photos a step apart")
            scale, unit, source, metric = metres / d, "m", f"--scale-from {a},{b},{metres:g}", True
        elif cfg.board is not None:
            scale = _board_scale(cfg.board, frames_rgb, ks, c2w, reg_names)
            unit, source, metric = "m", f"board {cfg.board}", True
        else:
            d = np.linalg.norm(c2w[0, :3, 3] - c2w[1, :3, 3])
            scale, metric = 1.0 / d, False
            unit = f"the distance between the cameras of {reg_names[0]} and {reg_names[1]} (no metric scale given)"
            source = "none"
        c2w[:, :3, 3] *= scale

        # ---- outputs
        frames = [
            frame_from_parts(f"photo {n}", img, k, m, float(j), None, n)
            for j, (n, img, k, m) in enumerate(zip(reg_names, frames_rgb, ks, c2w))
        ]
        platform = HandHeldPlatform.around_photos(ks[0], c2w, cfg.margin_m)
        margin = platform.margin_m
        meta = {
            "source": "aes-planner pose",
            "unit": unit,
            "metric": metric,
            "scale_source": source,
            "photos": reg_names,
            "unregistered": missing,
            "mean_reprojection_error_px": mean_err,
            "distortion": distortion,
            "gravity": gravity,
            "frame": (
                f"levelled (z up: {gravity}), origin at {reg_names[0]}'s camera, "
                f"x along its levelled view; lengths in {'metres' if metric else unit}"
            ),
            **platform.to_meta(),
        }
        save_dataset(root, frames, meta=meta, frame_meta=[{"photo": n} for n in reg_names])
        write_nerfstudio(root, frames, meta={"unit": unit, "metric": metric, "source": "aes-planner pose"})
        del frames_rgb
    finally:
        if tmp is not None:
            tmp.cleanup()
    total_s = time.perf_counter() - t_start
    return PoseResult(
        registered=reg_names,
        unregistered=missing,
        total=len(files),
        cam2world=c2w,
        intrinsics=ks,
        mean_reprojection_px=mean_err,
        unit=unit,
        metric=metric,
        scale_source=source,
        time_s=total_s,
        out_dir=root,
        cameras=len(groups),
        other_models=others,
        timings_s=timings,
        margin=margin,
        distortion=distortion,
        gravity=gravity,
        vertical=vertical,
    )


def _camera_text(rec) -> str:
    return "; ".join(f"{c.model_name} {', '.join(f'{v:.4g}' for v in c.params)}" for c in rec.cameras.values())


def _check_parallax(rec, reg_ids: list[int], total: int, flat_share: float = 0.0) -> None:
    """Refuse a model whose cameras sit within :data:`MIN_PARALLAX` of the scene's median depth of
    one another (turning on one spot: depths and poses are not determined), or within
    :data:`PANORAMIC_PARALLAX` of it when most photo pairs were explained by a rotation
    (``flat_share`` > 0.5): COLMAP can still build a model from a turn in place, its cameras spread
    by noise (4 of 6 photos of a 50 deg turn, 0.04 of the depth apart; a walked arc: 1.2, 7 % of its
    pairs rotation-like)."""
    centres = np.stack([rec.images[i].projection_center() for i in reg_ids])  # [R, 3]
    spread = float(np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)))
    pts = np.array([p.xyz for p in rec.points3D.values()]) if rec.num_points3D() else np.zeros((0, 3))
    if not len(pts):
        raise _no_parallax_error(total)
    depth = float(np.median(np.linalg.norm(pts[:, None] - centres[None], axis=-1)))
    if depth <= 0 or spread / depth < (PANORAMIC_PARALLAX if flat_share > 0.5 else MIN_PARALLAX):
        raise _no_parallax_error(total)
