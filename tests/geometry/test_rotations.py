"""The one numpy rotation module (on transforms3d): round trips, the poles, quaternion sign."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.geometry.rotations import (
    matrix_to_quat,
    matrix_to_rpy,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rpy_to_matrix,
)

angle = st.floats(-math.pi + 1e-6, math.pi - 1e-6)


@settings(max_examples=200, deadline=None)
@given(angle, st.floats(-math.pi / 2 + 1e-4, math.pi / 2 - 1e-4), angle)
def test_rpy_round_trips_and_is_z_y_x(roll, pitch, yaw):
    r = rpy_to_matrix(roll, pitch, yaw)
    np.testing.assert_allclose(r, rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), atol=1e-12)
    np.testing.assert_allclose(matrix_to_rpy(r), (roll, pitch, yaw), atol=1e-6)


@given(angle)
def test_at_the_poles_the_turn_is_yaw(yaw):
    for pitch in (-math.pi / 2, math.pi / 2):
        roll_back, pitch_back, yaw_back = matrix_to_rpy(rpy_to_matrix(0.0, pitch, yaw))
        assert roll_back == 0.0 and math.isclose(pitch_back, pitch, abs_tol=1e-9)
        np.testing.assert_allclose(rpy_to_matrix(0.0, pitch, yaw_back), rpy_to_matrix(0.0, pitch, yaw), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 1e-3))
def test_quaternions_are_wxyz_normalised_with_w_non_negative(q):
    r = quat_to_matrix(q)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)
    back = matrix_to_quat(r)
    assert back[0] >= 0 and math.isclose(np.linalg.norm(back), 1.0)
    np.testing.assert_allclose(quat_to_matrix(back), r, atol=1e-9)
    np.testing.assert_allclose(quat_to_matrix([math.cos(0.4), 0, 0, math.sin(0.4)]), rot_z(0.8), atol=1e-12)
