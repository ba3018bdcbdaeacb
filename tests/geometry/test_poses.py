"""Pose conventions, 5-DoF round trips, the poles, yaw wrap, quaternions, large coordinates."""

import math

import numpy as np
import pytest
import torch
import transforms3d
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.geometry import (
    LocalFrame,
    cam2world_to_view,
    look_at,
    matrix_to_quat,
    quat_to_matrix,
    rigid_inverse,
    validate_cam2world,
    view_to_cam2world,
    world2cam,
    wrap_angle,
)
from aes_planner.geometry.poses import PoseError

yaws = st.floats(-math.pi, math.pi, allow_nan=False)
pitches = st.floats(-math.pi / 2, math.pi / 2, allow_nan=False)
coords = st.floats(-1e5, 1e5, allow_nan=False)


def angle_diff(a, b):
    return abs(float(wrap_angle(a - b)))


def test_axes_follow_the_stated_conventions():
    m = view_to_cam2world(np.array([1.0, 2.0, 3.0, 0.0, 0.0]))
    right, down, forward = m[:3, 0], m[:3, 1], m[:3, 2]
    np.testing.assert_allclose(forward, [1, 0, 0], atol=1e-15)  # yaw 0 looks along +x
    np.testing.assert_allclose(right, [0, -1, 0], atol=1e-15)  # image right is world -y (y is left)
    np.testing.assert_allclose(down, [0, 0, -1], atol=1e-15)  # image down is world -z
    np.testing.assert_allclose(m[:3, 3], [1, 2, 3])
    m = view_to_cam2world(np.array([0, 0, 0, math.pi / 2, 0.0]))
    np.testing.assert_allclose(m[:3, 2], [0, 1, 0], atol=1e-15)  # yaw +90 deg looks along +y
    m = view_to_cam2world(np.array([0, 0, 0, 0.0, math.radians(30)]))
    assert m[2, 2] > 0  # positive pitch looks up


@given(coords, coords, coords, yaws, pitches)
def test_view_round_trip(x, y, z, yaw, pitch):
    view = np.array([x, y, z, yaw, pitch])
    m = view_to_cam2world(view)
    r = m[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
    back = cam2world_to_view(m)
    np.testing.assert_array_equal(back[:3], view[:3])
    assert angle_diff(back[3], yaw) < 1e-9  # yaw survives even at the poles
    assert abs(back[4] - pitch) < 1e-7
    np.testing.assert_allclose(view_to_cam2world(back), m, atol=1e-9)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.5, math.pi])
def test_poles_are_defined_and_differentiable(pitch, yaw):
    view = torch.tensor([0.5, -0.5, 2.0, yaw, pitch], dtype=torch.float64, requires_grad=True)
    m = view_to_cam2world(view)
    assert torch.isfinite(m).all()
    forward = m[:3, 2].detach().numpy()
    np.testing.assert_allclose(forward, [0, 0, math.copysign(1, pitch)], atol=1e-15)
    # image right keeps the yaw at the pole: right = (sin yaw, -cos yaw, 0)
    np.testing.assert_allclose(m[:3, 0].detach().numpy(), [math.sin(yaw), -math.cos(yaw), 0], atol=1e-15)
    back = cam2world_to_view(m)
    back.sum().backward()
    assert torch.isfinite(view.grad).all()
    assert angle_diff(back[3].item(), yaw) < 1e-12
    assert back[4].item() == pytest.approx(pitch)


def test_pitch_beyond_the_pole_is_clamped():
    a = view_to_cam2world(np.array([0, 0, 0, 0.3, math.radians(120)]))
    b = view_to_cam2world(np.array([0, 0, 0, 0.3, math.pi / 2]))
    np.testing.assert_allclose(a, b)


@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_yaw_wraps_to_half_open_interval(yaw):
    back = cam2world_to_view(view_to_cam2world(np.array([0, 0, 0, yaw, 0.1])))
    assert -math.pi < back[3] <= math.pi
    assert angle_diff(back[3], yaw) < 1e-6 * max(1.0, abs(yaw))


def test_wrap_angle_edges():
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    t = wrap_angle(torch.tensor([-math.pi, math.pi, 0.0, 7.0], dtype=torch.float64))
    assert (t > -math.pi).all() and (t <= math.pi).all()


def test_roll_is_discarded_but_direction_kept():
    m = np.eye(4)
    m[:3, :3] = view_to_cam2world(np.array([0, 0, 0, 0.4, 0.3]))[:3, :3] @ transforms3d.axangles.axangle2mat(
        [0, 0, 1], 0.5
    )
    view = cam2world_to_view(m)
    # rolling about the optical axis keeps the forward axis: yaw/pitch unchanged
    assert angle_diff(view[3], 0.4) < 1e-12 and view[4] == pytest.approx(0.3)
    # roll of 90 degrees at the pole: the right axis still carries the yaw
    m[:3, :3] = view_to_cam2world(np.array([0, 0, 0, 0.4, math.pi / 2]))[:3, :3] @ transforms3d.axangles.axangle2mat(
        [0, 0, 1], math.pi / 2
    )
    view = cam2world_to_view(m)
    assert np.all(np.isfinite(view)) and view[4] == pytest.approx(math.pi / 2)


def test_batched_torch_matches_numpy_and_keeps_dtype():
    views = np.random.default_rng(1).uniform(-3, 3, size=(4, 3, 5))
    t = view_to_cam2world(torch.tensor(views, dtype=torch.float32))
    assert t.shape == (4, 3, 4, 4) and t.dtype == torch.float32
    np.testing.assert_allclose(t.numpy(), view_to_cam2world(views), atol=1e-5)


def test_view_gradients_match_finite_differences():
    view = torch.tensor([0.3, -1.0, 2.0, 0.7, -0.4], dtype=torch.float64, requires_grad=True)
    point = torch.tensor([2.0, 0.5, 1.0, 1.0], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda v: world2cam(view_to_cam2world(v)) @ point, (view,))


@given(coords, coords, coords, yaws, pitches)
def test_world2cam_inverts(x, y, z, yaw, pitch):
    m = view_to_cam2world(np.array([x, y, z, yaw, pitch]))
    np.testing.assert_allclose(world2cam(m) @ m, np.eye(4), atol=1e-9 * max(1, abs(x), abs(y), abs(z)))
    np.testing.assert_allclose(rigid_inverse(world2cam(m)), m, atol=1e-9)


@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 1e-3))
def test_quaternion_round_trip_matches_transforms3d(q):
    q = np.asarray(q) / np.linalg.norm(q)
    m = quat_to_matrix(q)
    np.testing.assert_allclose(m, transforms3d.quaternions.quat2mat(q), atol=1e-12)
    back = matrix_to_quat(m)
    assert back[0] >= 0
    assert abs(np.dot(back, q)) == pytest.approx(1.0, abs=1e-9)  # q and -q are one rotation


def test_zero_quaternion_is_identity_with_finite_gradient():
    q = torch.zeros(2, 4, dtype=torch.float64, requires_grad=True)
    m = quat_to_matrix(q)
    np.testing.assert_allclose(m.detach().numpy(), np.broadcast_to(np.eye(3), (2, 3, 3)))
    m.sum().backward()
    assert torch.isfinite(q.grad).all()


def test_matrix_to_quat_at_180_degree_rotations():
    for axis in np.eye(3):
        m = transforms3d.axangles.axangle2mat(axis, math.pi)
        q = matrix_to_quat(m)
        np.testing.assert_allclose(quat_to_matrix(q), m, atol=1e-12)


def test_look_at_points_the_optical_axis_at_the_target():
    eye = np.array([1.0, 2.0, 1.5])
    target = np.array([4.0, -1.0, 0.5])
    m = look_at(eye, target)
    d = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(m[:3, 2], d, atol=1e-12)
    assert abs(m[2, 0]) < 1e-12  # roll 0: image right horizontal
    up = look_at(eye, eye + [0, 0, 3.0], yaw_hint_rad=0.8)
    assert np.all(np.isfinite(up))
    assert angle_diff(cam2world_to_view(up)[3], 0.8) < 1e-12
    with pytest.raises(PoseError, match="coincide"):
        look_at(eye, eye)


def test_validate_cam2world_names_the_problem():
    good = view_to_cam2world(np.array([1, 2, 3, 0.3, 0.2]))
    np.testing.assert_array_equal(validate_cam2world(good[:3]), good)
    with pytest.raises(PoseError, match="frames\\[2\\].*orthonormal"):
        validate_cam2world(np.diag([2.0, 1, 1, 1]), name="frames[2].cam2world")
    bad = good.copy()
    bad[0, 3] = np.nan
    with pytest.raises(PoseError, match="NaN"):
        validate_cam2world(bad)
    with pytest.raises(PoseError, match="shape"):
        validate_cam2world(np.eye(3))
    with pytest.raises(PoseError, match="determinant"):
        validate_cam2world(np.diag([1.0, 1, -1, 1]))


@given(coords, coords, st.floats(-100, 100), yaws, pitches)
def test_local_frame_keeps_float32_precision_far_from_origin(x, y, dz, yaw, pitch):
    first = view_to_cam2world(np.array([x + 1e5, y + 4e6, 50.0, 0.0, 0.0]))  # UTM-like
    frame = LocalFrame.centred_on(first)
    pose = view_to_cam2world(np.array([x + 1e5 + 3.7, y + 4e6 - 12.3, 50.0 + dz, yaw, pitch]))
    local32 = frame.pose_to_local(pose).astype(np.float32)  # what the field stores
    back = frame.pose_to_world(local32)
    assert np.abs(back[:3, 3] - pose[:3, 3]).max() < 1e-4  # sub-0.1 mm
    # the naive float32 world pose loses far more (quantisation at 4e6 m is 0.25 m)
    naive = pose.astype(np.float32).astype(np.float64)
    assert np.abs(naive[:3, 3] - pose[:3, 3]).max() <= 0.5
    np.testing.assert_allclose(frame.points_to_world(frame.points_to_local(pose[:3, 3])), pose[:3, 3])
