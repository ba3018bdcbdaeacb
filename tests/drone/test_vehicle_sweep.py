"""Sweep: vehicles the bridge must not fly, and an ArduPilot with its default stream rates.

* ArduPilot sends a companion only a 1 Hz heartbeat until asked: the bridge asks (SET_MESSAGE_INTERVAL,
  REQUEST_DATA_STREAM), flies once the telemetry arrives, and ends the run naming the missing
  message when it never does;
* a vehicle outside the box is sent nothing in any mode, OFFBOARD and GUIDED included;
* telemetry no vehicle produces (3e38 m, jumps of 70 m in 33 ms, a position beyond the plausibility
  bound) is garbage: nothing is flown on it, the link pauses and reports it.
The hostile vehicles are raw pymavlink frames on a socket, independent of the package's emulator."""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest

from aes_planner.config import from_dict
from aes_planner.drone.node import MavlinkDroneConfig, MavlinkDroneNode
from tests.drone.spec_vehicle import _Out
from tests.drone.test_spec_vehicle import free_port
from tests.helpers import wait_for

pytest.importorskip("pymavlink")
from pymavlink.dialects.v20 import common as mavlink2

BOX = {"bounds_min_m": [-2.0, -2.0, 0.5], "bounds_max_m": [2.0, 2.0, 2.5]}  # world ENU
PX4_OFFBOARD = 6 << 16
ARDUPILOT_GUIDED = 4


def node(port, **kw) -> MavlinkDroneNode:
    cfg = {"connection": f"udpin:127.0.0.1:{port}", "request_offboard": True, "prime_s": 0.5, **BOX, **kw}
    return MavlinkDroneNode(from_dict(MavlinkDroneConfig, cfg))


class ScriptedVehicle:
    """Armed, in ``custom_mode`` (``autopilot`` 12 PX4 or 3 ArduPilot), reporting ``position(t)``
    (NED) at 30 Hz; counts the setpoints it receives."""

    def __init__(self, port: int, position, custom_mode: int, autopilot: int = 12):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.005)
        self.mav = mavlink2.MAVLink(_Out(self.sock, ("127.0.0.1", port)), srcSystem=1, srcComponent=1)
        self.position, self.custom_mode, self.autopilot = position, custom_mode, autopilot
        self.setpoints = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(5)
        self.sock.close()

    def _run(self):
        t0 = time.monotonic()
        next_hb = next_pos = 0.0
        sample = 0
        while not self._stop.is_set():
            t = time.monotonic() - t0
            if t >= next_hb:
                next_hb = t + 0.5
                self.mav.heartbeat_send(2, self.autopilot, 1 | 128, self.custom_mode, 4)
            if t >= next_pos:  # the k-th sample is measured at k/30 s on the vehicle's clock, however late it leaves
                next_pos = t + 1 / 30
                sample += 1
                n, e, d = self.position(sample / 30)
                self.mav.local_position_ned_send(sample * 1000 // 30, n, e, d, 0.0, 0.0, 0.0)
                self.mav.attitude_send(sample * 1000 // 30, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            try:
                data = self.sock.recv(2048)
            except OSError:
                continue
            try:
                msgs = self.mav.parse_buffer(data) or []
            except Exception:
                continue
            self.setpoints += sum(m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" for m in msgs)


def _watch(n: MavlinkDroneNode, until, timeout_s: float = 60.0) -> bool:
    return wait_for(lambda: n.step({}, time.time()) is not None and until(), timeout_s)


# ------------------------------------------------------------------ a vehicle outside the box
@pytest.mark.parametrize(
    ("autopilot", "custom_mode", "code"),
    [("px4", PX4_OFFBOARD, 12), ("ardupilot", ARDUPILOT_GUIDED, 3)],
    ids=["px4-offboard", "ardupilot-guided"],
)
@pytest.mark.parametrize("north_m", [140.0, 3e38, 2e9], ids=["140m", "3e38m", "2e9m"])
def test_a_vehicle_far_outside_the_box_is_sent_nothing_in_any_mode(autopilot, custom_mode, code, north_m):
    port = free_port()
    n = node(port, autopilot=autopilot)
    with ScriptedVehicle(port, lambda t: (north_m, 0.0, -1.5), custom_mode, code) as vehicle:
        n.start()
        try:
            expected = "outside_box" if north_m < 1e9 else "implausible_telemetry"
            counter = "outside_box_refusals" if north_m < 1e9 else "telemetry_implausible"
            assert _watch(n, lambda: n.link.counters.get(counter, 0) >= 30), n.link.counters
            assert n.link.status == expected
            assert vehicle.setpoints == 0 and n.link.counters["setpoints_sent"] == 0
            assert n.diagnostics(time.time()).state.startswith(expected)
        finally:
            n.stop()


def test_telemetry_jumping_faster_than_any_vehicle_pauses_the_stream():
    """In OFFBOARD inside the box, then positions 70 m apart every 33 ms: setpoints stop, the link
    says why; steady telemetry afterwards (the vehicle back in the box) resumes control."""
    port = free_port()
    n = node(port)

    def position(t):
        if 3.0 <= t < 6.0:  # garbage: 70 m jumps at 30 Hz
            return (70.0 * (int(t * 30) % 2), 0.0, -1.5)
        return (0.0, 0.0, -1.5)

    with ScriptedVehicle(port, position, PX4_OFFBOARD) as vehicle:
        n.start()
        try:
            assert _watch(n, lambda: n.link.status == "flying")
            assert _watch(n, lambda: n.link.status == "implausible_telemetry", 30)
            sent = vehicle.setpoints
            assert _watch(n, lambda: n.link.counters.get("telemetry_implausible", 0) >= 20, 30)
            assert n.link.status == "implausible_telemetry"
            assert vehicle.setpoints - sent <= 2  # at most those already on the way
            assert np.allclose(n.link.position_ned, [0.0, 0.0, -1.5])  # nothing accepted of the garbage
            assert _watch(n, lambda: n.link.status == "flying", 30)  # sane again: flown again
        finally:
            n.stop()


# ------------------------------------------------------------------ ArduPilot's default stream rates
@pytest.mark.parametrize("streams", ["on_request", "data_stream_only"])
def test_an_ardupilot_with_default_stream_rates_is_asked_for_telemetry_and_flown(streams):
    port = free_port()
    n = node(port, autopilot="ardupilot", emulate=True, emulator={"streams": streams})
    n.start()
    try:
        assert _watch(n, lambda: n.link.status == "flying", 90), (n.link.status, n.link.counters)
        n.link.set_view_goal([1.0, 0.5, 1.5, 0.0, 0.0], time.time())

        def there():
            with n.link.lock:
                p = n.link.position_ned
            return np.linalg.norm(np.array([p[1], p[0], -p[2]]) - [1.0, 0.5, 1.5]) < 0.05

        assert _watch(n, there, 60)
        assert n.link.counters["stream_requests_sent"] >= 1
        report = n.emulator.report()
        assert report["stream_requests"] and report["max_outside_fence_m"] <= 0.05
    finally:
        n.stop()


def test_a_vehicle_that_never_sends_its_position_ends_the_run_naming_the_message():
    port = free_port()
    # a PX4-like vehicle honouring only REQUEST_DATA_STREAM (which PX4 links do not send): nothing arrives
    n = node(port, emulate=True, emulator={"streams": "data_stream_only"}, telemetry_wait_s=2.0)
    n.start()
    try:
        assert _watch(n, lambda: n.aborted, 60)
        reason = n.abort_reason()
        assert "LOCAL_POSITION_NED" in reason and "telemetry_wait_s" in reason and "SRn_POSITION" in reason
        assert n.link.status == "waiting_for_telemetry" and n.link.counters["setpoints_sent"] == 0
        assert math.isinf(n.link.last_position_s)
    finally:
        n.stop()
