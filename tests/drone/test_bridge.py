"""The mavlink_drone node against the package's emulator and the spec vehicle, without a planner:
the gate, faults (packet loss, link loss, offboard refused, wind), ArduPilot GUIDED."""

import math
import time

import numpy as np
import pytest

from aes_planner.config import ConfigError, from_dict
from aes_planner.drone.node import MavlinkDroneConfig, MavlinkDroneNode
from aes_planner.drone.safety import GateLimits, SetpointGate
from tests.drone.spec_vehicle import SpecVehicle
from tests.drone.test_spec_vehicle import free_port
from tests.helpers import wait_for

pytest.importorskip("pymavlink")

BOX = {"bounds_min_m": [-2.0, -2.0, 0.5], "bounds_max_m": [2.0, 2.0, 2.5]}


def node(port, **kw) -> MavlinkDroneNode:
    cfg = {"connection": f"udpin:127.0.0.1:{port}", "request_offboard": True, "prime_s": 0.5, **BOX, **kw}
    return MavlinkDroneNode(from_dict(MavlinkDroneConfig, cfg))


def fly(n: MavlinkDroneNode, view, timeout_s=60.0) -> bool:
    """Step the node until the vehicle is flying, send the view, wait until the reported camera is there."""
    assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.status == "flying", timeout_s)
    n.link.set_view_goal(view, time.time())

    def there():
        n.step({}, time.time())
        with n.link.lock:
            p = np.array([n.link.position_ned[1], n.link.position_ned[0], -n.link.position_ned[2]])
        return np.linalg.norm(p - np.asarray(view[:3])) < 0.04  # wind: a P controller lags by wind/gain

    return wait_for(there, timeout_s)


def test_gate_keeps_every_setpoint_in_the_box_and_under_the_speed_limit():
    gate = SetpointGate([-1, -1, -3], [1, 1, -1], GateLimits(max_speed_m_s=1.0, margin_m=0.05, lead_m=10))
    gate.reset([0.0, 0.0, -2.0], 0.0)
    assert not gate.set_goal([math.nan, 0, -2], 0.0) and gate.counters["goals_refused"] == 1
    assert not gate.set_goal([0, 0, -2], math.inf)
    assert gate.set_goal([50.0, -50.0, 10.0], 1.0) and gate.counters["goals_clamped"] == 1
    prev = gate.carrot.copy()
    for _ in range(100):
        p, h = gate.next([0.0, 0.0, -2.0], 0.05)
        assert np.all(p >= [-0.95, -0.95, -2.95]) and np.all(p <= [0.95, 0.95, -1.05])
        assert np.linalg.norm(p - prev) <= 0.05 + 1e-12 and math.isfinite(h)
        prev = p
    assert np.allclose(p, [0.95, -0.95, -1.05])


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="autopilot"):
        from_dict(MavlinkDroneConfig, {"autopilot": "betaflight"})
    with pytest.raises(ConfigError, match="stream_rate_hz"):
        from_dict(MavlinkDroneConfig, {"stream_rate_hz": 1.0})
    with pytest.raises(ConfigError, match="emulator"):
        from_dict(MavlinkDroneConfig, {"emulate": True, "emulator": {"no_such": 1}})
    with pytest.raises(ConfigError, match="bounds_min_m"):
        MavlinkDroneNode(from_dict(MavlinkDroneConfig, {}))


@pytest.mark.parametrize("faults", [{}, {"packet_loss": 0.1, "wind_m_s": [0.05, -0.05, 0.0]}])
def test_emulator_closed_loop_with_faults(faults):
    port = free_port()
    n = node(port, emulate=True, emulator=faults)
    n.start()
    try:
        view = [1.0, -1.0, 1.5, 0.5, -0.3]
        assert fly(n, view)
        rep = n.emulator.report()
        assert rep["mode"] == "OFFBOARD" and rep["rejected"] == {
            "fence": 0,
            "nan": 0,
            "wrong_frame": 0,
            "wrong_target": 0,
        }
        assert rep["forbidden_requests"] == [] and rep["max_outside_fence_m"] == 0.0
        assert rep["max_setpoint_gap_in_offboard_s"] < 0.45  # 10 % loss at 20 Hz: a few in a row at most
        assert wait_for(lambda: abs(math.remainder(rep_heading(n) - (90 - math.degrees(0.5)), 360)) < 1.0, 5.0)
        assert wait_for(lambda: abs(n.emulator.report()["gimbal_pitch_deg"] - math.degrees(-0.3)) < 0.5, 5.0)
        n.link.stop()  # the planner stops: streaming stops, and PX4's rule puts it in hold
        assert wait_for(lambda: n.emulator.report()["mode"] == "AUTO.LOITER", 3.0)
    finally:
        n.stop()


def rep_heading(n) -> float:
    return n.emulator.report()["heading_deg"]


def test_offboard_refused_sends_only_hold_setpoints():
    port = free_port()
    n = node(port, emulate=True, emulator={"offboard_refused": True}, offboard_retry_s=0.3)
    n.start()
    try:
        n.link.set_view_goal([1.5, 1.5, 2.0, 0.0, 0.0], time.time())
        assert wait_for(lambda: n.step({}, time.time()) and n.link.counters.get("mode_requests_denied", 0) >= 2, 20)
        rep = n.emulator.report()
        assert rep["mode"] == "AUTO.LOITER" and rep["setpoints_flown"] == 0
        assert n.link.status == "waiting_for_offboard"
    finally:
        n.stop()


def test_link_loss_pauses_and_resumes_on_fresh_telemetry():
    port = free_port()
    n = node(port, emulate=True)
    n.start()
    try:
        assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.status == "flying", 60)
        n.link.set_view_goal([-1.0, 1.0, 1.0, 1.0, 0.0], time.time())
        # cut once flying: a link_loss window counted from the emulator's start fell before the
        # vehicle flew when the machine was loaded (the process took seconds to come up)
        n.emulator.cut_link(3.0)
        assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.status == "link_lost", 20)
        states = n.step({}, time.time())["drone/state"]
        assert all(s.link == "lost" for s in states)
        assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.status == "flying", 20)
        assert n.link.counters["link_losses"] == 1 and n.link.counters["mode_requests_accepted"] == 2
        assert fly(n, [-1.0, 1.0, 1.0, 1.0, 0.0])
        assert "offboard loss" in " ".join(n.emulator.report()["events"])
    finally:
        n.stop()


def test_ardupilot_guided_as_a_configuration():
    port = free_port()
    n = node(port, autopilot="ardupilot", emulate=True, gimbal={"axes": 3})
    n.start()
    try:
        assert fly(n, [0.5, 0.5, 2.0, -1.0, -0.2])
        rep = n.emulator.report()
        assert rep["mode"] == "GUIDED" and rep["mode_requests"] == ["GUIDED"]
        assert abs(rep["heading_deg"] - 90.0) < 1e-6  # 3-axis: the vehicle keeps its heading, the gimbal yaws
        want_yaw_right = math.degrees((math.pi / 2 - (-1.0)) - math.pi / 2)
        assert wait_for(lambda: abs(n.emulator.report()["gimbal_yaw_deg"] - want_yaw_right) < 0.5, 5.0)
    finally:
        n.stop()


def test_spec_vehicle_waits_for_the_pilot_and_never_commands_an_unexpected_system():
    port = free_port()
    v = SpecVehicle(port, sysid=7).start()
    n = node(port, request_offboard=False, vehicle_system_id=3)  # not this vehicle
    n.start()
    try:
        assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.counters.get("foreign_messages", 0) > 20)
        assert n.link.sysid is None and v.setpoint_times == [] and v.set_mode_requests == []
    finally:
        n.stop()
        v.stop()
    v = SpecVehicle(port, sysid=7).start()
    n = node(port, request_offboard=False)
    n.start()
    try:
        assert wait_for(lambda: n.step({}, time.time()) is not None and len(v.setpoint_times) > 20)
        assert v.set_mode_requests == [] and v.mode() == "LOITER"  # primed, but the pilot decides
        with v.lock:
            v._switch(6 << 16, "pilot")  # the pilot switches to OFFBOARD
        assert fly(n, [0.5, 0.5, 2.0, 0.0, 0.0])
        assert v.nan_setpoints == 0 and v.arming_requests == []
    finally:
        n.stop()
        v.stop()


def test_cli_emulator_in_its_own_process(tmp_path):
    import json
    import signal
    import subprocess
    import sys

    port = free_port()
    emu = subprocess.Popen(
        [sys.executable, "-m", "aes_planner", "drone", "emulate", "--connection", f"udpout:127.0.0.1:{port}",
         "--start-ned=0,0,-1.5", "--heading-deg", "90", "--fence-min-ned=-2,-2,-2.5",
         "--fence-max-ned=2,2,-0.5", "--packet-loss", "0.05"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    n = node(port)
    n.start()
    try:
        assert fly(n, [1.0, 1.0, 2.0, 0.0, -0.5]), emu.poll() is None or emu.communicate()
    finally:
        n.stop()
        emu.send_signal(signal.SIGTERM)
        out, err = emu.communicate(timeout=20)
    assert emu.returncode == 0, err
    report = json.loads(out[out.index("{") :])
    assert report["rejected"]["fence"] == 0 and report["rejected"]["nan"] == 0
    assert report["mode_requests"] == ["OFFBOARD"] and report["forbidden_requests"] == []
    assert report["max_outside_fence_m"] == 0.0
    assert report["position_ned_m"] == pytest.approx([1.0, 1.0, -2.0], abs=0.04)


def test_cli_emulate_bad_flags_are_one_line_errors():
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "aes_planner", "drone", "emulate", "--packet-loss", "2"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2 and "packet_loss" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_no_setpoint_outside_the_box_and_no_nan_whatever_the_suggestion():
    port = free_port()
    n = node(port, emulate=True)
    n.start()
    try:
        assert wait_for(lambda: n.step({}, time.time()) is not None and n.link.status == "flying", 60)
        n.link.set_view_goal([float("nan"), 0.0, 1.0, 0.0, 0.0], time.time())  # refused in the link process
        n.link.set_view_goal([40.0, -40.0, 30.0, 0.3, 0.0], time.time())  # far outside: clamped into the box
        corner = [2.0 - 0.02, -2.0 + 0.02, 2.5 - 0.02]  # the box shrunk by box_margin_m

        def at_corner():
            n.step({}, time.time())
            with n.link.lock:
                p = n.link.position_ned
            return np.allclose([p[1], p[0], -p[2]], corner, atol=0.02)

        assert wait_for(at_corner, 60)
        counters = n.diagnostics(time.time()).counters
        assert counters["goals_refused"] == 1 and counters["goals_clamped"] >= 1
        rep = n.emulator.report()
        assert rep["rejected"]["fence"] == 0 and rep["rejected"]["nan"] == 0 and rep["max_outside_fence_m"] == 0.0
    finally:
        n.stop()


@pytest.mark.parametrize("duration_s", [0.0, -1.0, math.nan, math.inf, 1e12, "3"])
def test_cut_link_refuses_a_duration_it_cannot_keep(duration_s):
    from aes_planner.drone.emulator import EmulatorConfig, VehicleEmulator

    emu = VehicleEmulator(EmulatorConfig())  # not started: the check comes first
    with pytest.raises(ConfigError, match="duration_s"):
        emu.cut_link(duration_s)
    assert emu._cuts == []
