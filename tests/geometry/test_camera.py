"""Intrinsics: pixel centres at +0.5, projection round trips, validation."""

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from aes_planner.geometry import Intrinsics
from aes_planner.geometry.camera import IntrinsicsError


def test_pixel_centres_are_at_half_pixels():
    k = Intrinsics.from_fov(4, 2, 90.0)
    assert k.cx == 2.0 and k.cy == 1.0 and k.fx == pytest.approx(2.0)
    d = k.pixel_directions()
    assert d.shape == (2, 4, 3)
    # pixel (0, 0) centre is (0.5, 0.5): x = (0.5 - 2) / 2
    np.testing.assert_allclose(d[0, 0], [-0.75, -0.25, 1.0])
    # the image is symmetric about the principal point
    np.testing.assert_allclose(d[0, 0, :2], -d[1, 3, :2])
    assert k.hfov_rad == pytest.approx(math.pi / 2)


@given(st.floats(1.0, 1e5), st.integers(1, 4096), st.integers(1, 4096), st.floats(0.01, 1e4))
def test_project_unproject_round_trip(f, w, h, depth):
    try:
        k = Intrinsics(f, f, w / 2, h / 2, w, h)
    except IntrinsicsError as exc:  # a 1 px image at f = 1e5 px: 0.0006 deg, no camera (tested there)
        assert exc.problem is not None
        assume(False)
    uv = np.array([[0.5, 0.5], [w - 0.5, h - 0.5], [w / 3, h / 5]])
    p = k.unproject(uv, np.full(3, depth))
    np.testing.assert_allclose(p[:, 2], depth)
    np.testing.assert_allclose(k.project(p), uv, rtol=1e-9, atol=1e-9 * max(w, h))


def test_supersampled_rays_average_to_pixel_centre():
    k = Intrinsics(10.0, 12.0, 3.0, 2.0, 6, 4)
    d = k.pixel_directions(supersample=3).reshape(4, 3, 6, 3, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(d, k.pixel_directions(), atol=1e-12)


def test_normalized_round_trip_and_scaling():
    k = Intrinsics(300.0, 310.0, 160.0, 118.0, 320, 240)
    assert Intrinsics.from_normalized(*k.to_normalized(), 320, 240) == k
    half = k.scaled(160, 120)
    assert half.fx == 150 and half.cy == 59
    assert half.hfov_rad == pytest.approx(k.hfov_rad)
    assert Intrinsics.from_matrix(k.K, 320, 240) == k


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(fx=0.0, fy=1.0, cx=0, cy=0, width=1, height=1), "positive"),
        (dict(fx=1.0, fy=float("nan"), cx=0, cy=0, width=1, height=1), "fy"),
        (dict(fx=1.0, fy=1.0, cx=0, cy=0, width=0, height=1), "width"),
    ],
)
def test_invalid_intrinsics_name_the_field(kwargs, match):
    with pytest.raises(IntrinsicsError, match=match):
        Intrinsics(**kwargs)


@pytest.mark.parametrize("hfov_deg", [5e-324, 1e-310, 2.2e-308])
def test_a_field_of_view_too_narrow_for_a_finite_focal_length_is_a_config_error(hfov_deg):
    # radians() of a denormal angle underflows to 0 (tan 0 = 0), or the focal length overflows
    with pytest.raises(IntrinsicsError, match="hfov_deg"):
        Intrinsics.from_fov(12, 9, hfov_deg)


@given(st.floats(1e-300, 179.999))
def test_from_fov_gives_finite_intrinsics_or_a_clear_error(hfov_deg):
    try:
        k = Intrinsics.from_fov(640, 480, hfov_deg)
    except IntrinsicsError as exc:
        assert "hfov_deg" in str(exc)
    else:
        assert math.isfinite(k.fx) and k.fx > 0
