"""Fixtures for the driver tests: an emulator in a background thread and a driver connected to it.

Every fixture stops what it started, whatever the test did; every wait has a timeout.
Short timeouts keep fault tests quick: the SDK waits 2 x latency_timer_ms + 2 ms for a reply.
"""

import sys

import pytest

from aes_planner.drivers.dynamixel import DynamixelPanTilt, DynamixelPanTiltConfig
from aes_planner.drivers.emulator import ServoEmulator

# Quick motion, for tests against the in-process emulator. The reply timeout (2 x 100 + 2 ms)
# leaves room for GIL hand-offs between the SDK's busy wait and the emulator thread, and for
# the scheduler of a shared 2-core machine under a load of 20 (seen while seven people ran
# their suites at once: at 2 x 25 + 2 ms, replies that took 1 ms idle timed out); replies
# normally take well under 1 ms, so this costs time only where a test drops replies on purpose.
LATENCY_TIMER_MS = 100.0
FAST = dict(
    profile_velocity_deg_s=0.0,
    profile_acceleration_deg_s2=0.0,
    latency_timer_ms=LATENCY_TIMER_MS,
    backoff_s=0.001,
    move_timeout_s=3.0,
    poll_interval_s=0.002,
)


@pytest.fixture(autouse=True)
def _in_process_timing(monkeypatch):
    """The SDK busy-waits holding the GIL; switch threads every 0.5 ms, not 5 ms, so that the
    in-process emulator answers about as fast as a servo would. Tests that use the SDK directly
    have no retries: they get a 0.5 s reply timeout (the SDK reads this global at call time; at
    0.2 s, reads timed out and came back as 0 on a 2-core machine under a load of 20)."""
    import dynamixel_sdk.port_handler

    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 250)
    before = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)
    yield
    sys.setswitchinterval(before)


@pytest.fixture
def emulator():
    emu = ServoEmulator().start()
    try:
        yield emu
    finally:
        emu.stop()


@pytest.fixture
def fast():
    """Config overrides for quick tests (see FAST)."""
    return dict(FAST)


@pytest.fixture
def make_gimbal():
    """``make_gimbal(port, **overrides)``: an unconnected driver, disconnected at teardown."""
    made = []

    def make(port, **overrides):
        g = DynamixelPanTilt(DynamixelPanTiltConfig(port=port, **{**FAST, **overrides}))
        made.append(g)
        return g

    yield make
    for g in made:
        g.disconnect()


@pytest.fixture
def gimbal(emulator, make_gimbal):
    g = make_gimbal(emulator.port)
    g.connect()
    return g
