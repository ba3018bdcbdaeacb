"""SimCamera: PosedFrames from poses or joints, seeded noise, and the latency model."""

import math

import numpy as np
import pytest

from aes_planner.config import ConfigError, from_dict
from aes_planner.geometry import look_at
from aes_planner.messages import PosedFrame
from aes_planner.sim import SimCamera, SimCameraConfig, load_scene, render
from aes_planner.sim.camera import SimCameraError
from aes_planner.sim.spec import CameraSpec, DroneSpec, SceneSpec, SphereSpec


@pytest.fixture(scope="module")
def scene():
    return load_scene("tabletop:0")


def test_joints_render_what_the_kinematics_show(scene):
    cam = SimCamera(scene)
    frame = cam.capture_joints(0.2, -0.4, stamp_s=1.5)
    assert isinstance(frame, PosedFrame)
    pose = scene.rig.kinematics().forward(0.2, -0.4)
    out = render(scene, pose, scene.rig.intrinsics())
    assert np.array_equal(frame.image, out.rgb) and np.array_equal(frame.depth_m, out.depth_m)
    assert np.array_equal(frame.extras["instance_id"], out.instance_id)
    assert np.allclose(frame.cam2world, pose) and np.allclose(frame.extras["true_cam2world"], pose)
    assert frame.stamp_s == 1.5 and frame.intrinsics == scene.rig.intrinsics()
    assert frame.frame_id == "tabletop-0/000000" and cam.capture().frame_id == "tabletop-0/000001"


def test_config_overrides_the_scene_camera(scene):
    cam = SimCamera(scene, SimCameraConfig(width=40, height=30, hfov_deg=90.0, supersample=2))
    frame = cam.capture_pose(scene.rig.kinematics().forward(0.0, 0.0))
    assert frame.image.shape == (30, 40, 3) and abs(math.degrees(frame.intrinsics.hfov_rad) - 90) < 1e-9


def test_pixel_noise_is_seeded_and_has_the_asked_sigma(scene):
    pose = scene.rig.kinematics().forward(0.0, -0.5)
    clean = SimCamera(scene).capture_pose(pose).image.astype(float)
    cfg = SimCameraConfig(pixel_noise_sigma=4.0, seed=3)
    a, b = SimCamera(scene, cfg).capture_pose(pose), SimCamera(scene, cfg).capture_pose(pose)
    assert np.array_equal(a.image, b.image)
    diff = a.image.astype(float) - clean
    mid = (clean > 20) & (clean < 235)  # away from clipping
    assert abs(diff[mid].std() - 4.0) < 0.3 and abs(diff[mid].mean()) < 0.2
    other = SimCamera(scene, SimCameraConfig(pixel_noise_sigma=4.0, seed=4)).capture_pose(pose)
    assert not np.array_equal(a.image, other.image)
    assert np.array_equal(a.depth_m, SimCamera(scene).capture_pose(pose).depth_m)  # depth stays exact


def test_pose_noise_perturbs_the_report_not_the_image(scene):
    pose = scene.rig.kinematics().forward(0.1, -0.3)
    small = dict(width=16, height=12)
    cfg = SimCameraConfig(pose_noise_translation_m=0.01, pose_noise_rotation_deg=0.5, seed=1, **small)
    cam = SimCamera(scene, cfg)
    frames = [cam.capture_pose(pose, stamp_s=float(i)) for i in range(200)]
    assert np.array_equal(frames[0].image, SimCamera(scene, SimCameraConfig(**small)).capture_pose(pose).image)
    offsets = np.array([f.cam2world[:3, 3] - pose[:3, 3] for f in frames])
    assert abs(offsets.std() - 0.01) < 0.0015
    angles = [
        math.degrees(math.acos(np.clip((np.trace(pose[:3, :3].T @ f.cam2world[:3, :3]) - 1) / 2, -1, 1)))
        for f in frames
    ]
    assert 0.4 < np.mean(angles) < 1.1  # |rotation vector| of a 3-D normal with sigma 0.5 deg: mean 0.8 deg
    assert all(np.allclose(f.extras["true_cam2world"], pose) for f in frames)
    assert frames[0].extras["reported_pose_error_m"] == pytest.approx(np.linalg.norm(offsets[0]))
    # turning pixel noise on does not change the pose-noise stream
    both = SimCamera(
        scene,
        SimCameraConfig(
            pose_noise_translation_m=0.01, pose_noise_rotation_deg=0.5, pixel_noise_sigma=2.0, seed=1, **small
        ),
    )
    assert np.array_equal(both.capture_pose(pose, 0.0).cam2world, frames[0].cam2world)


def test_noise_by_pose_does_not_depend_on_the_frames_rendered_before(scene):
    """With a stream, the noise of a view depends on how many frames came before it (a simulated
    gimbal arriving one tick later in another process changed a noise run's path: dev gallery:203
    first move at pan 2.2 in one process, 2.8 in another); keyed by the pose, a view gets the same
    noise whenever it is captured, another view other noise, and the seed still matters."""
    kin = scene.rig.kinematics()
    pose, other = kin.forward(0.1, -0.3), kin.forward(0.4, 0.1)
    noise = dict(pose_noise_translation_m=0.01, pose_noise_rotation_deg=0.5, pixel_noise_sigma=3.0, width=16, height=12)

    def after(n_before: int, by_pose: bool, seed: int = 1):
        cam = SimCamera(scene, SimCameraConfig(seed=seed, noise_by_pose=by_pose, **noise))
        for i in range(n_before):
            cam.capture_pose(other, stamp_s=float(i))
        return cam.capture_pose(pose, stamp_s=float(n_before))

    a, b = after(3, True), after(7, True)
    assert np.array_equal(a.cam2world, b.cam2world) and np.array_equal(a.image, b.image)
    assert not np.allclose(a.cam2world, pose)  # it is noisy
    assert not np.array_equal(a.cam2world, after(3, True, seed=2).cam2world)
    c = SimCamera(scene, SimCameraConfig(seed=1, noise_by_pose=True, **noise)).capture_pose(other)
    assert abs(c.extras["reported_pose_error_m"] - a.extras["reported_pose_error_m"]) > 1e-9  # other view, other draw
    s3, s7 = after(3, False), after(7, False)
    assert not np.array_equal(s3.cam2world, s7.cam2world)  # the stream: the count before matters
    with pytest.raises(ConfigError, match="noise_by_pose"):
        SimCameraConfig(noise_by_pose="yes")


def test_latency_shows_the_earlier_pose_and_reports_the_current(scene):
    kin = scene.rig.kinematics()
    a, b = kin.forward(-0.5, -0.3), kin.forward(0.5, -0.3)
    cam = SimCamera(scene, SimCameraConfig(latency_s=0.1))
    cam.move_to(a, 0.0)
    cam.move_to(b, 1.0)
    late = cam.capture(1.05)  # exposed at 0.95: still at a
    assert np.array_equal(late.image, render(scene, a, cam.intrinsics).rgb)
    assert np.allclose(late.cam2world, b) and np.allclose(late.extras["true_cam2world"], a)
    assert late.stamp_s == 1.05 and late.extras["exposure_stamp_s"] == pytest.approx(0.95)
    assert np.allclose(cam.capture(1.1).extras["true_cam2world"], b)  # exposed at 1.0: arrived
    assert np.allclose(cam.capture(-3.0).extras["true_cam2world"], a)  # before the first pose: the first
    assert np.allclose(cam.pose_at(0.999), a) and np.allclose(cam.pose_at(1.0), b)
    cam.move_joints(0.5, -0.3, 1.0)  # same stamp: replaces
    assert len(cam._stamps) == 2


def test_drone_scene_takes_poses_not_joints():
    spec = SceneSpec(
        objects=[SphereSpec(centre_m=(5.0, 0.0, 1.0), radius_m=1.0)],
        drone=DroneSpec(bounds_min_m=(-10, -10, 0.5), bounds_max_m=(10, 10, 30), camera=CameraSpec(32, 24, 70.0)),
    )
    scene = load_scene(spec)
    cam = SimCamera(scene)
    frame = cam.capture_pose(look_at(np.array([0.0, 0, 5]), np.array([5.0, 0, 1])))
    assert frame.image.shape == (24, 32, 3) and frame.extras["instance_id"].max() == 1
    with pytest.raises(SimCameraError, match="drone"):
        cam.move_joints(0.0, 0.0)
    assert scene.drone.contains([0, 0, 5]) and not scene.drone.contains([0, 0, 0])
    assert np.allclose(scene.drone.clamp([20, 0, 0]), [10, 0, 0.5])


def test_errors(scene):
    with pytest.raises(SimCameraError, match="no pose yet"):
        SimCamera(scene).capture(0.0)
    with pytest.raises(ConfigError, match="latency_s"):
        SimCameraConfig(latency_s=-0.1)
    with pytest.raises(ConfigError, match="supersample"):
        from_dict(SimCameraConfig, {"supersample": 9})
    with pytest.raises(ConfigError, match="sim_camera.pixel_noise_sgima: unknown key"):
        from_dict(SimCameraConfig, {"pixel_noise_sgima": 1.0}, "sim_camera")
    with pytest.raises(SimCameraError, match="load_scene"):
        SimCamera(scene.spec)
