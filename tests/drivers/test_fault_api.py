"""The fault-injection API shared by EmulatedPanTilt (real driver on the emulator) and SimPanTilt:
faults injected mid-run, what each gimbal does about them, and that no goal leaves the limits."""

import math
import os
import threading

import pytest

from aes_planner.devices import (
    GimbalCommError,
    GimbalFaults,
    GimbalHardwareError,
    GimbalPortLostError,
    GimbalTimeoutError,
    make_device,
)
from aes_planner.drivers.sim_gimbal import SimClock, SimPanTilt, SimPanTiltConfig
from tests.helpers import wait_for


@pytest.fixture
def emulated(fast):
    """Settings of a quick emulated_pan_tilt (the conftest's FAST, with a real motion profile)."""
    return dict(fast, profile_velocity_deg_s=30.0, profile_acceleration_deg_s2=300.0)


@pytest.fixture(params=["emulated", "sim"])
def any_gimbal(request, emulated):
    if request.param == "emulated":
        g = make_device({"type": "emulated_pan_tilt", **emulated})
    else:
        g = SimPanTilt(SimPanTiltConfig(max_velocity_deg_s=30.0, poll_interval_s=0.002), clock=SimClock())
    g.connect()
    try:
        yield g
    finally:
        g.disconnect()


def test_both_gimbals_offer_the_fault_api(any_gimbal):
    assert isinstance(any_gimbal, GimbalFaults)


def test_lost_and_corrupt_replies_within_the_retries_are_survived(any_gimbal):
    any_gimbal.move_to(0.1, 0.0)
    any_gimbal.inject_comm_faults(lost=1, corrupt=1)
    assert any_gimbal.state().goal_pan_rad == pytest.approx(0.1, abs=2e-3)
    any_gimbal.inject_comm_faults(delayed=1, delay_s=0.01)
    assert any_gimbal.state().goal_pan_rad == pytest.approx(0.1, abs=2e-3)


def test_a_dead_bus_is_fatal_then_recovers(any_gimbal):
    any_gimbal.move_to(0.1, 0.0)
    any_gimbal.inject_comm_faults(lost=40)  # more than every retry of a call (2 replies a sync read)
    with pytest.raises(GimbalCommError):
        any_gimbal.state()
    any_gimbal.clear_faults()
    any_gimbal.move_to(0.2, 0.0)  # takes control again once the bus answers
    assert any_gimbal.wait_until_reached(5.0).pan_rad == pytest.approx(0.2, abs=math.radians(1.0))


def test_overload_mid_move_stops_until_reboot(any_gimbal):
    any_gimbal.move_to(math.radians(60), 0.0)
    any_gimbal.inject_hardware_error("pan", "overload")
    with pytest.raises(GimbalHardwareError) as info:
        any_gimbal.wait_until_reached(5.0)
    assert info.value.faults == {"pan": ("overload",)}
    with pytest.raises(GimbalHardwareError, match="refusing to move"):
        any_gimbal.move_to(0.0, 0.0)
    any_gimbal.reboot()
    any_gimbal.move_to(0.05, 0.0)
    assert any_gimbal.wait_until_reached(5.0).hardware_error == ()


def test_a_stall_times_out_and_a_vanished_port_comes_back(any_gimbal):
    any_gimbal.inject_stall("tilt")
    any_gimbal.move_to(0.0, math.radians(20))
    with pytest.raises(GimbalTimeoutError):
        any_gimbal.wait_until_reached(0.3)
    any_gimbal.inject_stall("tilt", False)
    any_gimbal.vanish_port()
    with pytest.raises(GimbalPortLostError):
        any_gimbal.state()
    any_gimbal.restore_port()
    assert any_gimbal.wait_until_reached(5.0).tilt_rad == pytest.approx(math.radians(20), abs=math.radians(1.0))


def test_bad_fault_arguments_are_refused(any_gimbal):
    for kwargs in ({"lost": -1}, {"corrupt": 1.5}, {"delayed": 1, "delay_s": math.nan}, {"delay_s": 1e6}):
        with pytest.raises(ValueError):
            any_gimbal.inject_comm_faults(**kwargs)
    with pytest.raises(ValueError):
        any_gimbal.inject_hardware_error("roll", "overload")
    with pytest.raises(ValueError):
        any_gimbal.inject_hardware_error("pan", "gremlins")


def test_emulated_faults_from_another_thread_while_moving(emulated):
    """The closed-loop situation: one thread drives, another injects; goals stay in the limits."""
    g = make_device({"type": "emulated_pan_tilt", **emulated, "retries": 2})
    with g:
        link = g.config.port
        assert os.path.islink(link)  # a private symlink: found again after restore_port()
        errors, stop = [], threading.Event()

        def drive():
            k = 0
            while not stop.is_set():
                k += 1
                try:
                    g.move_to(math.radians(10 * (k % 7) - 30), math.radians(5 * (k % 5)))
                    g.state()
                except (GimbalCommError, GimbalPortLostError, GimbalHardwareError) as exc:
                    errors.append(type(exc).__name__)

        t = threading.Thread(target=drive)
        t.start()
        try:
            g.inject_comm_faults(lost=2, corrupt=2, delayed=1, delay_s=0.02)
            stop.wait(0.2)
            g.vanish_port()
            wait_for(lambda: "GimbalPortLostError" in errors, timeout_s=30.0)  # however slow the host
            g.restore_port()
            stop.wait(0.2)
        finally:
            stop.set()
            t.join(10.0)
        assert not t.is_alive()
        assert "GimbalPortLostError" in errors
        g.clear_faults()
        g.move_to(0.0, 0.0)
        assert g.wait_until_reached(5.0).pan_rad == pytest.approx(0.0, abs=math.radians(1.0))
        for dxl_id, ticks in g.emulator.goal_log:
            lo, hi = g.config.calibration("pan" if dxl_id == 1 else "tilt").tick_limits
            assert lo <= ticks <= hi
    assert not os.path.lexists(link)  # the private link and its folder are gone
