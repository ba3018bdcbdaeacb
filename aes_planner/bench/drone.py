"""Benchmark group ``drone``: the MAVLink bridge (``mavlink_drone``) against the package's emulator,
each in its own process, on UDP loopback. Figures:

* ``drone.setpoint_latency.ms`` -- a suggestion handed to the node -> the first setpoint toward it
  leaves the link process (median over moves).
* ``drone.time_to_reach_2m.s`` -- a 2 m move (at the default 1 m/s limit) until the reported
  position is within 5 cm of the goal.
* ``drone.telemetry_without_loss.hz`` -- the highest rate of ``LOCAL_POSITION_NED`` (250 Hz
  doubling to 16 kHz, 2 s each) that the link takes in with under 1 % missing: above it, it falls
  behind and the kernel's socket buffer overflows. Vehicles send 30-250 Hz.
"""

from __future__ import annotations

import logging
import os
import socket
import statistics
import time

import numpy as np

from aes_planner.bench import Recorder
from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(pred, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return bool(pred())


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.config import from_dict
    from aes_planner.drone.node import MavlinkDroneConfig, MavlinkDroneNode

    box = {"bounds_min_m": [-3.0, -3.0, 0.5], "bounds_max_m": [3.0, 3.0, 3.0]}
    cfg = {"connection": f"udpin:127.0.0.1:{_free_port()}", "emulate": True, "request_offboard": True, **box}
    node = MavlinkDroneNode(from_dict(MavlinkDroneConfig, cfg))
    node.start()
    rec.meta["backends"]["drone"] = "pymavlink link process <-> VehicleEmulator process, UDP loopback"
    try:
        if not _wait(lambda: node.step({}, time.time()) is not None and node.link.status == "flying", 120):
            raise AesPlannerError(f"the emulated vehicle never entered OFFBOARD (status {node.link.status})")
        moves = 3 if quick else 8
        latencies, reach = [], []
        for i in range(moves):
            x = 1.0 if i % 2 == 0 else -1.0
            goal = np.array([x, 0.0, 1.5])
            node.link.set_view_goal([*goal, 0.0, 0.0], time.time())
            t0 = time.time()

            def there(goal=goal):
                node.step({}, time.time())
                with node.link.lock:
                    p = node.link.position_ned
                return np.linalg.norm(np.array([p[1], p[0], -p[2]]) - goal) < 0.05

            if not _wait(there, 30):
                raise AesPlannerError("the emulated vehicle did not reach the goal within 30 s")
            if i:  # the first move starts from the hover point, not 2 m away
                reach.append(time.time() - t0)
            with node.link.lock:
                latencies.append(node.link.goal_latencies_s[-1])
        rec.record("drone.setpoint_latency.ms", statistics.median(latencies) * 1000, "ms", len(latencies))
        rec.record("drone.time_to_reach_2m.s", statistics.median(reach), "s", len(reach))
    finally:
        node.stop()
    _flood(rec, node.config, 0.5 if quick else 2.0)


def _flood(rec: Recorder, config, duration_s: float) -> None:
    """A fresh link (a thread here, as in its own process) fed LOCAL_POSITION_NED at doubling rates
    for ``duration_s`` each, after one heartbeat: the highest rate with under 1 % not taken in."""
    from dataclasses import asdict, replace
    from types import SimpleNamespace

    from aes_planner.drone.link import MavlinkLink

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as mavlink2

    port = _free_port()
    d = asdict(replace(config, connection=f"udpin:127.0.0.1:{port}"))
    cfg = SimpleNamespace(**d, engage_mode_list=list(config.engage_mode_list))
    cfg.gimbal_config = config.gimbal_config
    link = MavlinkLink(cfg, [-3, -3, -3], [3, 3, -0.5])
    link.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    sock.sendto(mav.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 3 << 24, 4).pack(mav), ("127.0.0.1", port))
    if not _wait(lambda: link.sysid == 1, 10):
        raise AesPlannerError("the link never saw the flood's heartbeat")
    frames = [mav.local_position_ned_encode(i, 0.0, 0.0, -1.5, 0.0, 0.0, 0.0).pack(mav) for i in range(64)]
    best_hz = 0.0
    for rate_hz in (250, 500, 1000, 2000, 4000, 8000, 16000):
        with link.lock:
            before = link.counters["positions_in"]
        n = int(rate_hz * duration_s)
        t0 = time.perf_counter()
        for i in range(n):  # paced: message i leaves at t0 + i / rate
            while time.perf_counter() < t0 + i / rate_hz:
                pass
            sock.sendto(frames[i % 64], ("127.0.0.1", port))
        time.sleep(0.3)  # what is still queued is taken in
        with link.lock:
            got = link.counters["positions_in"] - before
        lost = 1.0 - got / n
        log.info("drone: %d Hz of LOCAL_POSITION_NED: %.2f %% not taken in", rate_hz, 100 * lost)
        if lost > 0.01:
            break
        best_hz = float(rate_hz)
    link.stop()
    sock.close()
    rec.record("drone.telemetry_without_loss.hz", best_hz, "Hz", 1)
