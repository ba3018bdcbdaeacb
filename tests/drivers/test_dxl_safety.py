"""No command sequence ever reaches a servo outside the limits; concurrent use is safe."""

import math
import random
import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aes_planner.geometry.pantilt import JointCommandError
from tests.helpers import wait_for

ANGLES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-10.0, 10.0),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0, math.pi, -math.pi]),
)


@pytest.mark.parametrize(
    "calibration",
    [
        {},
        {
            "pan_direction": -1,
            "pan_zero_offset_ticks": 300,
            "tilt_direction": -1,
            "tilt_zero_offset_ticks": -200,
            "tilt_limits_deg": (-30.0, 80.0),
        },
    ],
)
def test_no_goal_outside_the_limits(emulator, calibration, make_gimbal):
    with make_gimbal(emulator.port, **calibration) as g:
        limits = {1: g.config.calibration("pan").tick_limits, 2: g.config.calibration("tilt").tick_limits}

        @settings(max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
        @given(st.lists(st.tuples(ANGLES, ANGLES), min_size=1, max_size=6))
        def check(commands):
            start = len(emulator.goal_log)
            sent = 0
            for pan, tilt in commands:
                if math.isfinite(pan) and math.isfinite(tilt):
                    g.move_to(pan, tilt)
                    sent += 1
                else:
                    with pytest.raises(JointCommandError):
                        g.move_to(pan, tilt)
            g.state()  # a round trip: every sync write before it has been handled
            received = emulator.goal_log[start:]
            assert len(received) == 2 * sent
            for dxl_id, ticks in received:
                lo, hi = limits[dxl_id]
                assert lo <= ticks <= hi, (dxl_id, ticks, limits[dxl_id])

        check()
        with emulator.lock:
            for dxl_id, (lo, hi) in limits.items():
                servo = emulator.servos[dxl_id]
                assert (servo.get("min_position_limit"), servo.get("max_position_limit")) == (lo, hi)


def test_concurrent_reads_and_moves(emulator, make_gimbal):
    errors, counts = [], {"state": 0, "move": 0}
    stop = threading.Event()
    with make_gimbal(emulator.port) as g:

        def reader():
            while not stop.is_set():
                try:
                    st_ = g.state()
                    assert math.isfinite(st_.pan_rad) and st_.hardware_error == ()
                    counts["state"] += 1
                except Exception as exc:
                    errors.append(exc)
                    return

        def mover(seed):
            rng = random.Random(seed)
            while not stop.is_set():
                try:
                    g.move_to(rng.uniform(-3, 3), rng.uniform(-2, 2))
                    counts["move"] += 1
                except Exception as exc:
                    errors.append(exc)
                    return

        threads = [threading.Thread(target=reader) for _ in range(3)] + [
            threading.Thread(target=mover, args=(i,)) for i in range(2)
        ]
        for t in threads:
            t.start()
        # Run until every thread has made progress (or errored), not for a fixed time: on a
        # loaded host the lock can favour the readers for a while, which is not a failure.
        wait_for(lambda: errors or (counts["state"] > 20 and counts["move"] > 20), timeout_s=60.0, poll_s=0.05)
        stop.set()
        for t in threads:
            t.join(5.0)
        assert not any(t.is_alive() for t in threads)
        assert not errors, errors[:3]
        assert counts["state"] > 20 and counts["move"] > 20
        assert not g._port.is_using
        g.state()
        with emulator.lock:
            assert emulator.packets_seen > 0
        for dxl_id, ticks in emulator.goal_log:
            lo, hi = g.config.calibration("pan" if dxl_id == 1 else "tilt").tick_limits
            assert lo <= ticks <= hi
