"""Fixtures for the driver tests: an emulator in a background thread and a driver connected to it.

Every fixture stops what it started, whatever the test did; every wait has a timeout.
Short timeouts keep fault tests quick: the SDK waits 2 x latency_timer_ms + 2 ms for a reply.
"""

import pytest

from aes_planner.drivers.dynamixel import DynamixelPanTilt, DynamixelPanTiltConfig
from aes_planner.drivers.emulator import ServoEmulator

# Quick motion and short reply timeouts, for tests against the in-process emulator.
FAST = dict(
    profile_velocity_deg_s=0.0,
    profile_acceleration_deg_s2=0.0,
    latency_timer_ms=5.0,
    backoff_s=0.001,
    move_timeout_s=3.0,
    poll_interval_s=0.002,
)


@pytest.fixture
def emulator():
    emu = ServoEmulator().start()
    try:
        yield emu
    finally:
        emu.stop()


def make_gimbal(port, **overrides):
    return DynamixelPanTilt(DynamixelPanTiltConfig(port=port, **{**FAST, **overrides}))


@pytest.fixture
def gimbal(emulator):
    g = make_gimbal(emulator.port)
    g.connect()
    try:
        yield g
    finally:
        g.disconnect()
