"""A suggestion said from the nearest photo: steps in the photo's levelled frame, turn and tilt."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.photos import moves_from_photos, relative_move


def _view(x, y, z, yaw_deg, pitch_deg):
    return view_to_cam2world(np.array([x, y, z, math.radians(yaw_deg), math.radians(pitch_deg)]))


def test_the_issue_example_reads_back():
    # the photo looks along +y (yaw 90): its right is +x (forward x up), its forward +y
    photo = _view(1.0, 2.0, 1.5, 90.0, 0.0)
    target = _view(1.0 + 0.6, 2.0, 1.6, 102.0, -5.0)
    move = relative_move("IMG_0042.jpg", photo, target)
    assert move.text() == "from IMG_0042.jpg: 0.6 m right, 0.1 m up, turn 12 deg left, tilt 5 deg down"
    assert math.isclose(move.right, 0.6, abs_tol=1e-9) and math.isclose(move.up, 0.1, abs_tol=1e-9)
    assert math.isclose(move.forward, 0.0, abs_tol=1e-9)


def test_opposite_moves_and_units():
    photo = _view(0, 0, 1.5, 0.0, -10.0)
    move = relative_move("a.jpg", photo, _view(-0.5, 0.4, 1.2, -20.0, 5.0), unit="photo spacing")
    # yaw 0 looks along +x, its right is -y: +0.4 in y is left
    assert (
        move.text() == "from a.jpg: 0.4 units left, 0.3 units down, 0.5 units back, turn 20 deg right, tilt 15 deg up"
    )
    assert relative_move("a.jpg", photo, photo).text() == "from a.jpg: stay where it was taken"


def test_the_nearest_photo_is_the_one_from_the_same_spot_looking_the_same_way():
    photos = np.stack([_view(0, 0, 1.5, 0, 0), _view(1, 0, 1.5, 0, 0), _view(1, 0, 1.5, 180, 0)])
    moves = moves_from_photos(np.stack([_view(1.05, 0, 1.5, 170, 0)]), photos, ["p0", "p1", "p2"])
    assert moves[0].photo == "p2" and moves[0].photo_index == 2
    assert "turn 10 deg right" in moves[0].text()


@given(
    st.tuples(*[st.floats(-100, 100)] * 3),
    st.floats(-179, 179),
    st.floats(-80, 80),
    st.tuples(*[st.floats(-100, 100)] * 3),
    st.floats(-179, 179),
    st.floats(-80, 80),
)
def test_moves_are_finite_and_undo_exactly(p, yaw, pitch, q, yaw2, pitch2):
    photo, target = _view(*p, yaw, pitch), _view(*q, yaw2, pitch2)
    move = relative_move("x", photo, target)
    values = [move.right, move.up, move.forward, move.turn_left_deg, move.tilt_up_deg]
    assert all(math.isfinite(v) for v in values)
    a = math.radians(yaw)
    forward, left = np.array([math.cos(a), math.sin(a), 0]), np.array([-math.sin(a), math.cos(a), 0])
    back = photo[:3, 3] + move.forward * forward - move.right * left + np.array([0, 0, move.up])
    np.testing.assert_allclose(back, target[:3, 3], atol=1e-6)
    assert abs(move.turn_left_deg) <= 180.0 + 1e-9
    assert math.isclose(move.tilt_up_deg, pitch2 - pitch, abs_tol=1e-6)
