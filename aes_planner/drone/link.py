"""``MavlinkLink``: the companion's side of the MAVLink link, in its own thread.

It reads the vehicle's telemetry and, ``stream_rate_hz`` times a second, decides what to do with
one readable rule (:meth:`MavlinkLink._decide`)::

    waiting_for_vehicle  no autopilot heartbeat yet                     -> nothing sent
    link_lost            no heartbeat for heartbeat_timeout_s, or no
                         position for pose_timeout_s (paused; resumes
                         only on fresh telemetry: a new heartbeat and
                         a new position)                                -> nothing sent
    planner_stopped      the planner is done or failed                  -> nothing sent (the vehicle
                                                                           runs its offboard-loss failsafe)
    disarmed             the vehicle is not armed (never armed here)    -> nothing sent
    flying               the vehicle is in OFFBOARD (PX4) / GUIDED      -> setpoints toward the
                         (ArduPilot)                                       planner's view, gimbal
    waiting_for_offboard in a mode from which control may begin         -> hold-here setpoints (PX4
                         (engage_modes: hold/loiter), inside the box       needs a stream before the
                                                                           switch); the switch is
                                                                           requested only with
                                                                           request_offboard
    pilot_control        the pilot left OFFBOARD while the link was up  -> as above, but never requested
    unexpected_mode      any other mode (manual, RTL, land...), the     -> nothing sent
                         wrong autopilot, or outside the box by more
                         than max_entry_m

Every setpoint passes :class:`~aes_planner.drone.safety.SetpointGate` (box, speed, finiteness).
Nothing here arms, disarms, takes off or lands.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from aes_planner.drone import frames as fr
from aes_planner.drone.modes import connect, control_mode, mode_name, set_mode_params
from aes_planner.drone.safety import GateLimits, SetpointGate

log = logging.getLogger(__name__)

__all__ = ["MavlinkLink", "TYPE_MASK_POSITION_YAW"]

#: SET_POSITION_TARGET_LOCAL_NED.type_mask: use x, y, z and yaw; ignore velocity (8|16|32),
#: acceleration (64|128|256) and yaw rate (2048). FORCE_SET (512) is not set.
TYPE_MASK_POSITION_YAW = 8 | 16 | 32 | 64 | 128 | 256 | 2048
MAV_FRAME_LOCAL_NED = 1
NOT_A_VEHICLE = {6, 18, 26, 27, 30}  # GCS, onboard controller, gimbal, ADS-B, camera
AUTOPILOTS = {12: "px4", 3: "ardupilot"}


class MavlinkLink:
    """``config``: a :class:`~aes_planner.drone.node.MavlinkDroneConfig`; ``lo_ned``/``hi_ned``: the box."""

    def __init__(self, config, lo_ned_m, hi_ned_m, clock=time.time):
        self.config = c = config
        self.clock = clock
        self.gate = SetpointGate(
            lo_ned_m, hi_ned_m, GateLimits(c.max_speed_m_s, c.max_yaw_rate_deg_s, c.box_margin_m, c.lead_m)
        )
        self.lock = threading.Lock()
        self.counters = dict.fromkeys(
            (
                "messages_in",
                "foreign_messages",
                "telemetry_rejected",
                "heartbeats_in",
                "positions_in",
                "setpoints_sent",
                "gimbal_commands_sent",
                "mode_requests_sent",
                "mode_requests_accepted",
                "mode_requests_denied",
                "link_losses",
                "pilot_takeovers",
                "goals_in",
            ),
            0,
        )
        self.status = "waiting_for_vehicle"
        self.sysid: int | None = None
        self.compid = 1
        self.autopilot_seen: str | None = None
        self.mode = ""
        self.mode_known = False
        self.armed = False
        self.last_heartbeat_s = -math.inf
        self.last_position_s = -math.inf
        self.position_ned = np.zeros(3)
        self.velocity_ned = np.zeros(3)
        self.r_ned_frd = np.eye(3)
        self.heading = 0.0
        self.gimbal_q: np.ndarray | None = None
        self.gimbal_earth = False
        self.last_gimbal_s = -math.inf
        self.gimbal_sent: tuple[float, float] | None = None  # (pitch, yaw) radians, last commanded
        self.gimbal_sent_s = -math.inf
        self.view_goal: np.ndarray | None = None  # [5] ENU view
        self.goal_s: float | None = None
        self.first_setpoint_after_goal_s: float | None = None
        self.goal_latencies_s: list[float] = []
        self.planner_stopped = False
        self.in_control = False
        self.pilot_took_over = False
        self.lost_since: float | None = None
        self.fresh_since_loss = {"heartbeat": True, "position": True}
        self.primed_since: float | None = None
        self.last_mode_request_s = -math.inf
        self.started_s = clock()
        self._conn = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._last_hb_out = -math.inf
        self._last_tick = None
        self._goal_pending = False

    # ------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        c = self.config
        self._conn = connect(c.connection, c.source_system or 1, c.source_component)
        self.started_s = self.clock()
        self._thread = threading.Thread(target=self._run, name="mavlink-link", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread: streaming stops (the vehicle runs its own offboard-loss failsafe)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def set_view_goal(self, view, now: float) -> bool:
        v = np.asarray(view, dtype=np.float64).reshape(-1)
        with self.lock:
            self.counters["goals_in"] += 1
            if v.shape != (5,) or not np.all(np.isfinite(v)):
                self.gate.counters["goals_refused"] += 1
                return False
            self.view_goal, self.goal_s, self.first_setpoint_after_goal_s = v, now, None
            self._goal_pending = True  # steer at once, not at the next tick
            return True

    # -------------------------------------------------------------------------- the loop
    def _run(self) -> None:
        period = 1.0 / self.config.stream_rate_hz
        next_tick = self.clock()
        while not self._stop.is_set():
            try:
                msg = self._conn.recv_match(blocking=True, timeout=max(0.0, min(0.01, next_tick - self.clock())))
            except OSError:
                msg = None
            while msg is not None:
                with self.lock:
                    self._handle(msg, self.clock())
                try:
                    msg = self._conn.recv_msg()
                except OSError:
                    msg = None
            now = self.clock()
            if now >= next_tick or self._goal_pending:
                if now >= next_tick:
                    next_tick = max(next_tick + period, now - period)
                with self.lock:
                    self._goal_pending = False
                    try:
                        self._tick(now)
                    except OSError as exc:  # the vehicle's address went away; the next tick retries
                        log.debug("send failed: %s", exc)

    # ------------------------------------------------------------------------- telemetry
    def _handle(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        self.counters["messages_in"] += 1
        src = msg.get_srcSystem()
        if kind == "HEARTBEAT":
            if msg.type in NOT_A_VEHICLE or msg.autopilot == 8:
                return
            if self.sysid is None and self.config.vehicle_system_id in (0, src):
                self.sysid, self.compid = src, msg.get_srcComponent()
                if not self.config.source_system:
                    self._conn.mav.srcSystem = src  # a companion shares its vehicle's system id
                log.info("vehicle: system %d component %d (autopilot %s)", src, self.compid, msg.autopilot)
        if src != self.sysid:
            if self.sysid is not None or self.config.vehicle_system_id not in (0, src):  # never followed
                self.counters["foreign_messages"] += 1
            return
        if kind == "HEARTBEAT":
            self.counters["heartbeats_in"] += 1
            self.last_heartbeat_s = now
            self.fresh_since_loss["heartbeat"] = True
            self.autopilot_seen = AUTOPILOTS.get(int(msg.autopilot), f"autopilot {msg.autopilot}")
            self.armed = bool(msg.base_mode & 128)
            new_mode = mode_name(self.config.autopilot, int(msg.base_mode), int(msg.custom_mode))
            if self.mode_known and new_mode != self.mode:
                log.warning("vehicle mode %s -> %s", self.mode, new_mode)
            self.mode, self.mode_known = new_mode, True
        elif kind == "LOCAL_POSITION_NED":
            p = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
            v = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
            if not np.all(np.isfinite(p)):
                self.counters["telemetry_rejected"] += 1
                return
            self.counters["positions_in"] += 1
            self.position_ned, self.velocity_ned = p, np.where(np.isfinite(v), v, 0.0)
            self.last_position_s = now
            self.fresh_since_loss["position"] = True
        elif kind == "ATTITUDE":
            if not all(math.isfinite(a) for a in (msg.roll, msg.pitch, msg.yaw)):
                self.counters["telemetry_rejected"] += 1
                return
            self.r_ned_frd = fr.euler_to_matrix(msg.roll, msg.pitch, msg.yaw)
            self.heading = fr.wrap(msg.yaw)
        elif kind == "ATTITUDE_QUATERNION":
            q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
            if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
                self.counters["telemetry_rejected"] += 1
                return
            self.r_ned_frd = fr.quat_to_matrix(q)
            self.heading = fr.matrix_to_euler(self.r_ned_frd)[2]
        elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            q = np.asarray(msg.q, dtype=np.float64)
            if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
                self.counters["telemetry_rejected"] += 1
                return
            flags = int(msg.flags)
            self.gimbal_q = q / np.linalg.norm(q)
            self.gimbal_earth = bool(flags & 64) or (not flags & 32 and bool(flags & 16))
            self.last_gimbal_s = now
        elif kind == "COMMAND_ACK" and msg.command == 176:
            ok = msg.result == 0
            self.counters["mode_requests_accepted" if ok else "mode_requests_denied"] += 1
            if not ok:
                log.warning("vehicle refused the mode switch (MAV_RESULT %d)", msg.result)

    # ---------------------------------------------------------------------------- control
    def _decide(self, now: float) -> str:
        c = self.config
        if self.sysid is None or self.last_position_s == -math.inf:
            return "waiting_for_vehicle"
        stale = now - self.last_heartbeat_s > c.heartbeat_timeout_s or now - self.last_position_s > c.pose_timeout_s
        if stale or not all(self.fresh_since_loss.values()):
            if self.lost_since is None:
                self.lost_since = now
                self.counters["link_losses"] += 1
                self.fresh_since_loss = {"heartbeat": False, "position": False}
                self.in_control = self.mode_known = False
                self.primed_since = None
                log.warning("link lost: no telemetry; setpoints paused until fresh telemetry arrives")
            return "link_lost"
        if self.lost_since is not None:
            log.warning("link back after %.1f s", now - self.lost_since)
            self.lost_since = None
        if self.planner_stopped:
            self.in_control = False
            return "planner_stopped"
        if not self.armed:
            self.in_control = False
            return "disarmed"
        if self.autopilot_seen in AUTOPILOTS.values() and self.autopilot_seen != c.autopilot:
            return "unexpected_mode"  # a PX4 read as ArduPilot (or back): its modes would be misread
        if self.mode == control_mode(c.autopilot):
            if not self.in_control:
                self.in_control, self.pilot_took_over = True, False
                if self.gate.carrot is None:
                    self.gate.reset(self.position_ned, self.heading)
                log.warning("vehicle in %s: flying the planner's views", self.mode)
            return "flying"
        if self.in_control:  # it left control while the link was up: the pilot (or a failsafe)
            self.in_control, self.pilot_took_over = False, True
            self.counters["pilot_takeovers"] += 1
            log.warning("vehicle left %s for %s: the pilot has control", control_mode(c.autopilot), self.mode)
        if self.mode not in c.engage_mode_list or self.gate.outside_m(self.position_ned) > c.max_entry_m:
            self.primed_since = None
            return "unexpected_mode"
        return "pilot_control" if self.pilot_took_over else "waiting_for_offboard"

    def _tick(self, now: float) -> None:
        dt = 0.0 if self._last_tick is None else now - self._last_tick
        self._last_tick = now
        if self.sysid is not None and now - self._last_hb_out >= 1.0:
            self._last_hb_out = now
            kind = 18 if self.config.heartbeat_type == "onboard_controller" else 6
            self._conn.mav.heartbeat_send(kind, 8, 0, 0, 4)  # MAV_AUTOPILOT_INVALID, MAV_STATE_ACTIVE
        self.status = status = self._decide(now)
        if status in ("waiting_for_offboard", "pilot_control"):
            self.gate.reset(self.position_ned, self.heading)  # hold here
            self.primed_since = self.primed_since or now
            self._send_setpoint(now, 0.0)
            if self._may_request(now):
                self._request_control(now)
        elif status == "flying":
            self._steer()
            self._send_setpoint(now, dt)
            self._point_gimbal(now)
        else:
            self.gate.carrot = None

    def _may_request(self, now: float) -> bool:
        c = self.config
        return (
            c.request_offboard
            and not self.pilot_took_over
            and (self.counters["link_losses"] == 0 or c.reengage_after_link_loss)
            and now - self.primed_since >= c.prime_s
            and now - self.last_mode_request_s >= c.offboard_retry_s
        )

    def _request_control(self, now: float) -> None:
        c = self.config
        self.last_mode_request_s = now
        p1, p2, p3 = set_mode_params(c.autopilot, control_mode(c.autopilot))
        self._conn.mav.command_long_send(self.sysid, self.compid, 176, 0, p1, p2, p3, 0, 0, 0, 0)
        self.counters["mode_requests_sent"] += 1
        log.warning("requested %s (request_offboard is on)", control_mode(c.autopilot))

    def _view_setpoint(self):
        c = self.config
        return fr.view_to_setpoint(self.view_goal, c.gimbal_config.axes, self.heading, c.origin_m)

    def _steer(self) -> None:
        if self.view_goal is None:
            return
        p_ned, heading, _, _ = self._view_setpoint()
        self.gate.set_goal(p_ned, heading)

    def _send_setpoint(self, now: float, dt: float) -> None:
        sp = self.gate.next(self.position_ned, dt)
        if sp is None:
            return
        p, heading = sp
        ms = int((now - self.started_s) * 1000) & 0xFFFFFFFF
        self._conn.mav.set_position_target_local_ned_send(
            ms, self.sysid, self.compid, MAV_FRAME_LOCAL_NED, TYPE_MASK_POSITION_YAW, *map(float, p),
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, float(heading), 0.0,
        )  # fmt: skip
        self.counters["setpoints_sent"] += 1
        if self.status == "flying" and self.goal_s is not None and self.first_setpoint_after_goal_s is None:
            self.first_setpoint_after_goal_s = now
            self.goal_latencies_s = [*self.goal_latencies_s[-255:], now - self.goal_s]

    def _point_gimbal(self, now: float) -> None:
        g = self.config.gimbal_config
        if self.view_goal is None:
            return
        _, _, pitch, yaw = self._view_setpoint()
        lo, hi = (math.radians(a) for a in g.pitch_limits_deg)
        pitch = min(max(pitch, lo), hi)
        ylo, yhi = (math.radians(a) for a in g.yaw_limits_deg)
        yaw = min(max(yaw, ylo), yhi) if g.axes == 3 else 0.0
        if not (math.isfinite(pitch) and math.isfinite(yaw)):
            return
        changed = (
            self.gimbal_sent is None or max(abs(pitch - self.gimbal_sent[0]), abs(yaw - self.gimbal_sent[1])) > 1e-3
        )
        unconfirmed = now - self.last_gimbal_s < 2.0 and self._gimbal_error(pitch, yaw) > math.radians(0.5)
        if not changed and not (unconfirmed and now - self.gimbal_sent_s >= 1.0):
            return
        flags = 4 | 8 | 32  # roll and pitch relative to the horizon, yaw relative to the vehicle
        self._conn.mav.command_long_send(
            self.sysid, self.compid, 1000, 0, math.degrees(pitch), math.degrees(yaw), math.nan, math.nan, flags, 0, 0
        )
        self.gimbal_sent, self.gimbal_sent_s = (pitch, yaw), now
        self.counters["gimbal_commands_sent"] += 1

    def _gimbal_error(self, pitch: float, yaw: float) -> float:
        if self.gimbal_q is None:
            return 0.0
        _, p, y = fr.matrix_to_euler(fr.quat_to_matrix(self.gimbal_q))
        if self.gimbal_earth:
            y = fr.wrap(y - self.heading)
        return max(abs(p - pitch), abs(fr.wrap(y - yaw)) if self.config.gimbal_config.axes == 3 else 0.0)

    # --------------------------------------------------------------------------- readout
    def camera_rotation_ned(self, now: float) -> tuple[np.ndarray, float, float]:
        """The camera's FRD attitude in NED, and the gimbal's (pitch, yaw relative to the vehicle,
        positive right): the gimbal's report when fresh, else the last command (or the start pitch)."""
        g = self.config.gimbal_config
        if self.gimbal_q is not None and g.feedback == "auto" and now - self.last_gimbal_s <= 2.0:
            r = fr.camera_rotation_ned(self.heading, self.gimbal_q, self.gimbal_earth)
            _, p, y = fr.matrix_to_euler(r)
            return r, p, fr.wrap(y - self.heading)
        pitch, yaw = self.gimbal_sent if self.gimbal_sent is not None else (math.radians(g.start_pitch_deg), 0.0)
        r = fr.camera_rotation_ned(self.heading, fr.matrix_to_quat(fr.euler_to_matrix(0.0, pitch, yaw)))
        return r, pitch, yaw
