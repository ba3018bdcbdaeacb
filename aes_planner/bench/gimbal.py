"""Benchmark group ``gimbal``: the Dynamixel driver against the servo emulator at 1 Mbps.

The emulator runs in its own process (``aes-planner gimbal emulate``), as servos would, and
charges each reply its wire time at the line rate plus the servos' Return Delay Time (factory
default 500 us each). Figures:

* ``gimbal.sync_read.ms`` -- ``state()``: one sync read of Goal Position..Present Temperature of
  both servos (31 bytes each), decoded.
* ``gimbal.move.ms`` -- the round trip of a move command: ``move_to()`` (checks, clamp, one sync
  write of both goals) and the ``state()`` that reads the new goal back from the servos.
* ``gimbal.move_settle_10deg.ms`` -- ``move_to()`` + ``wait_until_reached()`` for a 10 degree
  step (between +-5 deg) of both joints at the default profile (60 deg/s, 300 deg/s^2; the
  triangular profile alone takes 2 sqrt(10 / 300) = 365 ms): what a caller waits for.
"""

from __future__ import annotations

import itertools
import math

from aes_planner.bench import Recorder
from aes_planner.errors import AesPlannerError

BAUD = 1_000_000


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.drivers.dynamixel import DynamixelPanTilt, DynamixelPanTiltConfig
    from aes_planner.drivers.emulator import EmulatorProcess

    runs = 20 if quick else 200
    with EmulatorProcess(baud=BAUD) as emulator:
        # a generous reply timeout and retries: they cost nothing on a successful exchange (what is
        # timed) and keep a loaded machine, where the emulator process waits for a CPU, from failing
        config = DynamixelPanTiltConfig(port=emulator.port, baud=BAUD, latency_timer_ms=100.0, retries=5)
        with DynamixelPanTilt(config) as gimbal:
            rec.meta["backends"]["gimbal"] = (
                f"dynamixel-sdk on emulator ({', '.join(gimbal.models.values())}) at {BAUD} baud"
            )
            gimbal.move_to(0.0, 0.0)
            gimbal.wait_until_reached(10.0)
            rec.time("gimbal.sync_read.ms", gimbal.state, runs=runs, warmup=5)

            half_degrees = itertools.cycle([0.5, 0.0])  # alternate so that every goal is new

            def command_round_trip():
                pan = math.radians(next(half_degrees))
                gimbal.move_to(pan, 0.0)
                if abs(gimbal.state().goal_pan_rad - pan) > 1e-3:
                    raise AesPlannerError("the emulated servos did not take the goal; the driver or emulator is broken")

            rec.time("gimbal.move.ms", command_round_trip, runs=runs, warmup=5)

            five_degrees = itertools.cycle([5.0, -5.0])

            def settle():
                step = math.radians(next(five_degrees))
                gimbal.move_to(step, step)
                gimbal.wait_until_reached(10.0)

            rec.time("gimbal.move_settle_10deg.ms", settle, runs=3 if quick else 7, warmup=1)
