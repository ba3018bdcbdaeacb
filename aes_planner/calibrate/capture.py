"""Where rig views come from, and which joint poses to take them at.

A :class:`ViewSource` moves the gimbal, waits until it is at rest and returns a grayscale image
with the joint angles the gimbal reports: :class:`SimViewSource` renders a sim scene's **true**
rig (the nominal rig is only the plan's guess), the hardware source (``cli/calibrate.py``) drives
a Dynamixel pan-tilt and reads a camera. :func:`find_board` sweeps coarsely until the board is in
view; :func:`plan_views` picks joint poses that keep the whole board in the image while spreading
it over the image and the joints over their range; :func:`collect` captures and detects them.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from aes_planner.calibrate.board import BoardSpec, Detection, detect
from aes_planner.calibrate.rig import RigCalibrationError, RigObservations
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.rig import PanTiltConfig

log = logging.getLogger(__name__)

__all__ = ["CameraModel", "ViewSource", "SimViewSource", "collect", "find_board", "plan_views"]


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics in OpenCV's pixel convention (``K [3, 3]``, plumb_bob ``distortion [5]``) and size."""

    K: np.ndarray
    distortion: np.ndarray
    width: int
    height: int

    def undistort(self, points: np.ndarray) -> np.ndarray:  # [N, 2] -> [N, 2] pixels of the ideal pinhole K
        if not np.any(self.distortion):
            return points
        out = cv2.undistortPoints(points.reshape(-1, 1, 2).astype(np.float64), self.K, self.distortion, P=self.K)
        return out.reshape(-1, 2)

    def project(self, points_cam: np.ndarray) -> np.ndarray:  # [..., 3] -> [..., 2], pinhole
        z = points_cam[..., 2:3]
        return points_cam[..., :2] / z * np.array([self.K[0, 0], self.K[1, 1]]) + self.K[:2, 2]


class ViewSource:
    """Moves the gimbal and images the board. ``camera`` is the :class:`CameraModel`."""

    camera: CameraModel

    def capture(self, pan_rad: float, tilt_rad: float) -> tuple[np.ndarray, float, float]:
        """Gray image ``[H, W]`` uint8 taken at rest at these joints, and the joints reported then."""
        raise NotImplementedError

    def close(self) -> None:
        pass


#: Narrowest sim image the rig calibration renders (wider scenes keep their own camera).
MIN_SIM_WIDTH_PX = 640


def sim_camera_size(scene, min_width: int = MIN_SIM_WIDTH_PX) -> tuple[int, int]:
    """The size the calibration renders a sim scene's camera at: its own, or ``min_width`` wide
    (same field of view and aspect) when it is narrower, since a board needs ~8 px squares to be
    found and the rig's kinematics do not depend on the resolution."""
    if scene.rig is None:
        raise RigCalibrationError(f"scene {scene.name!r} has a drone, not a pan-tilt rig")
    cam = scene.rig.camera
    if cam.width >= min_width:
        return cam.width, cam.height
    return min_width, max(1, round(min_width * cam.height / cam.width))


def _opencv_model(intrinsics) -> CameraModel:
    """The distortion-free :class:`CameraModel` of the package's :class:`Intrinsics` (pixel centres moved to OpenCV's)."""
    k = intrinsics
    K = np.array([[k.fx, 0, k.cx - 0.5], [0, k.fy, k.cy - 0.5], [0, 0, 1.0]])
    return CameraModel(K, np.zeros(5), k.width, k.height)


class SimViewSource(ViewSource):
    """A simulated camera on the sim scene's true rig: ``camera`` is an :class:`aes_planner.sim.SimCamera`
    the caller built (at :func:`sim_camera_size`; the calibration does not import the simulator).
    ``joint_noise_deg`` adds reading noise to the angles reported (what an encoder would), the image
    stays at the commanded pose."""

    def __init__(self, camera, joint_noise_deg: float = 0.0, seed: int = 0):
        self.sim = camera
        self.camera = _opencv_model(camera.intrinsics)
        self.rng = np.random.default_rng(seed + 1)
        self.joint_noise_rad = math.radians(joint_noise_deg)
        self.frames = 0

    def capture(self, pan_rad: float, tilt_rad: float) -> tuple[np.ndarray, float, float]:
        frame = self.sim.capture_joints(pan_rad, tilt_rad, stamp_s=float(self.frames))
        self.frames += 1
        noise = self.rng.normal(0.0, self.joint_noise_rad, 2) if self.joint_noise_rad > 0 else (0.0, 0.0)
        return cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY), pan_rad + noise[0], tilt_rad + noise[1]


def _fov_rad(camera: CameraModel) -> tuple[float, float]:
    return 2 * math.atan(camera.width / (2 * camera.K[0, 0])), 2 * math.atan(camera.height / (2 * camera.K[1, 1]))


def find_board(source: ViewSource, nominal: PanTiltConfig, board: BoardSpec) -> tuple[float, float, Detection]:
    """The first joint pose of a coarse sweep (half a field of view apart, from the middle of the
    range outwards) whose image holds the whole board."""
    kin = PanTilt(nominal)
    hfov, vfov = _fov_rad(source.camera)
    (plo, phi), (tlo, thi) = kin.pan_limits_rad, kin.tilt_limits_rad
    pans = _outwards(plo, phi, 0.5 * hfov)
    tilts = _outwards(tlo, thi, 0.5 * vfov)
    tried = 0
    for t in tilts:
        for p in pans:
            gray, pan, tilt = source.capture(p, t)
            tried += 1
            found = detect(gray, board)
            if found is not None:
                log.info(
                    "board found at pan %.1f, tilt %.1f deg after %d views",
                    math.degrees(pan),
                    math.degrees(tilt),
                    tried,
                )
                return pan, tilt, found
    raise RigCalibrationError(
        f"the board ({board}) was in none of {tried} views of a sweep over the joint range: check that --board "
        "matches the printed board (inner corners COLSxROWS, not squares), that it is lit and wholly in view "
        "somewhere in the range, and not so far that its squares are under ~8 pixels"
    )


def _outwards(lo: float, hi: float, step: float) -> list[float]:
    mid = 0.5 * (lo + hi)
    out = [mid]
    k = 1
    while mid + k * step <= hi or mid - k * step >= lo:
        out += [a for a in (mid + k * step, mid - k * step) if lo <= a <= hi]
        k += 1
    return out


def board_in_world(
    camera: CameraModel, nominal: PanTiltConfig, pan: float, tilt: float, found: Detection
) -> np.ndarray:
    """board2world ``[4, 4]`` from one detection through the nominal kinematics (the plan's guess)."""
    ok, rvec, tvec = cv2.solvePnP(found.object_points, camera.undistort(found.image_points), camera.K, None)
    b2c = np.eye(4)
    b2c[:3, :3], b2c[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
    return PanTilt(nominal).forward(pan, tilt) @ b2c


def plan_views(
    camera: CameraModel,
    nominal: PanTiltConfig,
    board: BoardSpec,
    board2world: np.ndarray,
    n_views: int,
    margin: float = 0.05,
    seed: int = 0,
) -> np.ndarray:
    """``[n, 2]`` joint poses where the nominal rig sees the whole board ``margin`` (fraction of the
    image) inside every edge, chosen by farthest-point sampling in joint space from the extremes,
    so the board travels over the whole image and the joints over the widest range it allows."""
    kin = PanTilt(nominal)
    hfov, vfov = _fov_rad(camera)
    obj = board.object_points()
    # the outline of the board with its white margin (the detector needs that quiet zone), to keep in view
    cx, cy = board.corners_grid
    s = board.square_m
    lo, hi_x, hi_y = -2 * s, (cx + 1) * s, (cy + 1) * s
    outline = np.array([[lo, lo, 0], [hi_x, lo, 0], [lo, hi_y, 0], [hi_x, hi_y, 0]])
    corners_w = outline @ board2world[:3, :3].T + board2world[:3, 3]
    centre_w = obj.mean(0) @ board2world[:3, :3].T + board2world[:3, 3]
    aim = kin.inverse_look_at(centre_w)
    pans = np.linspace(aim.pan_rad - hfov / 2, aim.pan_rad + hfov / 2, 41)
    tilts = np.linspace(aim.tilt_rad - vfov / 2, aim.tilt_rad + vfov / 2, 31)
    pp, tt = np.meshgrid(pans, tilts)
    pp, tt = pp.ravel(), tt.ravel()
    inside = np.array([kin.within_limits(p, t) for p, t in zip(pp, tt)])
    pp, tt = pp[inside], tt[inside]
    c2w = kin.forward(pp, tt)  # [G, 4, 4]
    pc = np.einsum("gji,gnj->gni", c2w[:, :3, :3], corners_w[None] - c2w[:, None, :3, 3])
    ok = (pc[..., 2] > 0.05).all(-1)
    uv = camera.project(np.where(pc[..., 2:3] > 0.05, pc, 1.0))
    mx, my = margin * camera.width, margin * camera.height
    ok &= (
        (uv[..., 0] >= mx)
        & (uv[..., 0] <= camera.width - 1 - mx)
        & (uv[..., 1] >= my)
        & (uv[..., 1] <= camera.height - 1 - my)
    ).all(-1)
    cand = np.stack([pp[ok], tt[ok]], -1)
    if len(cand) == 0:
        raise RigCalibrationError(
            "the board does not fit in the image at any joint pose (it fills more than the field of view): move it "
            "farther from the rig or use a smaller board"
        )
    scale = np.array([1.0 / max(np.ptp(cand[:, 0]), 1e-6), 1.0 / max(np.ptp(cand[:, 1]), 1e-6)])
    norm = cand * scale
    chosen = [int(np.argmin(norm.sum(1)))]
    dist = np.linalg.norm(norm - norm[chosen[0]], axis=1)
    while len(chosen) < min(n_views, len(cand)):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(norm - norm[nxt], axis=1))
    return cand[chosen]


@dataclass
class Collected:
    observations: RigObservations
    rejected: list[dict]
    images: list[np.ndarray]


def collect(source: ViewSource, board: BoardSpec, joints: np.ndarray, keep_images: bool = False) -> Collected:
    """Capture at each joint pose ``[n, 2]``, detect the board, undistort its corners."""
    pans, tilts, views, objs, uvs, rejected, images = [], [], [], [], [], [], []
    for p, t in joints:
        gray, pan, tilt = source.capture(float(p), float(t))
        found = detect(gray, board)
        if found is None:
            rejected.append({"pan_deg": math.degrees(pan), "tilt_deg": math.degrees(tilt), "reason": "board not found"})
            continue
        views.append(np.full(len(found.object_points), len(pans)))
        pans.append(pan)
        tilts.append(tilt)
        objs.append(found.object_points)
        uvs.append(source.camera.undistort(found.image_points))
        if keep_images:
            images.append(gray)
    if not pans:
        raise RigCalibrationError(
            f"the board was found in none of the {len(joints)} planned views: check --board against the printed board"
        )
    obs = RigObservations(
        np.asarray(pans),
        np.asarray(tilts),
        np.concatenate(views),
        np.concatenate(objs),
        np.concatenate(uvs),
        source.camera.K,
    )
    return Collected(obs, rejected, images)


class SimStream:
    """A continuous sweep in the simulator, for the latency: joint states every ``state_period_s``
    (what the gimbal node publishes), frames every ``frame_period_s`` stamped on arrival by the sim
    ``camera`` (built by the caller) whose ``latency_s`` makes them show the pose that long before. The sim camera holds each
    pose it is given, so the motion is fed to it every millisecond (a servo moves continuously)."""

    def __init__(self, camera, frame_period_s: float = 1 / 15, state_period_s: float = 0.01):
        self.sim = camera  # an aes_planner.sim.SimCamera with the latency to find (SimCameraConfig.latency_s)
        self.camera = _opencv_model(camera.intrinsics)
        self.frame_period_s = frame_period_s
        self.state_period_s = state_period_s

    def __call__(self, trajectory, duration_s: float):
        lead = 0.6  # states before the first frame, so every frame's exposure has a pose
        step = max(0.001, (duration_s + lead) / 4000)  # within the sim camera's pose history
        every = max(1, round(self.state_period_s / step))
        states = []
        for i, t in enumerate(np.arange(0.0, duration_s + lead, step)):
            pan, tilt = trajectory(t - lead)
            self.sim.move_joints(pan, tilt, float(t))
            if i % every == 0:
                states.append((float(t), pan, tilt))
        frames = []
        for t in np.arange(lead, duration_s + lead, self.frame_period_s):
            frame = self.sim.capture(float(t))
            frames.append((float(t), cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)))
        return frames, states


class HardwareViewSource(ViewSource):
    """A real gimbal (any :class:`~aes_planner.devices.Gimbal`, connected) and a camera (any
    :class:`~aes_planner.devices.Camera`, connected, giving raw frames: built by the device factory
    as a node's camera is, :func:`aes_planner.devices.make_camera` with ``raw=True``): move, wait
    until the servos report arrival, let the bracket settle ``settle_s``, drop ``flush_frames``
    buffered frames, then take one and the joints the gimbal reports."""

    def __init__(self, gimbal, camera_device, camera: CameraModel, settle_s: float = 0.5, flush_frames: int = 4):
        self.gimbal = gimbal
        self.camera_device = camera_device
        self.camera = camera
        self.settle_s = settle_s
        self.flush_frames = flush_frames

    def _read(self) -> np.ndarray:  # -> [H, W] uint8 gray
        import time

        shot = self.camera_device.read(time.time())
        if shot is None:
            raise RigCalibrationError(
                "the camera returned no frame; check the device index and that nothing else holds it"
            )
        rgb = shot.image  # [H, W, 3] uint8 RGB, raw
        if rgb.shape[:2] != (self.camera.height, self.camera.width):
            raise RigCalibrationError(
                f"the camera delivers {rgb.shape[1]}x{rgb.shape[0]} frames but its calibration is for "
                f"{self.camera.width}x{self.camera.height}; calibrate the camera at this resolution"
            )
        return rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    def capture(self, pan_rad: float, tilt_rad: float) -> tuple[np.ndarray, float, float]:
        import time

        self.gimbal.move_to(pan_rad, tilt_rad)
        self.gimbal.wait_until_reached()
        time.sleep(self.settle_s)
        for _ in range(self.flush_frames):
            self._read()
        gray = self._read()
        state = self.gimbal.state()
        return gray, state.pan_rad, state.tilt_rad

    def stream(self, trajectory, duration_s: float, state_period_s: float = 0.02):
        """A continuous sweep for :func:`~aes_planner.calibrate.pipeline.estimate_latency`: goals
        along ``trajectory`` and joint states every ``state_period_s`` from a thread, frames read
        as fast as the camera gives them, all stamped with ``time.time()`` on arrival."""
        import threading
        import time

        pan0, tilt0 = trajectory(0.0)
        self.gimbal.move_to(pan0, tilt0)
        self.gimbal.wait_until_reached()
        states, stop = [], threading.Event()
        start = time.time()

        def drive():
            while not stop.is_set():
                now = time.time()
                self.gimbal.move_to(*trajectory(now - start))
                s = self.gimbal.state()
                states.append((s.stamp_s, s.pan_rad, s.tilt_rad))
                stop.wait(max(0.0, state_period_s - (time.time() - now)))

        thread = threading.Thread(target=drive, name="calibrate-sweep", daemon=True)
        thread.start()
        frames = []
        try:
            while time.time() - start < duration_s:
                gray = self._read()
                frames.append((time.time(), gray))
        finally:
            stop.set()
            thread.join(timeout=5.0)
        return frames, states
