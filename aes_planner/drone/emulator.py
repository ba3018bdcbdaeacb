"""``VehicleEmulator``: a PX4-like (or ArduPilot-like) MAVLink multicopter with a gimbal, on UDP.

It sends to the companion as PX4 SITL does (``udpout:127.0.0.1:14540``: the companion listens
with ``udpin``) and answers where the companion's packets come from. It starts **armed and
hovering in hold** (PX4 ``AUTO.LOITER``; ArduPilot ``LOITER``) and follows these rules:

* PX4: ``MAV_CMD_DO_SET_MODE`` to ``OFFBOARD`` is accepted only after setpoints
  (``SET_POSITION_TARGET_LOCAL_NED``) streamed faster than 2 Hz for the last second; in offboard,
  ``offboard_loss_s`` (``COM_OF_LOSS_T``, 0.5 s) without a setpoint -> hold where it is.
  ArduPilot: ``GUIDED`` is accepted at once, and the last setpoint is held.
* a setpoint outside the fence, or with NaN/Inf in a field it uses, is recorded and not flown;
  arm/disarm, takeoff, land, RTL requests are recorded (and denied: the emulator stays armed).
* motion: position toward the setpoint at up to ``max_speed_m_s`` (gain ``position_gain_1_s``),
  heading at up to ``max_yaw_rate_deg_s``; the gimbal (2- or 3-axis, ``MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW``)
  within its limits at up to ``gimbal_rate_deg_s``; wind adds a drift velocity.
* telemetry: ``HEARTBEAT`` at ``heartbeat_hz``, ``LOCAL_POSITION_NED``, ``ATTITUDE`` and
  ``ATTITUDE_QUATERNION`` at ``telemetry_hz``, ``GIMBAL_DEVICE_ATTITUDE_STATUS`` at ``gimbal_hz``
  (yaw in the vehicle frame), from the start with ``streams: always`` (PX4 on its offboard port).
  ``streams: on_request`` is ArduPilot with its default ``SRn_*`` rates on a companion's port:
  only a 1 Hz heartbeat until a message is asked for, by ``MAV_CMD_SET_MESSAGE_INTERVAL`` (per
  message; -1 stops it) or ``REQUEST_DATA_STREAM`` (``POSITION``, ``EXTRA1``, ``ALL``);
  ``streams: data_stream_only`` honours only the latter (older firmware), answering the former
  ``MAV_RESULT_UNSUPPORTED``. The default is ``always`` for PX4 and ``on_request`` for ArduPilot.
* faults: ``packet_loss`` (each packet either way dropped with this probability), ``link_loss``
  (``[[start_s, duration_s], ...]`` after start: nothing in or out), ``offboard_refused`` (every
  mode switch denied), ``wind_m_s`` (NED drift velocity).

:meth:`VehicleEmulator.report` says what happened (modes, setpoint gaps in control, fence and
NaN rejections, forbidden requests, the largest excursion outside the fence).
"""

from __future__ import annotations

import logging
import math
import random
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from aes_planner.config import require, require_numbers, require_within, short_repr
from aes_planner.drone import frames as fr
from aes_planner.drone.connection import connect, parse_connection
from aes_planner.drone.modes import AUTOPILOTS, mavlink, mode_name, px4_custom_mode, set_mode_params

log = logging.getLogger(__name__)

__all__ = ["EmulatorConfig", "VehicleEmulator"]

mav = mavlink()
FORBIDDEN_COMMANDS = {
    mav.MAV_CMD_COMPONENT_ARM_DISARM: "arm_disarm",
    mav.MAV_CMD_NAV_TAKEOFF: "takeoff",
    mav.MAV_CMD_NAV_LAND: "land",
    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: "return_to_launch",
    mav.MAV_CMD_NAV_VTOL_TAKEOFF: "vtol_takeoff",
}
STREAM_POLICIES = ("always", "on_request", "data_stream_only")
#: How far from its local origin an emulated vehicle may start or fence itself, metres.
MAX_LOCAL_M = 1e4
#: The longest emulated run (a week), seconds: link-loss windows and ``drone emulate --duration``.
MAX_RUN_S = 7 * 86400.0
#: The telemetry the emulator sends: message -> (its id, the REQUEST_DATA_STREAM group holding it).
TELEMETRY = {
    "LOCAL_POSITION_NED": (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAV_DATA_STREAM_POSITION),
    "ATTITUDE": (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAV_DATA_STREAM_EXTRA1),
    "ATTITUDE_QUATERNION": (mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, mav.MAV_DATA_STREAM_EXTRA1),
    "GIMBAL_DEVICE_ATTITUDE_STATUS": (mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS, None),
}


@dataclass
class EmulatorConfig:
    """The emulated vehicle; see the module docstring. Positions are local NED metres."""

    connection: str = "udpout:127.0.0.1:14540"
    autopilot: str = "px4"
    system_id: int = 1
    component_id: int = 1
    start_ned_m: tuple[float, float, float] = (0.0, 0.0, -2.0)
    start_heading_deg: float = 0.0
    fence_min_ned_m: tuple[float, float, float] | None = None
    fence_max_ned_m: tuple[float, float, float] | None = None
    max_speed_m_s: float = 3.0
    position_gain_1_s: float = 3.0
    max_yaw_rate_deg_s: float = 120.0
    gimbal_axes: int = 2
    gimbal_pitch_limits_deg: tuple[float, float] = (-90.0, 30.0)
    gimbal_yaw_limits_deg: tuple[float, float] = (-170.0, 170.0)
    gimbal_rate_deg_s: float = 90.0
    start_gimbal_pitch_deg: float = 0.0
    heartbeat_hz: float | None = None  # PX4 2 Hz, ArduPilot 1 Hz
    streams: str | None = None
    telemetry_hz: float = 30.0
    gimbal_hz: float = 10.0
    offboard_loss_s: float = 0.5
    packet_loss: float = 0.0
    link_loss: list = field(default_factory=list)
    offboard_refused: bool = False
    wind_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seed: int = 0

    def __post_init__(self):
        require(self.autopilot in AUTOPILOTS, "autopilot", f"must be {' or '.join(AUTOPILOTS)}, got {self.autopilot!r}")
        require(self.gimbal_axes in (2, 3), "gimbal_axes", f"must be 2 or 3, got {self.gimbal_axes!r}")
        for name in ("system_id", "component_id"):
            v = getattr(self, name)
            require(isinstance(v, int) and 1 <= v <= 255, name, f"must be an integer in 1-255, got {v!r}")
        parse_connection(self.connection, "connection")
        require_numbers(
            self,
            ("max_speed_m_s", "position_gain_1_s", "max_yaw_rate_deg_s", "gimbal_rate_deg_s"),
            minimum=0.0,
        )
        require_within(self, ("start_ned_m",), -MAX_LOCAL_M, MAX_LOCAL_M)
        require_within(self, ("start_heading_deg",), -360.0, 360.0)
        require_within(self, ("max_speed_m_s",), 0.0, 30.0)  # a camera drone's top speed, and then some
        require_within(self, ("position_gain_1_s",), 0.0, 100.0)
        require_within(self, ("max_yaw_rate_deg_s", "gimbal_rate_deg_s"), 0.0, 1000.0)
        require_within(self, ("wind_m_s",), -30.0, 30.0)
        require_within(self, ("offboard_loss_s",), 0.0, 60.0)
        require(len(self.start_ned_m) == 3, "start_ned_m", f"expected (north, east, down), got {self.start_ned_m!r}")
        require(len(self.wind_m_s) == 3, "wind_m_s", f"expected (north, east, down), got {self.wind_m_s!r}")
        for name in ("gimbal_pitch_limits_deg", "gimbal_yaw_limits_deg"):
            require_within(self, (name,), -180.0, 180.0)
            lo, hi = getattr(self, name)
            require(lo < hi, name, f"must be (min, max) with min < max, got {(lo, hi)}")
        lo, hi = self.gimbal_pitch_limits_deg
        require_within(self, ("start_gimbal_pitch_deg",), lo, hi)
        require(
            isinstance(self.seed, int) and not isinstance(self.seed, bool) and 0 <= self.seed < 2**63,
            "seed",
            f"must be an integer in [0, 2**63), got {self.seed!r}",
        )
        if self.heartbeat_hz is None:
            self.heartbeat_hz = 2.0 if self.autopilot == "px4" else 1.0
        if self.streams is None:
            self.streams = "always" if self.autopilot == "px4" else "on_request"
        require(
            self.streams in STREAM_POLICIES,
            "streams",
            f"must be one of {', '.join(STREAM_POLICIES)}, got {self.streams!r}",
        )
        require_numbers(self, ("heartbeat_hz", "telemetry_hz", "gimbal_hz", "offboard_loss_s"))
        for name in ("heartbeat_hz", "telemetry_hz", "gimbal_hz"):
            require(getattr(self, name) <= 1000, name, f"must be at most 1000 Hz, got {getattr(self, name)}")
        require(0.0 <= self.packet_loss < 1.0, "packet_loss", f"must be in [0, 1), got {self.packet_loss}")
        require(
            (self.fence_min_ned_m is None) == (self.fence_max_ned_m is None), "fence_max_ned_m", "give both or neither"
        )
        if self.fence_min_ned_m is not None:
            require_within(self, ("fence_min_ned_m", "fence_max_ned_m"), -MAX_LOCAL_M, MAX_LOCAL_M)
            lo, hi = self.fence_min_ned_m, self.fence_max_ned_m
            require(
                len(lo) == len(hi) == 3 and all(a < b for a, b in zip(lo, hi)),
                "fence_max_ned_m",
                f"the fence must be larger than fence_min_ned_m on every axis (not reversed, not empty), got {lo} .. {hi}",
            )
        require(
            isinstance(self.link_loss, list) and len(self.link_loss) <= 100,
            "link_loss",
            f"expected at most 100 [start_s, duration_s] windows, got {short_repr(self.link_loss)}",
        )
        for w in self.link_loss:
            ok = isinstance(w, (list, tuple)) and len(w) == 2
            ok = ok and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in w)
            require(
                ok and 0 <= w[0] <= MAX_RUN_S and 0 < w[1] <= MAX_RUN_S,
                "link_loss",
                f"expected [[start_s, duration_s], ...] with 0 <= start_s <= {MAX_RUN_S:g} and 0 < duration_s <= "
                f"{MAX_RUN_S:g}, got {short_repr(self.link_loss)}",
            )


def _step(x: float, goal: float, max_step: float) -> float:
    return goal if abs(goal - x) <= max_step else x + math.copysign(max_step, goal - x)


class VehicleEmulator:
    """Run with :meth:`start` / :meth:`stop` (a thread) or as a context manager."""

    def __init__(self, config: EmulatorConfig | None = None):
        self.config = c = config or EmulatorConfig()
        self.position_ned = np.asarray(c.start_ned_m, dtype=np.float64).copy()
        self.heading_rad = math.radians(c.start_heading_deg)
        self.gimbal_pitch_rad = math.radians(c.start_gimbal_pitch_deg)
        self.gimbal_yaw_rad = 0.0  # relative to the heading, positive right
        self.mode = "AUTO.LOITER" if c.autopilot == "px4" else "LOITER"
        self.armed = True
        self.target_ned = self.position_ned.copy()
        self.target_heading = self.heading_rad
        self.gimbal_goal = (self.gimbal_pitch_rad, 0.0)
        self.setpoint_times: list[float] = []
        self.last_setpoint_s: float | None = None
        self.events: list[tuple[float, str]] = []
        self.rejected = {"fence": 0, "nan": 0, "wrong_frame": 0, "wrong_target": 0}
        self.forbidden: list[str] = []
        self.mode_requests: list[str] = []
        self.max_gap_in_control_s = 0.0
        self.setpoints_flown = 0
        self.gimbal_commands = 0
        self.max_outside_fence_m = 0.0
        always = c.streams == "always"
        self.rates_hz = {  # what is sent, and how often (0: not sent)
            name: (c.gimbal_hz if name.startswith("GIMBAL") else c.telemetry_hz) if always else 0.0
            for name in TELEMETRY
        }
        self.stream_requests: list[str] = []
        self._rng = random.Random(c.seed)
        self._conn = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._t0 = 0.0
        self._cuts: list[tuple[float, float]] = []  # cut_link()'s windows, as link_loss's
        self._boot = time.monotonic()

    # ------------------------------------------------------------------------- lifecycle
    def start(self) -> VehicleEmulator:
        c = self.config
        self._conn = connect(c.connection, c.system_id, c.component_id)
        self._t0 = time.time()
        self._thread = threading.Thread(target=self._run, name="vehicle-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def cut_link(self, duration_s: float) -> None:
        """Lose the link from now for ``duration_s`` (nothing in or out), as a ``link_loss`` window
        does: for a test or a demo that needs the loss at a moment of its own (a window counted
        from the emulator's start may fall before the vehicle flies on a loaded machine)."""
        require(
            isinstance(duration_s, (int, float)) and math.isfinite(duration_s) and 0.0 < duration_s <= MAX_RUN_S,
            "duration_s",
            f"expected seconds in (0, {MAX_RUN_S:g}] for the link to stay cut, got {short_repr(duration_s)}",
        )
        with self._lock:
            self._cuts.append((time.time() - self._t0, float(duration_s)))

    def __enter__(self) -> VehicleEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -------------------------------------------------------------------------- the loop
    def _link_down(self, now: float) -> bool:
        t = now - self._t0
        with self._lock:
            windows = [*self.config.link_loss, *self._cuts]
        return any(s <= t < s + d for s, d in windows)

    def _run(self) -> None:
        c = self.config
        due = {"hb": 0.0, **dict.fromkeys(TELEMETRY, 0.0)}
        senders = {
            "LOCAL_POSITION_NED": self._send_position,
            "ATTITUDE": self._send_attitude,
            "ATTITUDE_QUATERNION": self._send_attitude_quaternion,
            "GIMBAL_DEVICE_ATTITUDE_STATUS": self._send_gimbal,
        }
        last = time.time()
        while not self._stop.is_set():
            now = time.time()
            down = self._link_down(now)
            while True:  # everything that arrived
                try:
                    msg = self._conn.recv_msg()
                except OSError:  # the companion's port is not open yet (ICMP refused)
                    msg = None
                if msg is None:
                    break
                if down or self._rng.random() < c.packet_loss:
                    continue
                with self._lock:
                    self._handle(msg, now)
            with self._lock:
                self._physics(now, now - last)
            last = now
            if not down:
                with self._lock:
                    rates = [("hb", c.heartbeat_hz, self._send_heartbeat)]
                    rates += [(k, self.rates_hz[k], senders[k]) for k in TELEMETRY if self.rates_hz[k] > 0]
                for key, hz, send in rates:
                    if now >= due[key]:
                        due[key] = max(due[key] + 1.0 / hz, now)
                        if self._rng.random() >= c.packet_loss:
                            try:
                                send(now)
                            except OSError:
                                pass
            self._stop.wait(0.004)

    def _physics(self, now: float, dt: float) -> None:
        c = self.config
        dt = min(max(dt, 0.0), 0.1)
        if self.mode == "OFFBOARD" and self.last_setpoint_s is not None:
            gap = now - self.last_setpoint_s
            if gap > c.offboard_loss_s:  # PX4's offboard-loss failsafe (COM_OBL_RC_ACT): hold
                self._set_mode("AUTO.LOITER", now, f"offboard loss: no setpoint for {gap:.2f} s")
                self.target_ned = self.position_ned.copy()
                self.target_heading = self.heading_rad
        err = self.target_ned - self.position_ned
        dist = float(np.linalg.norm(err))
        speed = min(c.max_speed_m_s, c.position_gain_1_s * dist)
        vel = err / dist * speed if dist > 1e-9 else np.zeros(3)
        step = vel * dt
        if np.linalg.norm(step) >= dist:
            self.position_ned = self.target_ned.copy()
        else:
            self.position_ned = self.position_ned + step
        self.position_ned = self.position_ned + np.asarray(c.wind_m_s) * dt
        self.velocity_ned = vel + np.asarray(c.wind_m_s)
        yaw_err = fr.wrap(self.target_heading - self.heading_rad)
        self.heading_rad = fr.wrap(self.heading_rad + _step(0.0, yaw_err, math.radians(c.max_yaw_rate_deg_s) * dt))
        g_step = math.radians(c.gimbal_rate_deg_s) * dt
        self.gimbal_pitch_rad = _step(self.gimbal_pitch_rad, self.gimbal_goal[0], g_step)
        self.gimbal_yaw_rad = _step(self.gimbal_yaw_rad, self.gimbal_goal[1], g_step)
        if c.fence_min_ned_m is not None:
            lo, hi = np.asarray(c.fence_min_ned_m), np.asarray(c.fence_max_ned_m)
            out = float(np.max(np.maximum(lo - self.position_ned, 0) + np.maximum(self.position_ned - hi, 0)))
            self.max_outside_fence_m = max(self.max_outside_fence_m, out)

    # ------------------------------------------------------------------------- incoming
    def _handle(self, msg, now: float) -> None:
        c = self.config
        kind = msg.get_type()
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._on_setpoint(msg, now)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            if msg.target_system not in (0, c.system_id):
                return
            self._on_command(msg, now)
        elif kind == "REQUEST_DATA_STREAM":
            if msg.target_system in (0, c.system_id):
                self._on_data_stream(int(msg.req_stream_id), int(msg.req_message_rate), int(msg.start_stop))
        elif kind == "SET_MODE":
            self.mode_requests.append(f"SET_MODE {msg.custom_mode}")
            self._try_mode(int(msg.custom_mode), now)

    def _on_setpoint(self, msg, now: float) -> None:
        c = self.config
        if msg.target_system != c.system_id:
            self.rejected["wrong_target"] += 1
            return
        if msg.coordinate_frame != mav.MAV_FRAME_LOCAL_NED:
            self.rejected["wrong_frame"] += 1
            return
        mask = int(msg.type_mask)
        pos = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        used = [] if mask & 0b111 == 0b111 else list(pos)
        if not mask & 1024:
            used.append(msg.yaw)
        if not all(math.isfinite(v) for v in used):
            self.rejected["nan"] += 1
            self.events.append((now, "NaN setpoint rejected"))
            return
        if c.fence_min_ned_m is not None and not mask & 0b111:
            if np.any(pos < np.asarray(c.fence_min_ned_m)) or np.any(pos > np.asarray(c.fence_max_ned_m)):
                self.rejected["fence"] += 1
                self.events.append((now, f"setpoint outside the fence rejected: {pos.round(3).tolist()}"))
                return
        if self.mode in ("OFFBOARD", "GUIDED") and self.last_setpoint_s is not None:
            self.max_gap_in_control_s = max(self.max_gap_in_control_s, now - self.last_setpoint_s)
        self.setpoint_times.append(now)
        del self.setpoint_times[:-64]
        self.last_setpoint_s = now
        if self.mode in ("OFFBOARD", "GUIDED"):
            self.setpoints_flown += 1
            if not mask & 0b111:
                self.target_ned = pos
            if not mask & 1024:
                self.target_heading = float(msg.yaw)

    def _on_command(self, msg, now: float) -> None:
        cmd = int(msg.command)
        result = 0
        if cmd in FORBIDDEN_COMMANDS:
            self.forbidden.append(FORBIDDEN_COMMANDS[cmd])
            self.events.append((now, f"forbidden request {FORBIDDEN_COMMANDS[cmd]}"))
            result = mav.MAV_RESULT_DENIED  # the emulator stays armed and in the air
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            if not int(msg.param1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                result = mav.MAV_RESULT_DENIED
            else:
                custom = (
                    px4_custom_mode(int(msg.param2), int(msg.param3))
                    if self.config.autopilot == "px4"
                    else int(msg.param2)
                )
                self.mode_requests.append(mode_name(self.config.autopilot, 1, custom))
                result = self._try_mode(custom, now)
        elif cmd == mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            result = self._on_gimbal(msg)
        elif cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._on_message_interval(int(msg.param1), float(msg.param2))
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
        try:
            self._conn.mav.command_ack_send(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        except OSError:
            pass

    def _on_message_interval(self, msg_id: int, interval_us: float) -> int:
        """``MAV_CMD_SET_MESSAGE_INTERVAL``: -1 stops the message, 0 its default, else one every
        ``interval_us``; refused (UNSUPPORTED) by a ``data_stream_only`` vehicle."""
        if self.config.streams == "data_stream_only":
            return mav.MAV_RESULT_UNSUPPORTED
        name = next((k for k, (i, _) in TELEMETRY.items() if i == msg_id), None)
        if name is None or not math.isfinite(interval_us):
            return mav.MAV_RESULT_DENIED
        default = self.config.gimbal_hz if name.startswith("GIMBAL") else self.config.telemetry_hz
        self.rates_hz[name] = (
            0.0 if interval_us < 0 else default if interval_us == 0 else min(1e6 / interval_us, 1000.0)
        )
        self.stream_requests.append(f"SET_MESSAGE_INTERVAL {name} {self.rates_hz[name]:g} Hz")
        return mav.MAV_RESULT_ACCEPTED

    def _on_data_stream(self, stream_id: int, rate_hz: int, start: int) -> None:
        """``REQUEST_DATA_STREAM``: a group of messages (ArduPilot's ``SRn_*``) at ``rate_hz`` (0 or stop: off)."""
        if self.config.streams == "always":
            return  # PX4 ignores it
        for name, (_, group) in TELEMETRY.items():
            if group is not None and stream_id in (group, mav.MAV_DATA_STREAM_ALL):
                self.rates_hz[name] = float(min(max(rate_hz, 0), 50)) if start else 0.0
        self.stream_requests.append(f"REQUEST_DATA_STREAM {stream_id} {rate_hz} Hz {'start' if start else 'stop'}")

    def _try_mode(self, custom: int, now: float) -> int:
        c = self.config
        name = mode_name(c.autopilot, 1, custom)
        if c.offboard_refused or name.startswith("UNKNOWN"):
            self.events.append((now, f"mode {name} refused"))
            return mav.MAV_RESULT_DENIED
        if name == "OFFBOARD":
            recent = [t for t in self.setpoint_times if now - t <= 1.0]
            if len(recent) <= 2 or now - recent[-1] > c.offboard_loss_s:
                self.events.append((now, "OFFBOARD refused: no setpoint stream"))
                return mav.MAV_RESULT_TEMPORARILY_REJECTED
        if name in ("OFFBOARD", "GUIDED"):
            self.target_ned = self.position_ned.copy()
            self.target_heading = self.heading_rad
        self._set_mode(name, now, "requested")
        return mav.MAV_RESULT_ACCEPTED

    def _on_gimbal(self, msg) -> int:
        c = self.config
        pitch, yaw = float(msg.param1), float(msg.param2)
        goal_p, goal_y = self.gimbal_goal
        if math.isfinite(pitch):
            lo, hi = c.gimbal_pitch_limits_deg
            goal_p = math.radians(min(max(pitch, lo), hi))
        if math.isfinite(yaw) and c.gimbal_axes == 3:
            lo, hi = c.gimbal_yaw_limits_deg
            goal_y = math.radians(min(max(yaw, lo), hi))
        self.gimbal_goal = (goal_p, goal_y)
        self.gimbal_commands += 1
        return mav.MAV_RESULT_ACCEPTED

    def _set_mode(self, name: str, now: float, why: str) -> None:
        if name != self.mode:
            self.events.append((now, f"mode {self.mode} -> {name} ({why})"))
            log.info("emulator: mode %s -> %s (%s)", self.mode, name, why)
            self.mode = name

    # ------------------------------------------------------------------------- outgoing
    def _custom_mode(self) -> int:
        _, main, sub = set_mode_params(self.config.autopilot, self.mode)  # the one table of mode numbers
        return px4_custom_mode(int(main), int(sub)) if self.config.autopilot == "px4" else int(main)

    def _ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self, now: float) -> None:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        autopilot = mav.MAV_AUTOPILOT_PX4 if self.config.autopilot == "px4" else mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        self._conn.mav.heartbeat_send(
            mav.MAV_TYPE_QUADROTOR, autopilot, base, self._custom_mode(), mav.MAV_STATE_ACTIVE
        )

    def _send_position(self, now: float) -> None:
        with self._lock:
            p, v = self.position_ned.copy(), getattr(self, "velocity_ned", np.zeros(3))
        self._conn.mav.local_position_ned_send(self._ms(), *p.tolist(), *v.tolist())

    def _send_attitude(self, now: float) -> None:
        self._conn.mav.attitude_send(self._ms(), 0.0, 0.0, self.heading_rad, 0.0, 0.0, 0.0)

    def _send_attitude_quaternion(self, now: float) -> None:
        q = fr.matrix_to_quat(fr.euler_to_matrix(0.0, 0.0, self.heading_rad))
        self._conn.mav.attitude_quaternion_send(self._ms(), *q.tolist(), 0.0, 0.0, 0.0)

    def _send_gimbal(self, now: float) -> None:
        with self._lock:
            q = fr.matrix_to_quat(fr.euler_to_matrix(0.0, self.gimbal_pitch_rad, self.gimbal_yaw_rad))
        flags = (
            mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
            | mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        )
        nan = float("nan")
        self._conn.mav.gimbal_device_attitude_status_send(
            0, 0, self._ms(), flags, q.tolist(), nan, nan, nan, 0, nan, nan, 0
        )

    # ---------------------------------------------------------------------------- report
    def report(self) -> dict:
        with self._lock:
            return {
                "mode": self.mode,
                "armed": self.armed,
                "position_ned_m": self.position_ned.round(4).tolist(),
                "heading_deg": round(math.degrees(self.heading_rad), 3),
                "gimbal_pitch_deg": round(math.degrees(self.gimbal_pitch_rad), 3),
                "gimbal_yaw_deg": round(math.degrees(self.gimbal_yaw_rad), 3),
                "mode_requests": list(self.mode_requests),
                "stream_requests": list(self.stream_requests[-32:]),
                "rejected": dict(self.rejected),
                "forbidden_requests": list(self.forbidden),
                "setpoints_flown": self.setpoints_flown,
                "gimbal_commands": self.gimbal_commands,
                "max_setpoint_gap_in_offboard_s": round(self.max_gap_in_control_s, 3),
                "max_outside_fence_m": round(self.max_outside_fence_m, 4),
                "events": [f"{t - self._t0:7.2f} s {e}" for t, e in self.events[-200:]],
            }
