"""The demo command against a vehicle written from the MAVLink spec and PX4's offboard rules
(tests/drone/spec_vehicle.py, no code shared with the package), as a user would run it."""

import json
import math
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.drone.spec_vehicle import OFFBOARD, SpecVehicle
from tests.helpers import wait_for

pytest.importorskip("pymavlink")

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "garden_drone.yaml"
ORIGIN = (5000.0, -3000.0, 0.0)  # the scene's box is around (5000, -3000): the vehicle's local origin there
FENCE_NED = ((-3.0, -3.0, -4.0), (3.0, 3.0, -1.0))  # the box in the vehicle's local NED


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def demo(port: int, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [
        sys.executable, "-m", "aes_planner", "demo", "--drone", "mavlink", "--scene", str(SCENE),
        "--set", "drone.emulate=false", "--set", f"drone.connection=udpin:127.0.0.1:{port}",
        "--set", "drone.request_offboard=true", "--set", f"drone.origin_m={list(ORIGIN)}",
        "--moves", "1", "--set", "planner.explore_views=2", "--set", "planner.polish_captures=0",
        "--timeout", "150", "--out", str(out), *extra,
    ]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _check_safe(v: SpecVehicle) -> None:
    assert v.nan_setpoints == 0
    assert v.arming_requests == []
    assert v.fence_rejections == []
    assert v.max_outside_m == 0.0
    assert v.set_mode_requests, "the bridge never asked for OFFBOARD"
    for t, p1, p2, _ in v.set_mode_requests:  # asked with the custom-mode flag for main mode 6,
        assert int(p1) & 1 and int(p2) == 6
        assert sum(1 for s in v.setpoint_times if t - 1.0 <= s <= t) > 2  # after streaming above 2 Hz


@pytest.mark.slow  # ~100 s on 2 cores: the whole demo with its scoring
def test_demo_flies_a_spec_vehicle(tmp_path):
    port = free_port()
    v = SpecVehicle(port, start_ned=(0.5, -0.5, -2.5), heading=math.radians(90), fence=FENCE_NED).start()
    try:
        proc = demo(port, tmp_path / "run")
        out, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, out[-3000:]
        assert wait_for(lambda: v.mode() != "OFFBOARD", 3.0)  # streaming stopped with the planner: it holds
        with v.lock:
            _check_safe(v)
            assert any("OFFBOARD (requested)" in m for _, m in v.mode_log)
            assert max(v.offboard_gaps) < 0.1, f"a gap of {max(v.offboard_gaps):.3f} s in the stream"
            assert v.mode() == "LOITER"
            pos_enu = np.array([v.pos[1], v.pos[0], -v.pos[2]]) + ORIGIN
            yaw_enu = math.pi / 2 - v.yaw
        summary = json.loads((tmp_path / "run" / "summary.json").read_text())
        assert summary["state"] == "done" and summary["moves"] >= 0
        final = np.array(summary["final_cam2world"])
        assert np.linalg.norm(final[:3, 3] - pos_enu) < 0.06  # it ends where the final view is
        fwd = final[:3, 2]
        assert abs(math.remainder(math.atan2(fwd[1], fwd[0]) - yaw_enu, 2 * math.pi)) < math.radians(2.5)
    finally:
        v.stop()


@pytest.mark.slow
def test_link_cut_mid_flight_ends_cleanly_and_the_vehicle_holds(tmp_path):
    port = free_port()
    v = SpecVehicle(port, start_ned=(0.0, 0.0, -2.0), heading=0.0, fence=FENCE_NED).start()
    try:
        proc = demo(port, tmp_path / "run", "--set", "drone.link_loss_abort_s=30")
        assert wait_for(lambda: v.custom_mode == OFFBOARD and len(v.offboard_gaps) > 30, 150.0)
        v.cut(3.0)
        assert wait_for(lambda: v.mode() == "LOITER", 2.0)  # PX4's rule: 0.5 s without a setpoint -> hold
        out, _ = proc.communicate(timeout=300)
        assert (tmp_path / "run" / "summary.json").exists(), out[-3000:]
        summary = json.loads((tmp_path / "run" / "summary.json").read_text())
        assert summary["drone"]["counters"]["link_losses"] >= 1
        assert wait_for(lambda: v.mode() == "LOITER", 3.0)
        with v.lock:
            _check_safe(v)
            holds = list(v.pos)
        assert summary["state"] in ("done", "failed")
        with v.lock:
            assert np.allclose(v.pos, holds)  # nothing moves it any more
    finally:
        v.stop()


@pytest.mark.slow
def test_demo_on_the_emulator_with_packet_loss_and_a_link_loss(tmp_path):
    """The dry run, faults on: 10 % of packets lost each way and the link cut for 3 s mid-flight."""
    out = tmp_path / "run"
    cmd = [
        sys.executable, "-m", "aes_planner", "demo", "--drone", "mavlink", "--scene", str(SCENE),
        "--set", f"drone.connection=udpin:127.0.0.1:{free_port()}", "--set", "drone.request_offboard=true",
        "--set", "drone.emulator.packet_loss=0.1", "--set", "drone.emulator.link_loss=[[10, 3]]",
        "--moves", "1", "--set", "planner.explore_views=2", "--set", "planner.polish_captures=2",
        "--timeout", "200", "--out", str(out),
    ]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=400)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    drone, emu = summary["drone"], summary["drone"]["emulator"]
    assert summary["state"] == "done" and drone["emulated"]
    assert emu["rejected"] == {"fence": 0, "nan": 0, "wrong_frame": 0, "wrong_target": 0}
    assert emu["forbidden_requests"] == [] and emu["max_outside_fence_m"] == 0.0
    assert drone["counters"]["link_losses"] >= 1  # and the loop still completed
    final = np.array(summary["final_cam2world"])
    assert np.linalg.norm(final[:3, 3] - np.array(drone["final_position_m"])) < 0.06
