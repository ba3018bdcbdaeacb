"""Benchmark group ``gimbal``: the Dynamixel driver against the servo emulator at 1 Mbps.

The emulator runs in its own process (``aes-planner gimbal emulate``), as servos would, and
charges each reply its wire time at the line rate plus the servos' Return Delay Time (factory
default 500 us each). Figures:

* ``gimbal.sync_read.ms`` -- ``state()``: one sync read of Goal Position..Present Temperature of
  both servos (31 bytes each), decoded.
* ``gimbal.move.ms`` -- the round trip of a move command: ``move_to()`` (checks, clamp, one sync
  write of both goals) and the ``state()`` that reads the new goal back from the servos.
* ``gimbal.move_settle_5deg.ms`` -- ``move_to()`` + ``wait_until_reached()`` for a 5 degree step
  of both joints at the default profile (60 deg/s, 300 deg/s^2): what a caller waits for.
"""

from __future__ import annotations

import logging
import math
import subprocess
import sys

from aes_planner.bench import Recorder
from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)

BAUD = 1_000_000


def _start_emulator() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "aes_planner", "gimbal", "emulate", "--baud", str(BAUD)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    port = proc.stdout.readline().strip() if proc.stdout else ""
    if not port.startswith("/"):
        proc.kill()
        proc.wait(5)
        raise AesPlannerError(f"the servo emulator did not start (printed {port!r}); run `aes-planner gimbal emulate` to see why")
    return proc, port


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.drivers.dynamixel import DynamixelPanTilt, DynamixelPanTiltConfig

    runs = 20 if quick else 200
    proc, port = _start_emulator()
    try:
        config = DynamixelPanTiltConfig(port=port, baud=BAUD)
        with DynamixelPanTilt(config) as gimbal:
            rec.meta["backends"]["gimbal"] = f"dynamixel-sdk on emulator ({', '.join(gimbal.models.values())}) at {BAUD} baud"
            gimbal.move_to(0.0, 0.0)
            gimbal.wait_until_reached(10.0)
            rec.time("gimbal.sync_read.ms", gimbal.state, runs=runs, warmup=5)

            step = iter(range(10**9))

            def command_round_trip():
                yaw = math.radians(0.5 * (next(step) % 2))  # alternate so that every goal is new
                gimbal.move_to(yaw, 0.0)
                if abs(gimbal.state().goal_yaw_rad - yaw) > 1e-3:
                    raise AesPlannerError("the emulated servos did not take the goal; the driver or emulator is broken")

            rec.time("gimbal.move.ms", command_round_trip, runs=runs, warmup=5)

            sign = [1.0]

            def settle():
                sign[0] = -sign[0]
                gimbal.move_to(math.radians(5.0 * sign[0]), math.radians(5.0 * sign[0]))
                gimbal.wait_until_reached(10.0)

            rec.time("gimbal.move_settle_5deg.ms", settle, runs=3 if quick else 7, warmup=1)
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
