"""Slerp + lerp along an input trajectory: endpoints, identical and nearly opposite orientations."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.geometry import interpolate_poses, interpolate_views, slerp, view_to_cam2world
from aes_planner.geometry.poses import PoseError, matrix_to_quat, quat_to_matrix


def rot_angle(a, b):
    r = a[:3, :3].T @ b[:3, :3]
    return math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))


def test_endpoints_and_counts():
    views = np.array([[0, 0, 1, 0.0, 0.0], [1, 0, 1, 0.5, 0.2], [2, 1, 1, 1.0, -0.3]])
    poses = view_to_cam2world(views)
    out = interpolate_poses(poses, samples_per_segment=4)
    assert out.shape == (2 * 4 + 1, 4, 4)
    np.testing.assert_allclose(out[0], poses[0], atol=1e-12)
    np.testing.assert_allclose(out[4], poses[1], atol=1e-12)
    np.testing.assert_allclose(out[-1], poses[2], atol=1e-12)
    np.testing.assert_allclose(out[2, :3, 3], (poses[0, :3, 3] + poses[1, :3, 3]) / 2)
    assert interpolate_poses(poses, 4, include_end=False).shape == (8, 4, 4)
    assert interpolate_poses(poses[:1], 4).shape == (1, 4, 4)


@given(
    st.integers(1, 6),
    st.integers(1, 40),
    st.booleans(),
    st.integers(0, 2**32 - 1),
    st.sampled_from([1e-3, 1.0, 1e3]),
)
def test_each_sample_is_its_own_slerp_bit_for_bit(n, samples, include_end, seed, scale):
    """The samples' rotations come from one batched conversion: each row equals a slerp and a
    conversion of its own, bit for bit (the closed loop's searches start from these poses)."""
    from aes_planner.geometry.trajectory import _segment_params

    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = quat_to_matrix(rng.normal(size=(n, 4)))
    poses[:, :3, 3] = rng.normal(size=(n, 3)) * scale
    quats = matrix_to_quat(poses[:, :3, :3])
    want = []
    for i, t in _segment_params(n, samples, include_end):
        j = min(i + 1, n - 1)
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(slerp(quats[i], quats[j], t))
        m[:3, 3] = (1.0 - t) * poses[i, :3, 3] + t * poses[j, :3, 3]
        want.append(m)
    got = interpolate_poses(poses, samples, include_end)
    assert got.dtype == np.float64 and np.array_equal(got, np.stack(want))


def test_identical_orientations_stay_put():
    pose = view_to_cam2world(np.array([0, 0, 0, 0.3, 0.1]))
    other = pose.copy()
    other[:3, 3] = [1, 2, 3]
    out = interpolate_poses(np.stack([pose, other]), 10)
    for m in out:
        np.testing.assert_allclose(m[:3, :3], pose[:3, :3], atol=1e-12)


@given(st.floats(1e-9, 1e-3))
def test_nearly_opposite_orientations_interpolate_evenly(eps):
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = quat_to_matrix(np.array([math.cos((math.pi - eps) / 2), 0, 0, math.sin((math.pi - eps) / 2)]))
    out = interpolate_poses(np.stack([a, b]), 8)
    assert np.all(np.isfinite(out))
    total = rot_angle(a, b)
    steps = [rot_angle(out[i], out[i + 1]) for i in range(8)]
    np.testing.assert_allclose(steps, total / 8, atol=1e-7)


def test_exactly_opposite_orientations_have_a_midpoint():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = np.array([0.0, 0, 0, 1])  # 180 degrees about z
    mid = slerp(q0, q1, 0.5)
    assert np.linalg.norm(mid) == pytest.approx(1.0)
    assert rot_angle(np.pad(quat_to_matrix(mid), (0, 1)), np.pad(quat_to_matrix(q0), (0, 1))) == pytest.approx(
        math.pi / 2
    )


def test_slerp_takes_the_short_way():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = -matrix_to_quat(quat_to_matrix(np.array([math.cos(0.2), 0, math.sin(0.2), 0])))
    mid = slerp(q0, q1, 0.5)
    assert rot_angle(np.pad(quat_to_matrix(mid), (0, 1)), np.eye(4)) == pytest.approx(0.2, abs=1e-12)


def test_views_cross_the_yaw_seam_the_short_way():
    views = np.array([[0, 0, 0, math.radians(170), 0.0], [0, 0, 0, math.radians(-170), 0.4]])
    out = interpolate_views(views, 2)
    assert math.degrees(out[1, 3]) == pytest.approx(180.0)
    assert out[1, 4] == pytest.approx(0.2)
    assert np.all(out[:, 3] <= math.pi) and np.all(out[:, 3] > -math.pi)


def test_bad_inputs_name_the_problem():
    with pytest.raises(PoseError, match="samples_per_segment"):
        interpolate_views(np.zeros((2, 5)), 0)
    with pytest.raises(PoseError, match="NaN"):
        interpolate_views(np.full((2, 5), np.nan), 3)
    with pytest.raises(PoseError, match=r"\[N, 4, 4\]"):
        interpolate_poses(np.zeros((2, 3, 3)), 3)
