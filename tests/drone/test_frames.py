"""NED/ENU, FRD/FLU, quaternions and the camera pose against hand-computed cases."""

import math

import numpy as np
import pytest
import torch

from aes_planner.drone import frames as fr
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world


def test_positions_swap_and_flip():
    # 1 m north, 2 m east, 3 m down = 2 m east, 1 m north, 3 m below the origin
    assert np.allclose(fr.ned_to_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    assert np.allclose(fr.enu_to_ned([2.0, 1.0, -3.0]), [1.0, 2.0, 3.0])
    p = np.random.default_rng(0).normal(size=(5, 3))
    assert np.allclose(fr.enu_to_ned(fr.ned_to_enu(p)), p)


@pytest.mark.parametrize(
    "heading_deg, yaw_enu_deg",
    [(0, 90), (90, 0), (180, -90), (-90, 180), (45, 45), (135, -45)],
)
def test_heading_to_enu_yaw(heading_deg, yaw_enu_deg):
    # heading 0 = north = ENU yaw +90 deg; heading 90 (east) = ENU yaw 0
    got = math.degrees(fr.heading_ned_to_enu(math.radians(heading_deg)))
    assert got == pytest.approx(yaw_enu_deg, abs=1e-9)
    assert math.degrees(fr.heading_enu_to_ned(math.radians(yaw_enu_deg))) == pytest.approx(
        math.degrees(fr.wrap(math.radians(heading_deg))), abs=1e-9
    )


def test_euler_and_body_flu():
    # heading east (yaw 90 deg): body forward = NED east = ENU +x; body left (FLU +y) = north = ENU +y
    r_ned_frd = fr.euler_to_matrix(0.0, 0.0, math.pi / 2)
    assert np.allclose(r_ned_frd @ [1, 0, 0], [0, 1, 0])
    r_enu_flu = fr.body_flu_in_enu(r_ned_frd)
    assert np.allclose(r_enu_flu, np.eye(3))
    # heading north: FLU forward = ENU +y, left = ENU -x (west), up = up
    r = fr.body_flu_in_enu(fr.euler_to_matrix(0.0, 0.0, 0.0))
    assert np.allclose(r[:, 0], [0, 1, 0]) and np.allclose(r[:, 1], [-1, 0, 0]) and np.allclose(r[:, 2], [0, 0, 1])
    # nose up 30 deg (positive pitch) heading north: forward points north and up
    r = fr.euler_to_matrix(0.0, math.radians(30), 0.0)
    assert np.allclose(r @ [1, 0, 0], [math.cos(math.radians(30)), 0, -0.5])
    # roll right 90 deg: body right (FRD +y) points down
    r = fr.euler_to_matrix(math.pi / 2, 0.0, 0.0)
    assert np.allclose(r @ [0, 1, 0], [0, 0, 1])
    for angles in [(0.1, -0.4, 2.0), (-0.3, 0.2, -2.9)]:
        assert np.allclose(fr.matrix_to_euler(fr.euler_to_matrix(*angles)), angles)


def test_quaternions():
    # 90 deg about z: (cos 45, 0, 0, sin 45)
    q = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    assert np.allclose(fr.quat_to_matrix(q), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(fr.quat_to_matrix(q), fr.euler_to_matrix(0, 0, math.pi / 2))
    assert np.allclose(fr.matrix_to_quat(fr.quat_to_matrix(q)), q)
    assert np.allclose(fr.quat_to_matrix(2 * q), fr.quat_to_matrix(q))  # normalised


def test_optical_frame_in_frd():
    # optical z (forward) = FRD x, optical x (right) = FRD y, optical y (down) = FRD z
    assert np.allclose(fr.R_FRD_CV @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(fr.R_FRD_CV @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(fr.R_FRD_CV @ [0, 1, 0], [0, 0, 1])


def test_camera_pose_hand_case():
    # vehicle 10 m north, 5 m east, 2 m up (z -2), heading east, gimbal level: the camera looks
    # along ENU +x from (5, 10, 2), image right = ENU -y (south), image down = ENU -z
    r_g = fr.camera_rotation_ned(math.pi / 2, pitch_rad=0.0)
    c2w = fr.pose_to_cam2world([10.0, 5.0, -2.0], r_g)
    assert np.allclose(c2w[:3, 3], [5.0, 10.0, 2.0])
    assert np.allclose(c2w[:3, 2], [1, 0, 0]) and np.allclose(c2w[:3, 0], [0, -1, 0])
    assert np.allclose(c2w[:3, 1], [0, 0, -1])
    # gimbal pitched 30 deg down: forward = (cos 30, 0, -sin 30) in ENU
    c2w = fr.pose_to_cam2world([0, 0, 0], fr.camera_rotation_ned(math.pi / 2, pitch_rad=math.radians(-30)))
    assert np.allclose(c2w[:3, 2], [math.cos(math.radians(30)), 0, -0.5])
    # a camera 0.1 m forward and 0.05 m below the vehicle's origin, heading north: 0.1 m north, 0.05 m lower
    c2w = fr.pose_to_cam2world(
        [0, 0, 0], fr.camera_rotation_ned(0.0), fr.euler_to_matrix(0, 0, 0), mount_frd_m=(0.1, 0.0, 0.05)
    )
    assert np.allclose(c2w[:3, 3], [0.0, 0.1, -0.05])
    # the world origin moved: ENU offset added
    c2w = fr.pose_to_cam2world([1, 2, -3], fr.camera_rotation_ned(0.0), origin_m=[100, 200, 0])
    assert np.allclose(c2w[:3, 3], [102, 201, 3])


def test_gimbal_quaternion_vehicle_and_earth_frames():
    # vehicle heading 90 (east); the gimbal reports yaw +90 relative to the vehicle, pitch -20:
    # the camera looks south (heading 180), 20 deg down
    q_rel = fr.matrix_to_quat(fr.euler_to_matrix(0.0, math.radians(-20), math.pi / 2))
    r = fr.camera_rotation_ned(math.pi / 2, q_rel, yaw_in_earth_frame=False)
    roll, pitch, yaw = fr.matrix_to_euler(r)
    assert math.degrees(yaw) == pytest.approx(180.0, abs=1e-9) or math.degrees(yaw) == pytest.approx(-180.0)
    assert math.degrees(pitch) == pytest.approx(-20.0)
    # the same quaternion in the earth frame means heading 90 (east), whatever the vehicle does
    r = fr.camera_rotation_ned(-1.0, q_rel, yaw_in_earth_frame=True)
    assert math.degrees(fr.matrix_to_euler(r)[2]) == pytest.approx(90.0)
    c2w = fr.pose_to_cam2world([0, 0, 0], r)
    assert np.allclose(c2w[:3, 2], [math.cos(math.radians(20)), 0, -math.sin(math.radians(20))])


@pytest.mark.parametrize("axes", [2, 3])
def test_view_round_trip_matches_the_package_view(axes):
    rng = np.random.default_rng(3)
    for _ in range(20):
        view = np.array([*rng.uniform(-5, 5, 3), rng.uniform(-math.pi, math.pi), rng.uniform(-1.4, 1.4)])
        vehicle_heading = float(rng.uniform(-math.pi, math.pi))
        p_ned, heading, gpitch, gyaw = fr.view_to_setpoint(view, axes, vehicle_heading, origin_m=[1.0, -2.0, 0.5])
        if axes == 2:
            assert gyaw == 0.0
            r = fr.camera_rotation_ned(heading, pitch_rad=gpitch)
        else:
            assert heading == pytest.approx(fr.wrap(vehicle_heading))
            q_rel = fr.matrix_to_quat(fr.euler_to_matrix(0.0, gpitch, gyaw))
            r = fr.camera_rotation_ned(heading, q_rel)
        c2w = fr.pose_to_cam2world(p_ned, r, origin_m=[1.0, -2.0, 0.5])
        expected = view_to_cam2world(torch.tensor(view)).numpy()
        assert np.allclose(c2w, expected, atol=1e-9)
        assert np.allclose(cam2world_to_view(c2w)[:3], view[:3])


def test_matrix_to_quat_matches_the_package():
    from aes_planner.geometry.poses import matrix_to_quat

    rng = np.random.default_rng(5)
    for _ in range(50):
        r = fr.euler_to_matrix(*rng.uniform(-3, 3, 3))
        q = fr.matrix_to_quat(r)
        ref = np.asarray(matrix_to_quat(r))
        assert np.allclose(q, ref if ref[0] >= 0 else -ref, atol=1e-9)
        assert np.allclose(fr.quat_to_matrix(q), r, atol=1e-9)
    for r in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):  # w = 0
        assert np.allclose(fr.quat_to_matrix(fr.matrix_to_quat(r)), r)
