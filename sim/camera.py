"""``SimCamera``: renders :class:`~aes_planner.messages.PosedFrame` records of a scene.

Timing model (all times in seconds of sim time, the ``stamp_s`` of the frames):

* The camera keeps a **pose history**: :meth:`SimCamera.move_to` (a cam2world) or
  :meth:`SimCamera.move_joints` (rig joint angles through
  :meth:`~aes_planner.geometry.PanTilt.forward`) says where the camera is from ``stamp_s`` on.
  The pose at time ``t`` is the last one set at or before ``t`` (a zero-order hold); before the
  first one, the first one.
* :meth:`SimCamera.capture` at time ``t`` returns a frame stamped ``t`` whose **image, depth
  and ids show the pose at** ``t - latency_s`` (the exposure happened ``latency_s`` before the
  frame arrived), while its **reported** ``cam2world`` is the pose at ``t`` — what a system that
  pairs each frame with the latest pose would record. With ``latency_s = 0`` both agree.
* **Pose noise** perturbs only the reported pose (translation ``N(0, sigma^2)`` per world axis,
  rotation by a random rotation vector ``N(0, sigma^2)`` per camera axis); the true pose is
  rendered. **Pixel noise** adds ``N(0, sigma^2)`` (8-bit levels) to each channel, rounded and
  clipped. Both are seeded; they use separate streams, so turning one on does not change the
  other. With ``noise_by_pose`` a frame's noise is drawn from the seed and the pose it shows
  (the same view, the same noise, whenever it is captured) instead of from a stream one draw per
  frame: a closed loop's noise then does not depend on how many frames the camera rendered
  before a capture, which a simulated gimbal's arrival time changes from process to process.
* ``frame.extras`` holds ``instance_id`` (``[H, W]`` int32), ``true_cam2world`` (the rendered
  pose), ``exposure_stamp_s`` (``t - latency_s``) and ``reported_pose_error_m`` (translation
  between the reported and rendered poses).
"""

from __future__ import annotations

import bisect
import hashlib
import math
from dataclasses import dataclass

import cv2
import numpy as np

from aes_planner.config import require, require_numbers
from aes_planner.devices import Camera, CameraImage
from aes_planner.errors import AesPlannerError
from aes_planner.geometry import Intrinsics, validate_cam2world
from aes_planner.geometry.camera import MAX_CAMERA_PIXELS, MAX_CAMERA_SIDE_PX
from aes_planner.messages import PosedFrame
from aes_planner.sim.raycast import MAX_SUPERSAMPLE, render
from aes_planner.sim.scene import Scene

__all__ = ["SimCamera", "SimCameraConfig", "SimCameraError"]

_MAX_HISTORY = 4096  # poses kept; the oldest are dropped beyond this


class SimCameraError(AesPlannerError, ValueError):
    """A sim-camera call that cannot be served (no pose yet, joints on a drone scene...)."""


@dataclass
class SimCameraConfig:
    """How the simulated camera images and what errors it adds.

    * ``width``, ``height``, ``hfov_deg``: override the scene's camera (its ``rig`` or
      ``drone`` section) when set.
    * ``supersample``: anti-aliasing, ``s x s`` RGB samples per pixel (1 = off).
    * ``pixel_noise_sigma``: std-dev of Gaussian noise per channel, in 8-bit levels.
    * ``pose_noise_translation_m``, ``pose_noise_rotation_deg``: std-dev of the error added to
      the reported pose (the rendered pose stays true).
    * ``latency_s``: a frame captured at ``t`` shows the pose at ``t - latency_s``.
    * ``seed``: for the noise streams.
    * ``noise_by_pose``: draw each frame's noise from ``seed`` and its pose, not from a stream.
    """

    width: int | None = None
    height: int | None = None
    hfov_deg: float | None = None
    supersample: int = 1
    pixel_noise_sigma: float = 0.0
    pose_noise_translation_m: float = 0.0
    pose_noise_rotation_deg: float = 0.0
    latency_s: float = 0.0
    seed: int = 0
    noise_by_pose: bool = False

    def __post_init__(self):
        for name in ("width", "height"):
            v = getattr(self, name)
            require(
                v is None or (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_CAMERA_SIDE_PX),
                name,
                f"must be a number of pixels in [1, {MAX_CAMERA_SIDE_PX}], got {v!r}",
            )
        require(
            self.width is None or self.height is None or self.width * self.height <= MAX_CAMERA_PIXELS,
            "width",
            f"a {self.width}x{self.height} camera is too large: at most {MAX_CAMERA_PIXELS} pixels in all",
        )
        require(
            self.hfov_deg is None or 0.0 < self.hfov_deg < 180.0,
            "hfov_deg",
            f"must be in (0, 180), got {self.hfov_deg}",
        )
        require(
            1 <= self.supersample <= MAX_SUPERSAMPLE,
            "supersample",
            f"must be in [1, {MAX_SUPERSAMPLE}], got {self.supersample}",
        )
        require_numbers(
            self,
            ("pixel_noise_sigma", "pose_noise_translation_m", "pose_noise_rotation_deg", "latency_s"),
            strict=False,
        )
        require(self.latency_s <= 10.0, "latency_s", f"must be <= 10 s, got {self.latency_s}")
        require(
            self.pose_noise_rotation_deg <= 180.0,
            "pose_noise_rotation_deg",
            f"must be <= 180 deg, got {self.pose_noise_rotation_deg}",
        )
        require(
            isinstance(self.noise_by_pose, bool), "noise_by_pose", f"must be true or false, got {self.noise_by_pose!r}"
        )


class SimCamera(Camera):
    """A camera in a :class:`Scene` that turns poses into :class:`PosedFrame` records.

    Quick use: ``SimCamera(scene).capture_joints(pan_rad, tilt_rad)`` on a rig scene, or
    ``capture_pose(cam2world)``. For latency, set poses over time with :meth:`move_to` /
    :meth:`move_joints` and call :meth:`capture` (timing model in the module docstring).

    It is also a :class:`~aes_planner.devices.Camera` (nothing to open; :attr:`ready` once placed;
    :meth:`read` is :meth:`capture` as a :class:`~aes_planner.devices.CameraImage`, the pose it
    reports included), which is how the sim camera nodes publish it.
    """

    def __init__(self, scene: Scene, config: SimCameraConfig | None = None):
        if not isinstance(scene, Scene):
            raise SimCameraError(
                f"SimCamera needs a Scene, got {type(scene).__name__}; use aes_planner.sim.load_scene()"
            )
        self.scene = scene
        self.config = config or SimCameraConfig()
        c = self.config
        base = (scene.rig or scene.drone).camera
        self.intrinsics = Intrinsics.from_fov(
            c.width or base.width, c.height or base.height, c.hfov_deg or base.hfov_deg
        )
        self.kinematics = scene.rig.kinematics() if scene.rig is not None else None
        pose_seq, pixel_seq = np.random.SeedSequence(c.seed).spawn(2)
        self._pose_rng = np.random.default_rng(pose_seq)
        self._pixel_rng = np.random.default_rng(pixel_seq)
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        self.frames_captured = 0

    # ------------------------------------------------------------------------------ device
    @property
    def connected(self) -> bool:
        return True

    def connect(self) -> None:
        return None

    def disconnect(self) -> None:
        return None

    @property
    def ready(self) -> bool:
        """True once the camera has a pose (:meth:`move_to` / :meth:`move_joints`)."""
        return bool(self._stamps)

    def read(self, stamp_s: float) -> CameraImage | None:
        """:meth:`capture` at ``stamp_s`` (image, depth, and the pose it reports); None before the
        camera has a pose. The ground truth of ``frame.extras`` is not part of a reading."""
        if not self._stamps:
            return None
        frame = self.capture(stamp_s)
        return CameraImage(frame.image, frame.stamp_s, frame.depth_m, frame.cam2world)

    # ------------------------------------------------------------------------------ motion
    def move_to(self, cam2world: np.ndarray, stamp_s: float = 0.0) -> None:
        """The camera is at ``cam2world [4, 4]`` from ``stamp_s`` on (replacing a pose set at
        the same stamp)."""
        pose = validate_cam2world(cam2world, "SimCamera.move_to cam2world")
        if not math.isfinite(stamp_s):
            raise SimCameraError(f"stamp_s must be a finite number of seconds, got {stamp_s!r}")
        i = bisect.bisect_left(self._stamps, stamp_s)
        if i < len(self._stamps) and self._stamps[i] == stamp_s:
            self._poses[i] = pose
        else:
            self._stamps.insert(i, float(stamp_s))
            self._poses.insert(i, pose)
        if len(self._stamps) > _MAX_HISTORY:
            del self._stamps[0], self._poses[0]

    def move_joints(self, pan_rad: float, tilt_rad: float, stamp_s: float = 0.0) -> None:
        """Rig scenes: the gimbal is at these joint angles from ``stamp_s`` on. Angles outside
        the joint limits are rendered as given (a real servo would refuse them: clamp first
        with ``camera.kinematics.clamp``)."""
        if self.kinematics is None:
            raise SimCameraError("this scene has a drone, not a rig: use move_to(cam2world) instead of joint angles")
        self.move_to(self.kinematics.forward(float(pan_rad), float(tilt_rad)), stamp_s)

    def pose_at(self, stamp_s: float) -> np.ndarray:
        """cam2world ``[4, 4]`` held at ``stamp_s`` (zero-order hold over the history)."""
        if not self._stamps:
            raise SimCameraError("the camera has no pose yet: call move_to() or move_joints() first")
        i = bisect.bisect_right(self._stamps, stamp_s) - 1
        return self._poses[max(i, 0)].copy()

    # ----------------------------------------------------------------------------- capture
    def capture(self, stamp_s: float | None = None) -> PosedFrame:
        """The frame that arrives at ``stamp_s`` (default: the newest pose's stamp)."""
        if not self._stamps:
            raise SimCameraError("the camera has no pose yet: call move_to() or move_joints() first")
        t = self._stamps[-1] if stamp_s is None else float(stamp_s)
        exposure_s = t - self.config.latency_s
        true_pose = self.pose_at(exposure_s)
        reported = self._perturb(self.pose_at(t), self._rng_for(self._pose_rng, 0, true_pose))
        out = render(self.scene, true_pose, self.intrinsics, self.config.supersample)
        image = out.rgb
        sigma = self.config.pixel_noise_sigma
        if sigma > 0:
            rng = self._rng_for(self._pixel_rng, 1, true_pose)
            noisy = image + rng.normal(0.0, sigma, image.shape)
            image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        frame = PosedFrame(
            image=image,
            intrinsics=self.intrinsics,
            cam2world=reported,
            stamp_s=t,
            depth_m=out.depth_m,
            frame_id=f"{self.scene.name}/{self.frames_captured:06d}",
            extras={
                "instance_id": out.instance_id,
                "true_cam2world": true_pose,
                "exposure_stamp_s": exposure_s,
                "reported_pose_error_m": float(np.linalg.norm(reported[:3, 3] - true_pose[:3, 3])),
            },
        )
        self.frames_captured += 1
        return frame

    def capture_pose(self, cam2world: np.ndarray, stamp_s: float | None = None) -> PosedFrame:
        """Move to ``cam2world`` at ``stamp_s`` (default: the newest stamp, or 0) and capture then."""
        t = stamp_s if stamp_s is not None else (self._stamps[-1] if self._stamps else 0.0)
        self.move_to(cam2world, t)
        return self.capture(t)

    def capture_joints(self, pan_rad: float, tilt_rad: float, stamp_s: float | None = None) -> PosedFrame:
        """Rig scenes: move the gimbal to these joints at ``stamp_s`` and capture then."""
        t = stamp_s if stamp_s is not None else (self._stamps[-1] if self._stamps else 0.0)
        self.move_joints(pan_rad, tilt_rad, t)
        return self.capture(t)

    def _rng_for(self, stream: np.random.Generator, which: int, pose: np.ndarray) -> np.random.Generator:
        """The generator of one frame's noise: the stream, or with ``noise_by_pose`` one seeded by
        ``seed``, ``which`` (0 pose, 1 pixels) and the shown pose ``[4, 4]`` rounded to 1e-9."""
        if not self.config.noise_by_pose:
            return stream
        key = np.rint(np.asarray(pose, dtype=np.float64)[:3, :4] * 1e9).astype(np.int64).tobytes()
        digest = int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little")
        return np.random.default_rng([self.config.seed, which, digest])

    def _perturb(self, cam2world: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        c = self.config
        if c.pose_noise_translation_m == 0 and c.pose_noise_rotation_deg == 0:
            return cam2world
        pose = cam2world.copy()
        rotvec = rng.normal(0.0, math.radians(c.pose_noise_rotation_deg), 3)
        pose[:3, :3] = cam2world[:3, :3] @ cv2.Rodrigues(rotvec.reshape(3, 1))[0]
        pose[:3, 3] += rng.normal(0.0, c.pose_noise_translation_m, 3)
        return pose
