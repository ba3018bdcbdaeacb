"""Platforms own what differs between a rig and a drone: the clamp, the arrival test, the free box,
the search space and the random poses every chance level is drawn from."""

import math

import numpy as np
import pytest

from aes_planner.config import ConfigError
from aes_planner.geometry import Intrinsics, JointCommandError, PanTiltConfig, view_to_cam2world
from aes_planner.messages import GimbalState
from aes_planner.platform import (
    RIG_FREE_BOX_HALF_M,
    DroneBox,
    DronePlatform,
    RigPlatform,
    parse_kind,
    platform_from_meta,
)
from aes_planner.search.space import FreeSpace, RigSpace, random_poses, space_for

K = Intrinsics.from_fov(32, 24, 60.0)
RIG = PanTiltConfig(base_xyz_m=(0.5, -0.2, 1.4), pan_limits_deg=(-90.0, 90.0), tilt_limits_deg=(-30.0, 30.0))
BOX = DroneBox((-1.0, -1.0, 0.5), (1.0, 1.0, 2.0))


def test_one_word_for_the_kind_and_free_is_read_as_drone():
    assert (RigPlatform(K, RIG).kind, DronePlatform(K, BOX).kind) == ("rig", "drone")
    assert [parse_kind(w) for w in ("rig", "drone", "free")] == ["rig", "drone", "drone"]
    assert parse_kind("auto", allow_auto=True) == "auto"
    for bad in ("auto", "Rig", None, 3):
        with pytest.raises(ConfigError, match="mode"):
            parse_kind(bad, "mode")


def test_rig_check_refuses_beyond_the_joint_limits_and_nan_and_never_clamps():
    rig = RigPlatform(K, RIG)
    with pytest.raises(JointCommandError, match="pan 120.000 deg is beyond the limits"):
        rig.check(math.radians(120), 0.0)
    with pytest.raises(JointCommandError, match="tilt -50.000 deg"):
        rig.check(0.0, math.radians(-50))
    assert rig.check(0.1, -0.2) == (0.1, -0.2)
    edge = math.radians(90.15)  # a servo's read-back a few ticks past its limit: passes, unchanged
    assert rig.check(edge, 0.0) == (edge, 0.0)
    with pytest.raises(JointCommandError, match="finite"):
        rig.check(float("nan"), 0.0)


def test_rig_arrival_needs_the_gimbal_still_at_our_goal():
    rig = RigPlatform(K, RIG)
    tol = math.radians(1.0)

    def st(pan, goal, moving=False):
        return GimbalState(pan, 0.0, goal, 0.0, moving=moving, stamp_s=1.0)

    assert rig.arrived(st(0.3, 0.3), 0.3, 0.0, tol)
    assert not rig.arrived(st(0.3, 0.3, moving=True), 0.3, 0.0, tol)
    assert not rig.arrived(st(0.1, 0.3), 0.3, 0.0, tol)  # still on its way
    assert not rig.arrived(st(0.2, 0.2), 0.3, 0.0, tol)  # at a goal, not ours ...
    assert rig.arrived(st(0.2, 0.2), 0.3, 0.0, tol, any_goal=True)  # ... unless the device clamped ours
    assert not rig.arrived(None, 0.3, 0.0, tol)


def test_drone_clamp_and_arrival():
    drone = DronePlatform(K, BOX)
    inside = view_to_cam2world(np.array([0.2, 0.3, 1.0, 0.5, -0.1]))
    assert drone.clamp(inside) is inside
    outside = view_to_cam2world(np.array([5.0, -3.0, 0.0, 0.5, -0.1]))
    moved = drone.clamp(outside)
    np.testing.assert_allclose(moved[:3, 3], [1.0, -1.0, 0.5])
    np.testing.assert_array_equal(moved[:3, :3], outside[:3, :3])  # the view direction kept
    near = view_to_cam2world(np.array([0.22, 0.3, 1.0, 0.5 + math.radians(0.5), -0.1]))
    assert drone.arrived(near, inside, tol_deg=1.0, tol_m=0.05)
    assert not drone.arrived(near, inside, tol_deg=0.1, tol_m=0.05)
    assert not drone.arrived(near, inside, tol_deg=1.0, tol_m=0.01)


def test_one_free_box_around_a_rig_and_a_drone_flies_its_own():
    rig, drone = RigPlatform(K, RIG), DronePlatform(K, BOX)
    box = rig.free_box()
    np.testing.assert_allclose(box.bounds_min_m, np.subtract(RIG.base_xyz_m, RIG_FREE_BOX_HALF_M))
    np.testing.assert_allclose(box.bounds_max_m, np.add(RIG.base_xyz_m, RIG_FREE_BOX_HALF_M))
    assert rig.as_drone() == DronePlatform(K, box)
    assert drone.free_box() == BOX and drone.as_drone() is drone


def test_search_space_and_random_poses_follow_the_platform():
    rig, drone = RigPlatform(K, RIG), DronePlatform(K, BOX)
    assert isinstance(space_for(rig), RigSpace) and isinstance(space_for(drone), FreeSpace)
    for platform in (rig, drone):
        space = space_for(platform)
        want = space.to_poses(space.random(32, np.random.default_rng(4))).numpy()
        got = random_poses(platform, 32, np.random.default_rng(4))
        np.testing.assert_array_equal(got, want)  # the oracle's chance level draws exactly these
    joints = space_for(rig).from_poses(random_poses(rig, 64, np.random.default_rng(1)))
    assert all(rig.kinematics.within_limits(float(p), float(t), tol_rad=1e-6) for p, t in joints)
    pos = random_poses(drone, 64, np.random.default_rng(1))[:, :3, 3]
    assert drone.drone.contains(pos).all()


def test_meta_round_trip_and_errors():
    for platform in (RigPlatform(K, RIG), DronePlatform(K, BOX)):
        assert platform_from_meta(platform.to_meta(), K) == platform
    assert platform_from_meta({}, K) is None
    with pytest.raises(ConfigError, match="meta.platform"):
        platform_from_meta({"platform": "free"}, K)  # a stored file names the kind exactly
