"""Pan-tilt kinematics: forward against the 5-DoF convention, inverse round trips, limits."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.config import ConfigError, from_dict
from aes_planner.geometry import PanTilt, PanTiltConfig, cam2world_to_view, view_to_cam2world
from aes_planner.geometry.pantilt import JointCommandError

RIG = PanTilt(
    PanTiltConfig(
        base_xyz_m=(1.0, -2.0, 1.5),
        tilt_offset_m=(0.0, 0.0, 0.06),
        lever_arm_m=(0.04, 0.01, 0.03),
        pan_limits_deg=(-170, 170),
        tilt_limits_deg=(-80, 80),
    )
)
pans = st.floats(math.radians(-170), math.radians(170))
tilts = st.floats(math.radians(-80), math.radians(80))


def test_upright_rig_without_offsets_is_the_5dof_view():
    rig = PanTilt(PanTiltConfig(base_xyz_m=(1, 2, 3), tilt_offset_m=(0, 0, 0), lever_arm_m=(0, 0, 0)))
    for pan, tilt in [(0.0, 0.0), (0.7, -0.3), (-2.0, 0.9)]:
        np.testing.assert_allclose(
            rig.forward(pan, tilt), view_to_cam2world(np.array([1, 2, 3, pan, tilt])), atol=1e-12
        )


def test_lever_arm_moves_the_camera():
    m = RIG.forward(0.0, 0.0)
    np.testing.assert_allclose(m[:3, 3], [1.04, -1.99, 1.5 + 0.06 + 0.03], atol=1e-12)
    m = RIG.forward(math.pi / 2, 0.0)  # pan left 90 degrees: forward arm points along +y
    np.testing.assert_allclose(m[:3, 3], [1.0 - 0.01, -2.0 + 0.04, 1.59], atol=1e-12)


@given(pans, tilts)
def test_inverse_direction_round_trip(pan, tilt):
    forward = RIG.forward(pan, tilt)[:3, 2]
    sol = RIG.inverse_direction(forward, pan_hint_rad=pan)
    assert sol.reachable
    assert sol.error_rad < 1e-9
    assert abs(sol.pan_rad - pan) < 1e-9 and abs(sol.tilt_rad - tilt) < 1e-9


@given(pans, tilts, st.floats(0.5, 50.0))
def test_inverse_look_at_passes_through_the_target(pan, tilt, distance):
    c2w = RIG.forward(pan, tilt)
    target = c2w[:3, 3] + distance * c2w[:3, 2]
    sol = RIG.inverse_look_at(target, pan_hint_rad=0.0)
    m = RIG.forward(sol.pan_rad, sol.tilt_rad)
    ray = target - m[:3, 3]
    assert sol.reachable
    assert np.linalg.norm(np.cross(ray / np.linalg.norm(ray), m[:3, 2])) < 1e-8


def test_unreachable_aims_are_clamped_and_reported():
    sol = RIG.inverse_direction([0.0, 0.0, -1.0])  # straight down, tilt limit is -80 degrees
    assert not sol.reachable
    assert sol.tilt_rad == pytest.approx(math.radians(-80))
    assert sol.error_rad == pytest.approx(math.radians(10))
    behind = RIG.inverse_direction([-1.0, 0.0, 0.0])  # pan 180 is outside (-170, 170)
    assert not behind.reachable and abs(behind.pan_rad) == pytest.approx(math.radians(170))


def test_pole_keeps_the_pan_hint():
    rig = PanTilt(PanTiltConfig(tilt_limits_deg=(-90, 90)))
    sol = rig.inverse_direction([0.0, 0.0, 1.0], pan_hint_rad=0.7)
    assert sol.pan_rad == pytest.approx(0.7) and sol.tilt_rad == pytest.approx(math.pi / 2)
    assert sol.reachable and np.isfinite(rig.forward(sol.pan_rad, sol.tilt_rad)).all()


def test_tilted_base_round_trip():
    rig = PanTilt(PanTiltConfig(base_rpy_deg=(10.0, -20.0, 45.0)))
    c2w = rig.forward(0.4, -0.2)
    sol = rig.inverse_direction(c2w[:3, 2], pan_hint_rad=0.4)
    assert sol.pan_rad == pytest.approx(0.4) and sol.tilt_rad == pytest.approx(-0.2)
    # with a tilted base the camera rolls: the 5-DoF view keeps only the viewing direction
    view = cam2world_to_view(c2w)
    np.testing.assert_allclose(view_to_cam2world(view)[:3, 2], c2w[:3, 2], atol=1e-12)


def test_camera_roll_turns_the_image_about_the_optical_axis():
    """The roll moves neither the camera nor its optical axis: it turns the image axes (180 deg
    reverses both; +90 deg brings what was above the centre to its left), and the aim, which
    fixes the joints, ignores it."""
    base = dict(base_xyz_m=(0.5, 0.0, 1.0), lever_arm_m=(0.03, 0.01, 0.02))
    upright = PanTilt(PanTiltConfig(**base))
    flipped = PanTilt(PanTiltConfig(**base, camera_roll_deg=180.0))
    quarter = PanTilt(PanTiltConfig(**base, camera_roll_deg=90.0))
    for pan, tilt in [(0.0, 0.0), (0.7, -0.4), (-2.0, 0.9)]:
        a, b, q = upright.forward(pan, tilt), flipped.forward(pan, tilt), quarter.forward(pan, tilt)
        np.testing.assert_allclose(b[:3, 3], a[:3, 3], atol=1e-12)
        np.testing.assert_allclose(b[:3, 2], a[:3, 2], atol=1e-12)
        np.testing.assert_allclose(b[:3, :2], -a[:3, :2], atol=1e-12)
        above = a[:3, 3] + 5.0 * a[:3, 2] - a[:3, 1]  # up from the centre of the upright image
        x, y, _ = q[:3, :3].T @ (above - q[:3, 3])
        assert x == pytest.approx(-1.0) and y == pytest.approx(0.0, abs=1e-9)
        sol = flipped.inverse_direction(b[:3, 2], pan_hint_rad=pan)
        assert sol.pan_rad == pytest.approx(pan) and sol.tilt_rad == pytest.approx(tilt)


def test_a_ceiling_rig_whose_camera_flips_its_image_sees_upright():
    """Hung upside down, a rig looks down at positive tilt and its raw image is upside down
    (image down points up in the world); with camera_roll_deg 180 image down points down."""
    hung = dict(base_xyz_m=(0.0, 0.0, 2.6), base_rpy_deg=(180.0, 0.0, 0.0), tilt_limits_deg=(-20.0, 80.0))
    raw, flipped = PanTilt(PanTiltConfig(**hung)), PanTilt(PanTiltConfig(**hung, camera_roll_deg=180.0))
    for pan, tilt in raw.joint_grid(5, 4):
        assert raw.forward(pan, tilt)[2, 1] > 0.1  # world z of the image's down axis
        assert flipped.forward(pan, tilt)[2, 1] < -0.1
    assert flipped.forward(0.0, math.radians(45.0))[2, 2] == pytest.approx(-math.sqrt(0.5))


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_clamp_never_returns_outside_limits(pan, tilt):
    if not (math.isfinite(pan) and math.isfinite(tilt)):
        with pytest.raises(JointCommandError, match="finite"):
            RIG.clamp(pan, tilt)
        return
    p, t = RIG.clamp(pan, tilt)
    assert RIG.within_limits(p, t, tol_rad=0.0)


def test_forward_is_differentiable_and_batched():
    pan = torch.tensor([0.1, -0.5, 1.2], dtype=torch.float64, requires_grad=True)
    tilt = torch.tensor([0.3, 0.0, -1.0], dtype=torch.float64, requires_grad=True)
    m = RIG.forward(pan, tilt)
    assert m.shape == (3, 4, 4)
    np.testing.assert_allclose(m[1].detach().numpy(), RIG.forward(-0.5, 0.0), atol=1e-12)
    assert torch.autograd.gradcheck(lambda p, t: RIG.forward(p, t), (pan, tilt))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("kind", ["float", "numpy", "torch"])
def test_forward_refuses_non_finite_and_mismatched_joints(bad, kind):
    wrap = {"float": float, "numpy": np.asarray, "torch": torch.tensor}[kind]
    with pytest.raises(JointCommandError, match="pan_rad contains NaN or Inf"):
        RIG.forward(wrap(bad), wrap(0.1))
    with pytest.raises(JointCommandError, match="tilt_rad contains NaN or Inf"):
        RIG.forward(wrap(0.1), wrap(bad))
    with pytest.raises(JointCommandError, match=r"pan_rad \(3,\) and tilt_rad \(2,\) do not broadcast"):
        RIG.forward(np.zeros(3), np.zeros(2))


def test_joint_grid_spreads_inside_the_limits():
    grid = RIG.joint_grid(4, 3)
    assert grid.shape == (12, 2)
    assert all(RIG.within_limits(p, t) for p, t in grid)
    assert len(np.unique(grid[:, 0])) == 4 and len(np.unique(grid[:, 1])) == 3


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="tilt_limits_deg"):
        from_dict(PanTiltConfig, {"tilt_limits_deg": [-100, 30]})
    with pytest.raises(ConfigError, match="rig.pan_limits_deg: min must be below max"):
        from_dict(PanTiltConfig, {"pan_limits_deg": [30, -30]}, "rig")
    with pytest.raises(ConfigError, match=r"rig.lever_arm: unknown key"):
        from_dict(PanTiltConfig, {"lever_arm": [0, 0, 0]}, "rig")
    with pytest.raises(ConfigError, match=r"base_xyz_m: expected 3 values"):
        from_dict(PanTiltConfig, {"base_xyz_m": [0, 0]})
    with pytest.raises(ConfigError, match=r"base_xyz_m\[1\]: expected a number"):
        from_dict(PanTiltConfig, {"base_xyz_m": [0, "x", 1]})
    with pytest.raises(ConfigError, match=r"rig.camera_roll_deg: must be in \[-360, 360\]"):
        from_dict(PanTiltConfig, {"camera_roll_deg": 540.0}, "rig")
    with pytest.raises(ConfigError, match="camera_roll_deg: expected finite"):
        PanTiltConfig(camera_roll_deg=float("nan"))


@pytest.mark.parametrize("n", [1, 2, 4, 7])
def test_sweep_spreads_over_the_range(n):
    joints = RIG.sweep(n)
    assert joints.shape == (n, 2)
    assert all(RIG.within_limits(p, t) for p, t in joints)
    assert np.all(np.diff(joints[:, 0]) > 0)  # left to right
    if n > 2:
        span = RIG.pan_limits_rad[1] - RIG.pan_limits_rad[0]
        assert joints[-1, 0] - joints[0, 0] == pytest.approx(0.8 * span)
        assert len(np.unique(joints[:, 1])) == 2  # tilt zig-zags


@given(pans, tilts, st.floats(-3.0, 3.0), st.booleans())
def test_direction_joints_are_inverse_directions_joints_before_clamping(pan, tilt, hint, mount):
    """The search samples its trajectory with direction_joints (no aim-error forward pass): the
    same joints as inverse_direction, which clamps them."""
    rig = RIG if not mount else PanTilt(PanTiltConfig(camera_mount_rpy_deg=(1.5, -2.0, 0.7), tilt_limits_deg=(-60, 40)))
    axis = rig.forward(pan, tilt)[:3, 2]
    sol = rig.inverse_direction(axis, pan_hint_rad=hint)
    assert rig.clamp(*rig.direction_joints(axis, pan_hint_rad=hint)) == (sol.pan_rad, sol.tilt_rad)
    with pytest.raises(JointCommandError, match="direction"):
        rig.direction_joints([0.0, 0.0, 0.0])
