"""``aes-planner demo --drone mavlink``: the closed loop against a MAVLink vehicle.

:func:`aes_planner.cli.demo.run_demo` runs it with ``launch/drone_mavlink.yaml`` (the package's
emulator unless ``--set drone.emulate=false``); these helpers are its hooks: the launch file and
settings, whether the vehicle's link is gone for good (the run ends, cleanly), and what the run
folder's ``summary.json`` says about the flight (``drone``: the vehicle's last pose and mode, the
bridge's counters, the emulator's report on a dry run).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LAUNCH_FILE", "abort_reason", "aborted", "drone_summary"]

LAUNCH_FILE = "drone_mavlink.yaml"


def _drones(nodes) -> list:
    from aes_planner.drone.node import MavlinkDroneNode

    return [n for n, _ in nodes if isinstance(n, MavlinkDroneNode)]


def aborted(nodes) -> bool:
    """A vehicle's link has been lost (or never came up) for its ``link_loss_abort_s``."""
    return any(d.aborted for d in _drones(nodes))


def abort_reason(nodes) -> str:
    """One line: why the run ended early (no vehicle heard, no position from it, its link lost)."""
    for d in _drones(nodes):
        reason = d.abort_reason()
        if reason is not None:
            return reason
    return ""


def drone_summary(nodes) -> dict:
    from aes_planner.drone import frames as fr

    out = {}
    for d in _drones(nodes):
        link = d.link
        if link is None:
            continue
        with link.lock:
            pos = fr.ned_to_enu(link.position_ned) + np.asarray(d.config.origin_m)
            r_cam, pitch, _ = link.camera_rotation_ned(link.clock())
            c2w = fr.pose_to_cam2world(link.position_ned, r_cam, link.r_ned_frd, origin_m=d.config.origin_m)
            out = {
                "connection": d.config.connection,
                "emulated": d.emulator is not None,
                "status": link.status,
                "mode": link.mode,
                "armed": link.armed,
                "aborted": d.aborted,
                "final_position_m": [round(float(v), 4) for v in pos],
                "final_heading_enu_deg": round(math.degrees(fr.heading_ned_to_enu(link.heading)), 3),
                "final_camera_cam2world": c2w.tolist(),
                "counters": dict(link.counters),
                "setpoint_latency_s": [round(v, 4) for v in link.goal_latencies_s[-32:]],
            }
        if d.emulator is not None:
            out["emulator"] = d.emulator.report()
    return out
