"""``aes-planner calibrate board|camera|rig|verify``: bring up a real rig (or a simulated one).

* ``board``: a printable board (PNG with its print resolution, or SVG), sizes printed.
* ``camera``: intrinsics from board images (or live from ``--device``), ROS camera_info YAML out.
* ``rig``: the pan-tilt's kinematics from its own sweep (sim ``--scene`` or ``--launch`` hardware),
  optionally the camera's latency; writes a rig YAML of ``PanTiltConfig`` fields.
* ``verify``: re-projects the board from new joint poses with a calibrated rig.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path

from aes_planner.cli import drives_servos
from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)


class CalibrateUsageError(AesPlannerError, ValueError):
    """Flags of ``calibrate`` that do not go together."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate a rig: print a board, camera intrinsics, the pan-tilt's kinematics and latency, verify",
        description="Bring-up of a real (or simulated) rig, one command per step; README, 'Calibrating a real rig'.",
    )
    csub = p.add_subparsers(dest="calibrate_command", metavar="STEP", required=True)
    board_help = "chessboard:COLSxROWS:SQUARE_M (inner corners) or charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT (squares)"

    b = csub.add_parser("board", help="render a board to print", description="Write a board to print at 100 %% scale.")
    b.add_argument("--board", required=True, help=board_help)
    b.add_argument("--out", required=True, metavar="FILE", help=".png (with its dots per inch) or .svg (chessboards)")
    b.add_argument("--px-per-square", type=int, default=200, help="PNG pixels per square (default 200)")
    b.add_argument("--margin-squares", type=int, default=1, help="white squares of margin on every side (default 1)")
    b.set_defaults(func=run_board)

    c = csub.add_parser(
        "camera",
        help="camera intrinsics from board images (ROS camera_info YAML)",
        description="OpenCV's calibration (sub-pixel corners, plumb_bob) of the images, or of raw frames taken live "
        "with --device or from the camera node of --launch (its camera: {type: ...}, built as the node builds it); "
        "writes the ROS camera_info YAML the camera node reads.",
    )
    c.add_argument("images", nargs="*", metavar="IMAGE", help="board images (PNG, JPEG, ...)")
    c.add_argument("--board", required=True, help=board_help)
    c.add_argument("--out", required=True, metavar="YAML", help="camera_info YAML to write")
    c.add_argument("--json", metavar="REPORT", help="write the report (fx, fy, cx, cy, distortion, rms_px, views)")
    c.add_argument("--camera-name", default="camera", help="camera_name in the YAML (default camera)")
    c.add_argument(
        "--device", metavar="N", help="capture live from this camera index or path instead (an opencv_camera)"
    )
    c.add_argument(
        "--launch",
        metavar="LAUNCH",
        help="capture live from the camera node of this launch file instead (any camera type giving raw frames)",
    )
    c.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="--launch override (as `launch --set`)"
    )
    c.add_argument("--frames", type=int, default=20, help="live: views to accept (default 20)")
    c.add_argument("--save-dir", metavar="DIR", help="live: keep the accepted frames here")
    c.set_defaults(func=run_camera)

    r = csub.add_parser(
        "rig",
        help="the pan-tilt's kinematics (and --latency) from its own sweep",
        description="Find the board with a coarse sweep, capture planned joint poses at rest, and estimate the tilt "
        "offset, lever arm and camera mount rotation by least squares on the reprojection error.",
    )
    _source_args(r, board_help)
    r.add_argument("--out", required=True, metavar="RIG_YAML", help="calibrated rig (PanTiltConfig fields)")
    r.add_argument("--views", type=int, default=40, help="planned views (default 40)")
    r.add_argument("--latency", action="store_true", help="also estimate camera_latency_s from a continuous sweep")
    r.add_argument(
        "--zero-offsets",
        choices=["mount", "joints"],
        default="mount",
        help="mount (default): the rig file is for the driver as it is; joints: move the camera's pitch into the "
        "driver's tilt_zero_offset_ticks (printed) and write the rig for the re-zeroed driver",
    )
    r.set_defaults(func=run_rig)

    v = csub.add_parser(
        "verify",
        help="re-project the board from new joint poses with a calibrated rig",
        description="Capture new joint poses, fit only the board's pose on half of them, and report the reprojection "
        "error on the other half with the rig held fixed.",
    )
    _source_args(v, board_help)
    v.add_argument("--views", type=int, default=12, help="verification views (default 12)")
    v.set_defaults(func=run_verify)


def _source_args(p: argparse.ArgumentParser, board_help: str) -> None:
    p.add_argument("--board", required=True, help=board_help)
    p.add_argument(
        "--rig",
        required=True,
        metavar="RIG_YAML",
        help="the rig (PanTiltConfig fields): nominal drawing for rig, calibrated for verify",
    )
    p.add_argument("--json", metavar="REPORT", help="write the report as JSON")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--scene", metavar="FILE", help="simulator: the scene's own rig renders the views")
    where.add_argument(
        "--launch", metavar="LAUNCH", help="hardware: the gimbal and camera of this launch file (pan_tilt_rig)"
    )
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="launch override (as `launch --set`)"
    )
    p.add_argument(
        "--camera-info",
        metavar="YAML",
        help="intrinsics (default: the launch's camera calibration; the scene's camera)",
    )
    p.add_argument(
        "--supersample",
        type=int,
        help="sim: anti-aliasing samples per pixel side (default 2 up to 640x540 images, else 1)",
    )
    p.add_argument("--pixel-noise", type=float, default=0.0, help="sim: image noise sigma, 8-bit levels")
    p.add_argument("--joint-noise-deg", type=float, default=0.0, help="sim: noise of the reported joint angles")
    p.add_argument("--sim-latency", type=float, default=0.0, metavar="S", help="sim: the camera's simulated latency")
    p.add_argument(
        "--allow-outside-paths",
        action="store_true",
        help="sim: let the scene file's image paths leave its folder (absolute, '..', symlinks); only for files you trust",
    )
    p.add_argument("--settle-s", type=float, default=0.5, help="hardware: wait after arrival before a capture")
    p.add_argument("--seed", type=int, default=0, help="sim noise seed")


#: Bounds of the numeric flags, checked before any work: (flag, attribute, low, high).
NUMBER_FLAGS = (
    ("--pixel-noise", "pixel_noise", 0.0, 255.0),
    ("--joint-noise-deg", "joint_noise_deg", 0.0, 10.0),
    ("--sim-latency", "sim_latency", 0.0, 5.0),
    ("--settle-s", "settle_s", 0.0, 60.0),
    ("--supersample", "supersample", 1, 8),
    ("--seed", "seed", 0, 2**32 - 1),
    ("--margin-squares", "margin_squares", 0, 5),
    ("--px-per-square", "px_per_square", 8, 1000),
    ("--frames", "frames", 3, 500),
)


def _check_flags(args) -> None:
    """Every numeric flag of the step within its bounds (a NaN, a 1e9 noise, a seed of 2**70 or
    -1, --supersample 0): refused at once, before minutes of work, naming the flag."""
    for flag, name, lo, hi in NUMBER_FLAGS:
        v = getattr(args, name, None)
        if v is None:
            continue
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
            raise CalibrateUsageError(f"{flag} must be within [{lo:g}, {hi:g}], got {v}")


def _check_outputs(args, flags: tuple[str, ...]) -> None:
    """The output files (``--out``, ``--json``) writable and not symlinks, before any work."""
    from aes_planner.paths import output_file

    for flag in flags:
        value = getattr(args, flag.lstrip("-").replace("-", "_"), None)
        if value is not None:
            output_file(value, flag)


# ---------------------------------------------------------------------------------- board
def run_board(args) -> int:
    from aes_planner.calibrate.board import parse_board, write_board

    _check_flags(args)
    _check_outputs(args, ("--out",))
    spec = parse_board(args.board)
    info = write_board(spec, args.out, args.px_per_square, args.margin_squares)
    size = f"{info['width_mm']:.1f} x {info['height_mm']:.1f} mm"
    pixels = f", {info['width_px']}x{info['height_px']} px" if "width_px" in info else ""
    print(f"wrote {args.out}: {spec}, {size} with {args.margin_squares} white square(s) of margin{pixels}")
    print(
        f"{info['scale']}; then measure a square: it must be {info['square_mm']:g} mm (else give the measured size in --board)"
    )
    return 0


# --------------------------------------------------------------------------------- camera
def run_camera(args) -> int:
    from aes_planner.calibrate.board import parse_board
    from aes_planner.calibrate.intrinsics import (
        CalibrationFailed,
        calibrate_views,
        camera_info_yaml,
        check_camera_name,
        load_views,
    )

    _check_flags(args)
    check_camera_name(args.camera_name)
    _check_outputs(args, ("--out", "--json"))
    spec = parse_board(args.board)
    t0 = time.monotonic()
    if args.device is not None or args.launch is not None:
        if args.images or (args.device is not None and args.launch is not None):
            raise CalibrateUsageError("give one of IMAGES, --device or --launch")
        views = _live_views(args, spec)
    else:
        if not args.images:
            raise CalibrationFailed(
                "no images given; pass the board images (e.g. views/*.png), --device N or --launch LAUNCH"
            )
        views = load_views(args.images, spec)
    result = calibrate_views(views, spec)
    Path(args.out).write_text(
        camera_info_yaml(result.K, result.distortion, result.width, result.height, args.camera_name), encoding="utf-8"
    )
    report = result.report()
    report["runtime_s"] = time.monotonic() - t0
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2), encoding="utf-8")
    print(
        f"{len(result.used)} views used, {len(result.rejected)} rejected; RMS {result.rms_px:.3f} px; "
        f"fx {report['fx']:.2f} fy {report['fy']:.2f} cx {report['cx']:.2f} cy {report['cy']:.2f}; "
        f"corners cover {100 * result.coverage:.0f} % of the image"
    )
    for r in result.rejected:
        print(f"  rejected {r['image']}: {r['reason']}")
    quality = "good" if result.rms_px < 0.5 else "acceptable" if result.rms_px < 1.0 else "poor: retake sharper views"
    print(f"wrote {args.out} (ROS camera_info); RMS is {quality}")
    return 0


def launch_camera_spec(launch: str, overrides) -> dict:
    """The ``camera: {type: ...}`` mapping of the launch file's camera node (its short form
    ``device:`` / ``calibration:`` read as an ``opencv_camera``), checked as the node checks it."""
    from aes_planner.config import from_dict
    from aes_planner.graph.launch_file import load_launch
    from aes_planner.node.camera import CameraNodeConfig

    entry = next((e for e in load_launch(launch, overrides).nodes if e.type == "camera"), None)
    if entry is None:
        raise CalibrateUsageError(f"--launch {launch}: needs a camera node (as pan_tilt_rig.yaml)")
    return dict(from_dict(CameraNodeConfig, entry.config, "camera.config").device_spec)


def _live_camera(args):
    """The camera a live ``calibrate camera`` reads, raw, built by the device factory as the camera
    node builds it: ``--device N`` an ``opencv_camera``, ``--launch`` the launch's camera node's."""
    from aes_planner.devices import make_camera

    if args.launch is not None:
        return make_camera(launch_camera_spec(args.launch, args.set), "camera", raw=True)
    device = int(args.device) if str(args.device).isdigit() else args.device
    # the config refuses a bad index before OpenCV sees it (VideoCapture(-1) kills the process)
    return make_camera({"type": "opencv_camera", "device": device}, "device", raw=True)


def _live_views(args, spec):
    """Raw frames from a live camera: a view is kept when the board is found and its corners moved
    (a new pose); prints the image coverage as views accumulate."""
    import cv2
    import numpy as np

    from aes_planner.calibrate.board import detect
    from aes_planner.calibrate.intrinsics import DUPLICATE_PX, View, _coverage

    camera = _live_camera(args)
    camera.connect()
    views, tries = [], 0
    try:
        while len(views) < args.frames and tries < 200 * args.frames:
            tries += 1
            shot = camera.read(time.time())
            if shot is None:
                continue
            rgb = shot.image  # [H, W, 3] uint8, raw
            gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            found = detect(gray, spec)
            if found is None:
                continue
            if (
                views
                and min(
                    float(np.linalg.norm(v.detection.image_points - found.image_points, axis=1).mean()) for v in views
                )
                < 10 * DUPLICATE_PX
            ):
                continue
            name = f"live_{len(views):03d}"
            if args.save_dir:
                Path(args.save_dir).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(Path(args.save_dir) / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            views.append(View(name, gray, found))
            cover = _coverage([v.detection.image_points for v in views], gray.shape[1], gray.shape[0])
            print(
                f"view {len(views)}/{args.frames}: corners cover {100 * cover:.0f} % of the image (move the board to the empty parts)"
            )
    finally:
        camera.disconnect()
    return views


# ------------------------------------------------------------------------------------ rig
def _load_rig(path: str):
    from aes_planner.config import ConfigError, from_dict, load_yaml
    from aes_planner.geometry.rig import PanTiltConfig

    doc = load_yaml(path)
    if not isinstance(doc, dict) or not doc:
        raise ConfigError(
            "rig", f"{path}: give the rig's PanTiltConfig fields (base_xyz_m, tilt_offset_m, lever_arm_m, ...)"
        )
    return from_dict(PanTiltConfig, doc, "rig")


def sim_calibration_camera(
    scene,
    supersample: int,
    seed: int,
    pixel_noise_sigma: float = 0.0,
    latency_s: float = 0.0,
    min_width: int | None = None,
):
    """The simulated camera a ``--scene`` calibration images the board with: the scene's camera on
    its true rig, at :func:`~aes_planner.calibrate.capture.sim_camera_size` (the calibration takes it
    built, and never imports the simulator itself)."""
    from aes_planner.calibrate.capture import MIN_SIM_WIDTH_PX, sim_camera_size
    from aes_planner.sim import SimCamera, SimCameraConfig

    w, h = sim_camera_size(scene, MIN_SIM_WIDTH_PX if min_width is None else min_width)
    config = SimCameraConfig(
        width=w, height=h, supersample=supersample, pixel_noise_sigma=pixel_noise_sigma, latency_s=latency_s, seed=seed
    )
    return SimCamera(scene, config)


class _Session:
    """The view source (and for hardware the devices to release) of a ``--scene``/``--launch`` run."""

    def __init__(self, args):
        self.args = args
        self.scene = None
        self.gimbal = None
        self.camera = None  # the camera device (--launch), raw frames
        self.tilt_direction = 1
        self.tilt_zero_offset_ticks: int | None = None  # the driver's present value (--launch)

    def __enter__(self):
        from aes_planner.calibrate.capture import SimViewSource, sim_camera_size

        a = self.args
        if a.scene:
            from aes_planner.sim import load_scene

            self.scene = load_scene(a.scene, allow_outside=a.allow_outside_paths)
            if self.scene.rig is None:
                raise CalibrateUsageError(f"--scene {a.scene}: the scene has a drone; calibration needs a rig scene")
            w, h = sim_camera_size(self.scene)
            supersample = a.supersample if a.supersample is not None else (2 if w * h <= 640 * 540 else 1)
            if not 1 <= supersample <= 8:
                raise CalibrateUsageError(f"--supersample must be 1..8, got {supersample}")
            camera = sim_calibration_camera(self.scene, supersample, a.seed, pixel_noise_sigma=a.pixel_noise)
            self.source = SimViewSource(camera, a.joint_noise_deg, a.seed)
            if a.camera_info:
                log.warning("--camera-info is not used with --scene: the scene's camera is exact")
            return self
        self.source = self._hardware()
        return self

    def _hardware(self):
        import numpy as np

        from aes_planner.calibrate.capture import CameraModel, HardwareViewSource
        from aes_planner.devices import make_camera, make_device
        from aes_planner.drivers.camera import load_calibration
        from aes_planner.graph.launch_file import load_launch

        a = self.args
        spec = load_launch(a.launch, a.set)
        gimbal_entry = next((e for e in spec.nodes if e.type == "gimbal"), None)
        if gimbal_entry is None or "device" not in gimbal_entry.config:
            raise CalibrateUsageError(
                f"--launch {a.launch}: needs a gimbal node with a device and a camera node (as pan_tilt_rig.yaml)"
            )
        # the camera node's own config: camera: {type: ...} or its device/calibration short form, checked
        # (a bad index fails here, before OpenCV: VideoCapture(-1) kills the process)
        camera_spec = launch_camera_spec(a.launch, a.set)
        device_spec = dict(gimbal_entry.config["device"])
        self.tilt_direction = int(device_spec.get("tilt_direction", 1))
        self.tilt_zero_offset_ticks = int(device_spec.get("tilt_zero_offset_ticks", 0))
        calibration_file = a.camera_info or camera_spec.get("calibration")
        if not calibration_file:
            raise CalibrateUsageError(
                "the camera's intrinsics are needed: run `calibrate camera` first and pass --camera-info"
            )
        cal = load_calibration(calibration_file)
        k = cal.intrinsics
        dist = np.zeros(5)
        dist[: min(5, cal.distortion.size)] = cal.distortion[:5]
        camera = CameraModel(cal.K_opencv, dist, k.width, k.height)
        if "calibration" in camera_spec:  # the file the rig is calibrated with sets the frame size asked for
            camera_spec["calibration"] = calibration_file
        # raw frames (not undistorted: the calibration models the distortion), through the device
        # factory as the camera node builds its camera
        self.camera = make_camera(camera_spec, "camera", raw=True)
        self.gimbal = make_device(device_spec, "gimbal.device")
        self.gimbal.connect()
        self.camera.connect()
        return HardwareViewSource(self.gimbal, self.camera, camera, settle_s=a.settle_s)

    def stream(self):
        """The continuous-sweep callable for the latency."""
        from aes_planner.calibrate.capture import SimStream

        if self.scene is not None:
            return SimStream(sim_calibration_camera(self.scene, 1, self.args.seed, latency_s=self.args.sim_latency))
        return self.source.stream

    def __exit__(self, *exc):
        if self.camera is not None:
            self.camera.disconnect()
        if self.gimbal is not None:
            self.gimbal.disconnect()


@drives_servos
def run_rig(args) -> int:
    from dataclasses import replace

    import numpy as np

    from aes_planner.calibrate.board import parse_board
    from aes_planner.calibrate.pipeline import calibrate_rig, estimate_latency, latency_sweep_centre, rig_yaml
    from aes_planner.config import to_dict

    _check_flags(args)
    _check_outputs(args, ("--out", "--json"))  # before the calibration, not after it
    board = parse_board(args.board)
    nominal = _load_rig(args.rig)
    if not 8 <= args.views <= 200:
        raise CalibrateUsageError(f"--views must be in [8, 200], got {args.views}")
    t0 = time.monotonic()
    with _Session(args) as session:
        config, report = calibrate_rig(
            session.source, nominal, board, args.views, args.zero_offsets, session.tilt_direction, args.seed
        )
        report["rig_s"] = time.monotonic() - t0
        if "driver" in report and session.tilt_zero_offset_ticks is not None:
            change = report["driver"]["tilt_zero_offset_ticks_change"]
            report["driver"]["tilt_zero_offset_ticks"] = session.tilt_zero_offset_ticks + change
        if args.latency:
            t1 = time.monotonic()
            b2w = np.asarray(report["board2world"])
            centre, amplitude = latency_sweep_centre(session.source.camera, config, board, b2w)
            lat = estimate_latency(session.stream(), session.source.camera, config, board, b2w, centre, amplitude)
            config = replace(config, camera_latency_s=round(float(lat["camera_latency_s"]), 4))
            report["latency"] = {**lat, "runtime_s": time.monotonic() - t1}
    Path(args.out).write_text(
        rig_yaml(
            config,
            f"aes-planner calibrate rig --board {board}: PanTiltConfig fields (suggest --rig, scene rig.pan_tilt, launch rig)",
        ),
        encoding="utf-8",
    )
    report["rig"] = to_dict(config)
    report["runtime_s"] = time.monotonic() - t0
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2), encoding="utf-8")
    print(
        f"{report['views_used']} views (pan over {report['pan_span_deg']:.0f} deg, tilt over {report['tilt_span_deg']:.0f} deg); "
        f"reprojection RMS {report['rms_before_px']:.2f} px with the nominal rig -> {report['rms_after_px']:.3f} px calibrated"
    )
    for name, p in report["parameters"].items():
        print(f"  {name:26s} {p['value']:+9.3f} {p['unit']:3s} +- {p['std']:.3f}  (nominal {p['nominal']:+.3f})")
    for u in report["unobservable"]:
        print(f"  not observable: {u['combination']} -> {u['fixed']}")
    if "driver" in report:
        d = report["driver"]
        target = (
            f" (set tilt_zero_offset_ticks: {d['tilt_zero_offset_ticks']} in the gimbal's device config)"
            if "tilt_zero_offset_ticks" in d
            else ""
        )
        print(
            f"  the driver's tilt_zero_offset_ticks += {d['tilt_zero_offset_ticks_change']}{target}; {args.out} is for that driver"
        )
    if "latency" in report:
        print(
            f"  camera latency {1000 * report['latency']['camera_latency_s']:.1f} ms ({report['latency']['frames_used']} frames)"
        )
    print(f"wrote {args.out} in {report['runtime_s']:.0f} s")
    return 0


@drives_servos
def run_verify(args) -> int:
    from aes_planner.calibrate.board import parse_board
    from aes_planner.calibrate.pipeline import verify_rig

    _check_flags(args)
    _check_outputs(args, ("--json",))
    board = parse_board(args.board)
    config = _load_rig(args.rig)
    if not 4 <= args.views <= 200:
        raise CalibrateUsageError(f"--views must be in [4, 200], got {args.views}")
    t0 = time.monotonic()
    with _Session(args) as session:
        report = verify_rig(session.source, config, board, args.views, seed=args.seed + 101)
    report["runtime_s"] = time.monotonic() - t0
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2), encoding="utf-8")
    verdict = (
        "holds" if report["held_out_rms_px"] < 1.0 else "does NOT hold: recalibrate (did the camera or board move?)"
    )
    print(
        f"{report['views']} new views: held-out reprojection RMS {report['held_out_rms_px']:.3f} px "
        f"(worst view {report['held_out_max_view_rms_px']:.3f} px), all views {report['rms_px']:.3f} px; the calibration {verdict}"
    )
    return 0 if math.isfinite(report["held_out_rms_px"]) else 2
