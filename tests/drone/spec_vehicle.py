"""A MAVLink vehicle written for the tests from the MAVLink common.xml specification and PX4's
offboard rules, independently of aes_planner.drone (it shares no code with the package's emulator):

* a raw UDP socket that sends to the companion's port as PX4 SITL does; MAVLink 2 frames built and
  parsed by pymavlink's generated dialect only (no mavutil);
* starts armed, hovering in AUTO.LOITER (custom_mode main 4 << 16 | sub 3 << 24);
* OFFBOARD (main 6) only when setpoints arrived above 2 Hz over the last second; 0.5 s without a
  setpoint in OFFBOARD -> AUTO.LOITER where it is;
* setpoints outside the fence, or with NaN/Inf in a used field, are recorded and not flown;
  arming/disarming/takeoff/land requests are recorded;
* flies to the setpoint at a fixed 2 m/s, yaw at 90 deg/s; no gimbal (a fixed camera);
* ``cut(seconds)`` drops everything both ways for that long.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink2

LOITER = (4 << 16) | (3 << 24)
OFFBOARD = 6 << 16


class _Out:
    def __init__(self, sock, addr):
        self.sock, self.addr = sock, addr

    def write(self, data):
        try:
            self.sock.sendto(data, self.addr)
        except OSError:
            pass


class SpecVehicle:
    def __init__(self, port: int, start_ned=(0.0, 0.0, -2.0), heading=0.0, fence=None, sysid=1):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.002)
        self.mav = mavlink2.MAVLink(_Out(self.sock, ("127.0.0.1", port)), srcSystem=sysid, srcComponent=1)
        self.sysid = sysid
        self.pos = list(start_ned)
        self.yaw = heading
        self.target = list(start_ned)
        self.target_yaw = heading
        self.custom_mode = LOITER
        self.fence = fence  # ((n0, e0, d0), (n1, e1, d1)) or None
        self.setpoint_times: list[float] = []
        self.offboard_gaps: list[float] = []
        self.fence_rejections: list[tuple] = []
        self.nan_setpoints = 0
        self.arming_requests: list[int] = []
        self.mode_log: list[tuple[float, str]] = []
        self.set_mode_requests: list[tuple] = []
        self.max_outside_m = 0.0
        self.cut_until = 0.0
        self.running = True
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def mode(self) -> str:
        return "OFFBOARD" if self.custom_mode == OFFBOARD else "LOITER"

    def cut(self, seconds: float) -> None:
        self.cut_until = time.time() + seconds

    def start(self):
        self.thread.start()
        return self

    def stop(self):
        self.running = False
        self.thread.join(3)
        self.sock.close()

    def _switch(self, mode: int, why: str) -> None:
        if mode != self.custom_mode:
            self.custom_mode = mode
            self.mode_log.append((time.time(), f"{self.mode()} ({why})"))

    def receive(self, now: float) -> None:
        while True:
            try:
                data, _ = self.sock.recvfrom(4096)
            except (TimeoutError, BlockingIOError):
                return
            except OSError:  # ICMP port unreachable before the companion listens
                return
            if now < self.cut_until:
                continue
            try:
                msgs = self.mav.parse_buffer(data) or []
            except mavlink2.MAVError:
                continue
            for m in msgs:
                self.handle(m, now)

    def handle(self, m, now: float) -> None:
        t = m.get_type()
        if t == "SET_POSITION_TARGET_LOCAL_NED" and m.target_system == self.sysid:
            vals = [m.x, m.y, m.z, m.yaw]
            if not all(math.isfinite(v) for v in vals):
                self.nan_setpoints += 1
                return
            if self.fence is not None:
                lo, hi = self.fence
                if any(not (a <= v <= b) for v, a, b in zip(vals[:3], lo, hi)):
                    self.fence_rejections.append(tuple(vals[:3]))
                    return
            if self.custom_mode == OFFBOARD and self.setpoint_times:
                self.offboard_gaps.append(now - self.setpoint_times[-1])
            self.setpoint_times.append(now)
            if self.custom_mode == OFFBOARD:
                self.target, self.target_yaw = vals[:3], vals[3]
        elif t == "COMMAND_LONG" and m.target_system == self.sysid:
            result = mavlink2.MAV_RESULT_ACCEPTED
            if m.command in (400, 21, 22, 20):  # arm/disarm, land, takeoff, RTL
                self.arming_requests.append(m.command)
                result = mavlink2.MAV_RESULT_DENIED
            elif m.command == mavlink2.MAV_CMD_DO_SET_MODE:
                self.set_mode_requests.append((now, m.param1, m.param2, m.param3))
                recent = [s for s in self.setpoint_times if now - s <= 1.0]
                wants_offboard = int(m.param1) & 1 and int(m.param2) == 6
                if wants_offboard and len(recent) > 2:
                    self.target, self.target_yaw = list(self.pos), self.yaw
                    self._switch(OFFBOARD, "requested")
                else:
                    result = mavlink2.MAV_RESULT_DENIED
            self.mav.command_ack_send(m.command, result)

    def fly(self, dt: float) -> None:
        d = [b - a for a, b in zip(self.pos, self.target)]
        dist = math.sqrt(sum(x * x for x in d))
        step = 2.0 * dt
        self.pos = list(self.target) if dist <= step else [a + x / dist * step for a, x in zip(self.pos, d)]
        dy = math.atan2(math.sin(self.target_yaw - self.yaw), math.cos(self.target_yaw - self.yaw))
        turn = math.radians(90) * dt
        self.yaw += max(-turn, min(turn, dy))
        if self.fence is not None:
            lo, hi = self.fence
            out = sum(max(a - v, 0) + max(v - b, 0) for v, a, b in zip(self.pos, lo, hi))
            self.max_outside_m = max(self.max_outside_m, out)

    def run(self) -> None:
        last = time.time()
        next_hb = next_tel = 0.0
        boot = time.time()
        while self.running:
            now = time.time()
            with self.lock:
                self.receive(now)
                if self.custom_mode == OFFBOARD and self.setpoint_times and now - self.setpoint_times[-1] > 0.5:
                    self.target, self.target_yaw = list(self.pos), self.yaw
                    self._switch(LOITER, "offboard loss")
                self.fly(min(now - last, 0.1))
                last = now
                if now >= self.cut_until:
                    ms = int((now - boot) * 1000)
                    if now >= next_hb:
                        next_hb = now + 1.0
                        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
                        self.mav.heartbeat_send(
                            mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, base, self.custom_mode, 4
                        )
                    if now >= next_tel:
                        next_tel = now + 1 / 30
                        self.mav.local_position_ned_send(ms, *self.pos, 0.0, 0.0, 0.0)
                        self.mav.attitude_send(ms, 0.0, 0.0, self.yaw, 0.0, 0.0, 0.0)
            time.sleep(0.003)
