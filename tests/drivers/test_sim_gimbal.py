"""The in-process simulated gimbal (``sim_pan_tilt``): motion limits, clamping, NaN, injected faults."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.config import ConfigError
from aes_planner.devices import (
    Gimbal,
    GimbalCommError,
    GimbalHardwareError,
    GimbalPortLostError,
    GimbalTimeoutError,
    make_device,
)
from aes_planner.drivers.sim_gimbal import SimClock, SimPanTilt, SimPanTiltConfig
from aes_planner.geometry.pantilt import JointCommandError


def _sim(**config):
    clock = SimClock(100.0)
    return SimPanTilt(SimPanTiltConfig(**config), clock=clock), clock


def test_registered_as_a_launch_type():
    g = make_device({"type": "sim_pan_tilt", "max_velocity_deg_s": 30.0, "tilt_limits_deg": [-30, 45]}, "gimbal")
    assert isinstance(g, SimPanTilt) and isinstance(g, Gimbal) and not g.connected
    assert g.config.max_velocity_deg_s == 30.0 and g.config.tilt_limits_deg == (-30.0, 45.0)
    with pytest.raises(ConfigError, match="gimbal.port: unknown key"):
        make_device({"type": "sim_pan_tilt", "port": "/dev/x"}, "gimbal")
    with pytest.raises(ConfigError, match="gimbal.max_velocity_deg_s"):
        make_device({"type": "sim_pan_tilt", "max_velocity_deg_s": 1e30}, "gimbal")


def test_a_trapezoidal_move_in_simulated_time():
    g, clock = _sim(max_velocity_deg_s=60.0, max_acceleration_deg_s2=300.0, arrival_tolerance_deg=0.01)
    with g:
        assert g.move_to(math.radians(60), 0.0) == (math.radians(60), 0.0)
        assert g.state().moving and g.torque_on
        t0, prev = clock(), g.state()
        peak_v = 0.0
        while g.state().moving:
            clock.advance(0.01)
            now = g.state()
            v = (now.pan_rad - prev.pan_rad) / 0.01
            assert v <= math.radians(60.0) + 1e-9
            peak_v, prev = max(peak_v, v), now
        # 0.2 s up to 60 deg/s, 0.8 s cruising, 0.2 s down: 1.2 s
        assert clock() - t0 == pytest.approx(1.2, abs=0.03)
        assert peak_v == pytest.approx(math.radians(60.0), rel=1e-6)
        assert prev.pan_deg == pytest.approx(60.0) and prev.tilt_deg == 0.0 and prev.stamp_s == clock()


def test_wait_runs_faster_than_real_time_and_clamps():
    g, clock = _sim(max_velocity_deg_s=5.0)
    with g:
        pan, tilt = g.move_to(10.0, -10.0)  # far outside the limits
        assert (math.degrees(pan), math.degrees(tilt)) == pytest.approx((150.0, -60.0))
        t0 = clock()
        st_ = g.wait_until_reached(60.0)
        assert clock() - t0 > 30.0  # 150 deg at 5 deg/s, in simulated time
        assert (st_.pan_deg, st_.tilt_deg) == pytest.approx((150.0, -60.0), abs=1.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1", None])
def test_nan_and_junk_are_refused_and_change_nothing(bad):
    g, _ = _sim()
    with g:
        g.move_to(0.1, 0.1)
        with pytest.raises(JointCommandError):
            g.move_to(bad, 0.0)
        with pytest.raises(JointCommandError):
            g.move_to(0.0, bad)
        assert g.commands == [(0.1, 0.1)] and g.state().goal_pan_rad == 0.1


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True, width=64),
            st.floats(-10, 10),
            st.floats(0.0, 5.0),
        ),
        max_size=8,
    )
)
def test_joints_stay_inside_the_limits_and_finite(steps):
    g, clock = _sim(tilt_limits_deg=(-30.0, 80.0), max_velocity_deg_s=200.0, max_acceleration_deg_s2=5000.0)
    with g:
        for pan, tilt, dt in steps:
            try:
                g.move_to(pan, tilt)
            except JointCommandError:
                assert not (math.isfinite(pan) and math.isfinite(tilt))
            clock.advance(dt)
            s = g.state()
            for v in (s.pan_rad, s.tilt_rad, s.goal_pan_rad, s.goal_tilt_rad):
                assert math.isfinite(v)
            assert -150.0 - 1e-9 <= s.pan_deg <= 150.0 + 1e-9 and -30.0 - 1e-9 <= s.tilt_deg <= 80.0 + 1e-9


def test_hardware_error_stops_latches_and_clears_on_reboot():
    g, clock = _sim(max_velocity_deg_s=10.0)
    with g:
        g.move_to(math.radians(90), 0.0)
        clock.advance(1.0)
        g.inject_hardware_error("pan", "overload")
        stopped = g.state()
        assert stopped.hardware_error == ("pan: overload",) and not g.torque_on and not stopped.moving
        clock.advance(5.0)
        assert g.state().pan_rad == stopped.pan_rad  # torque off: it stays where it stopped
        with pytest.raises(GimbalHardwareError, match="refusing to move") as info:
            g.move_to(0.0, 0.0)
        assert info.value.faults == {"pan": ("overload",)}
        with pytest.raises(GimbalHardwareError, match="stopped on the way"):
            g.wait_until_reached()
        g.reboot()
        assert g.state().hardware_error == () and not g.torque_on
        g.move_to(0.0, 0.0)
        assert g.wait_until_reached().pan_rad == pytest.approx(0.0, abs=math.radians(1.0))


def test_comm_faults_are_retried_then_fatal_with_torque_off():
    g, clock = _sim(retries=3)
    with g:
        g.move_to(0.5, 0.0)
        g.inject_comm_faults(lost=2, corrupt=1)  # 3 bad replies: the 4th try of one call succeeds
        g.state()
        g.inject_comm_faults(delayed=1, delay_s=0.25)
        t0 = clock()
        g.state()
        assert clock() - t0 == pytest.approx(0.25)
        g.inject_comm_faults(lost=4)
        with pytest.raises(GimbalCommError, match="no valid reply after 4 tries"):
            g.state()
        assert not g.torque_on
        g.move_to(0.0, 0.0)  # takes control again once replies come back
        assert g.torque_on


def test_a_vanished_port_and_a_stall():
    g, clock = _sim()
    with g:
        g.move_to(0.2, 0.0)
        g.vanish_port()
        with pytest.raises(GimbalPortLostError):
            g.state()
        with pytest.raises(GimbalPortLostError):
            g.move_to(0.0, 0.0)
        g.restore_port()
        g.inject_stall("tilt")
        g.move_to(0.2, 0.3)
        with pytest.raises(GimbalTimeoutError, match="within 2 s"):
            g.wait_until_reached(2.0)
        g.inject_stall("tilt", False)
        assert g.wait_until_reached().tilt_rad == pytest.approx(0.3, abs=math.radians(1.0))
    with pytest.raises(ValueError):
        g.inject_hardware_error("roll")
    with pytest.raises(ValueError):
        g.inject_comm_faults(lost=-1)


def test_real_clock_by_default():
    with SimPanTilt(SimPanTiltConfig(max_velocity_deg_s=3000.0, max_acceleration_deg_s2=1e5)) as g:
        g.move_to(0.1, -0.1)
        st_ = g.wait_until_reached(5.0)
        assert st_.pan_rad == pytest.approx(0.1, abs=0.02) and abs(st_.stamp_s - __import__("time").time()) < 5.0
    assert not g.torque_on and not g.connected
