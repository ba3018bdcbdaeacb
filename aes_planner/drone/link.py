"""``MavlinkLink``: the companion's side of the MAVLink link, in its own thread.

It reads the vehicle's telemetry and, ``stream_rate_hz`` times a second, decides what to do with
one readable rule (:meth:`MavlinkLink._decide`, a :class:`LinkStatus`)::

    waiting_for_vehicle  no autopilot heartbeat yet                     -> nothing sent
    waiting_for_telemetry the vehicle's heartbeat but no position yet:  -> the telemetry is
                         its streams are asked for (ArduPilot sends        requested (again every
                         only a 1 Hz heartbeat to a companion until        stream_request_retry_s)
                         asked); after telemetry_wait_s the run ends
                         naming the missing message
    link_lost            no heartbeat for heartbeat_timeout_s, or no
                         position for pose_timeout_s (paused; resumes
                         only on fresh telemetry: a new heartbeat and
                         a new position)                                -> nothing sent
    implausible_telemetry a position no vehicle reaches (beyond the      -> nothing sent (paused
                         plausibility bound, or a jump faster than         for telemetry_hold_s of
                         max_vehicle_speed_m_s): garbage, not flown on     sane telemetry, reported)
    planner_stopped      the planner is done or failed                  -> nothing sent (the vehicle
                                                                           runs its offboard-loss failsafe)
    disarmed             the vehicle is not armed (never armed here)    -> nothing sent
    outside_box          more than max_entry_m outside the box, in any  -> nothing sent (said once
                         mode (OFFBOARD/GUIDED included)                   per visit)
    flying               the vehicle is in OFFBOARD (PX4) / GUIDED      -> setpoints toward the
                         (ArduPilot)                                       planner's view, gimbal
    waiting_for_offboard in a mode from which control may begin         -> hold-here setpoints (PX4
                         (engage_modes: hold/loiter), inside the box       needs a stream before the
                                                                           switch); the switch is
                                                                           requested only with
                                                                           request_offboard
    pilot_control        the pilot left OFFBOARD while the link was up  -> as above, but never requested
    unexpected_mode      any other mode (manual, RTL, land...), or the  -> nothing sent
                         wrong autopilot

Every setpoint passes :class:`~aes_planner.drone.safety.SetpointGate` (box, speed, finiteness).
Nothing here arms, disarms, takes off or lands.
"""

from __future__ import annotations

import enum
import logging
import math
import threading
import time

import numpy as np

from aes_planner.drone import frames as fr
from aes_planner.drone.connection import connect
from aes_planner.drone.modes import control_mode, mavlink, mode_name, set_mode_params
from aes_planner.drone.safety import GateLimits, SetpointGate
from aes_planner.geometry.plausible import MAX_COORDINATE_M

log = logging.getLogger(__name__)

__all__ = ["LinkStatus", "MavlinkLink", "TYPE_MASK_POSITION_YAW", "TELEMETRY_NEEDED"]

mav = mavlink()  # pymavlink's common dialect: the named constants of common.xml

#: SET_POSITION_TARGET_LOCAL_NED.type_mask: use x, y, z and yaw; ignore velocity, acceleration
#: and yaw rate. FORCE_SET is not set.
TYPE_MASK_POSITION_YAW = (
    mav.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_VZ_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)
NOT_A_VEHICLE = {
    mav.MAV_TYPE_GCS,
    mav.MAV_TYPE_ONBOARD_CONTROLLER,
    mav.MAV_TYPE_GIMBAL,
    mav.MAV_TYPE_ADSB,
    mav.MAV_TYPE_CAMERA,
}
AUTOPILOTS = {mav.MAV_AUTOPILOT_PX4: "px4", mav.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot"}

#: What the bridge needs from the vehicle, and how it is asked for: the message (its id for
#: ``MAV_CMD_SET_MESSAGE_INTERVAL``, which PX4 and ArduPilot 4 honour) and ArduPilot's
#: ``REQUEST_DATA_STREAM`` group holding it (``SRn_POSITION``, ``SRn_EXTRA1``: what older firmware
#: honours), as MAVROS and MAVSDK ask.
TELEMETRY_NEEDED = {
    "LOCAL_POSITION_NED": (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAV_DATA_STREAM_POSITION),
    "ATTITUDE": (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAV_DATA_STREAM_EXTRA1),
}
#: Asked for too, never waited for (a vehicle without a gimbal manager has none).
TELEMETRY_WANTED = {"GIMBAL_DEVICE_ATTITUDE_STATUS": (mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS, None)}


class LinkStatus(str, enum.Enum):
    """What the link does this tick (the module docstring's table); a ``str`` (its value) on the wire."""

    WAITING_FOR_VEHICLE = "waiting_for_vehicle"
    WAITING_FOR_TELEMETRY = "waiting_for_telemetry"
    LINK_LOST = "link_lost"
    IMPLAUSIBLE_TELEMETRY = "implausible_telemetry"
    PLANNER_STOPPED = "planner_stopped"
    DISARMED = "disarmed"
    OUTSIDE_BOX = "outside_box"
    FLYING = "flying"
    WAITING_FOR_OFFBOARD = "waiting_for_offboard"
    PILOT_CONTROL = "pilot_control"
    UNEXPECTED_MODE = "unexpected_mode"

    __str__ = str.__str__
    __format__ = str.__format__


S = LinkStatus
#: A position may jump this much beyond what max_vehicle_speed_m_s allows (an estimator's small reset).
JUMP_SLACK_M = 2.0


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
                "stream_requests_sent",
                "telemetry_implausible",
                "outside_box_refusals",
            ),
            0,
        )
        self.status = S.WAITING_FOR_VEHICLE
        self.sysid: int | None = None
        self.first_heartbeat_s: float | None = None
        self.last_seen_s: dict[str, float] = {}  # message name -> arrival of the newest
        self.last_stream_request_s = -math.inf
        self.implausible_s = -math.inf  # arrival of the newest garbage position
        self._position_ref: tuple[np.ndarray, float, float] | None = (
            None  # newest position heard (any): arrival, vehicle time
        )
        self._outside_said = False
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
            if msg.type in NOT_A_VEHICLE or msg.autopilot == mav.MAV_AUTOPILOT_INVALID:
                return
            if self.sysid is None and self.config.vehicle_system_id in (0, src):
                self.sysid, self.compid = src, msg.get_srcComponent()
                self.first_heartbeat_s = now
                if not self.config.source_system:
                    self._conn.mav.srcSystem = src  # a companion shares its vehicle's system id
                log.info("vehicle: system %d component %d (autopilot %s)", src, self.compid, msg.autopilot)
        if src != self.sysid:
            if self.sysid is not None or self.config.vehicle_system_id not in (0, src):  # never followed
                self.counters["foreign_messages"] += 1
            return
        self.last_seen_s[kind] = now
        if kind == "HEARTBEAT":
            self.counters["heartbeats_in"] += 1
            self.last_heartbeat_s = now
            self.fresh_since_loss["heartbeat"] = True
            self.autopilot_seen = AUTOPILOTS.get(int(msg.autopilot), f"autopilot {msg.autopilot}")
            self.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
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
            problem = self._implausible(p, now, msg.time_boot_ms / 1000.0)
            if problem is not None:
                self.counters["telemetry_implausible"] += 1
                if now - self.implausible_s > self.config.telemetry_hold_s:
                    log.warning("implausible telemetry (%s): setpoints paused, nothing flown on it", problem)
                self.implausible_s = now
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
            self.gimbal_earth = bool(flags & mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME) or (
                not flags & mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
                and bool(flags & mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK)
            )
            self.last_gimbal_s = now
        elif kind == "COMMAND_ACK" and msg.command == mav.MAV_CMD_DO_SET_MODE:
            ok = msg.result == mav.MAV_RESULT_ACCEPTED
            self.counters["mode_requests_accepted" if ok else "mode_requests_denied"] += 1
            if not ok:
                log.warning("vehicle refused the mode switch (MAV_RESULT %d)", msg.result)

    # ---------------------------------------------------------------------------- control
    def _implausible(self, p_ned: np.ndarray, now: float, boot_s: float = 0.0) -> str | None:
        """What no vehicle does about position ``p_ned`` arriving at ``now``, measured at ``boot_s``
        on the vehicle's own clock (``time_boot_ms``; None: plausible). A jump is measured from the
        newest position heard, garbage or not, so a vehicle whose estimate really moved (an EKF
        reset) is flown again after ``telemetry_hold_s`` of steady telemetry. The time between two
        positions is the vehicle's (when it measured them), not when they arrived: on a loaded
        companion computer messages arrive late and in bursts, which would make a real move look
        too fast, or a stalled stream make garbage look slow enough. Arrival time is the fallback
        when the vehicle's clock is absent (0) or went back (a reboot)."""
        far = float(np.abs(p_ned).max())
        if not far <= MAX_COORDINATE_M:
            return f"LOCAL_POSITION_NED {far:.3g} m from the origin (beyond {MAX_COORDINATE_M:.0e} m)"
        ref, self._position_ref = self._position_ref, (p_ned, now, boot_s)
        if ref is None:
            return None
        jump = float(np.linalg.norm(p_ned - ref[0]))
        vehicle_clock = boot_s > 0.0 and ref[2] > 0.0 and boot_s >= ref[2]
        dt = boot_s - ref[2] if vehicle_clock else max(now - ref[1], 0.0)
        allowed = self.config.max_vehicle_speed_m_s * dt + JUMP_SLACK_M
        if jump > allowed:
            return f"LOCAL_POSITION_NED jumped {jump:.3g} m in {dt:.3f} s (faster than max_vehicle_speed_m_s {self.config.max_vehicle_speed_m_s:g})"
        return None

    @property
    def missing(self) -> list[str]:
        return self.missing_telemetry(self.clock())

    def missing_telemetry(self, now: float) -> list[str]:
        """The needed messages (:data:`TELEMETRY_NEEDED`) not heard within ``pose_timeout_s``."""
        return [k for k in TELEMETRY_NEEDED if now - self.last_seen_s.get(k, -math.inf) > self.config.pose_timeout_s]

    def _decide(self, now: float) -> LinkStatus:
        c = self.config
        if self.sysid is None:
            return S.WAITING_FOR_VEHICLE
        if now - self.implausible_s <= c.telemetry_hold_s:
            self.in_control = False  # resumes, from where the vehicle then is, on sane telemetry
            self.primed_since = None
            return S.IMPLAUSIBLE_TELEMETRY
        if self.last_position_s == -math.inf:
            return S.WAITING_FOR_TELEMETRY
        stale = now - self.last_heartbeat_s > c.heartbeat_timeout_s or now - self.last_position_s > c.pose_timeout_s
        if stale or not all(self.fresh_since_loss.values()):
            if self.lost_since is None:
                self.lost_since = now
                self.counters["link_losses"] += 1
                self.fresh_since_loss = {"heartbeat": False, "position": False}
                self.in_control = self.mode_known = False
                self.primed_since = None
                log.warning("link lost: no telemetry; setpoints paused until fresh telemetry arrives")
            return S.LINK_LOST
        if self.lost_since is not None:
            log.warning("link back after %.1f s", now - self.lost_since)
            self.lost_since = None
        if self.planner_stopped:
            self.in_control = False
            return S.PLANNER_STOPPED
        if not self.armed:
            self.in_control = False
            return S.DISARMED
        if self.autopilot_seen in AUTOPILOTS.values() and self.autopilot_seen != c.autopilot:
            return S.UNEXPECTED_MODE  # a PX4 read as ArduPilot (or back): its modes would be misread
        outside = self.gate.outside_m(self.position_ned)
        if outside > c.max_entry_m:  # in every mode: a vehicle out there is not flown to the box
            if not self._outside_said:
                self._outside_said = True
                log.warning(
                    "vehicle %.3g m outside the box (more than max_entry_m %g) in %s: no setpoints are sent; "
                    "fly it into the box",
                    outside,
                    c.max_entry_m,
                    self.mode or "an unknown mode",
                )
            self.counters["outside_box_refusals"] += 1
            self.in_control = False
            self.primed_since = None
            return S.OUTSIDE_BOX
        self._outside_said = False
        if self.mode == control_mode(c.autopilot):
            if not self.in_control:
                self.in_control, self.pilot_took_over = True, False
                self.gate.reset(self.position_ned, self.heading)  # (re)gains control where the vehicle is
                log.warning("vehicle in %s: flying the planner's views", self.mode)
            return S.FLYING
        if self.in_control:  # it left control while the link was up: the pilot (or a failsafe)
            self.in_control, self.pilot_took_over = False, True
            self.counters["pilot_takeovers"] += 1
            log.warning("vehicle left %s for %s: the pilot has control", control_mode(c.autopilot), self.mode)
        if self.mode not in c.engage_mode_list:
            self.primed_since = None
            return S.UNEXPECTED_MODE
        return S.PILOT_CONTROL if self.pilot_took_over else S.WAITING_FOR_OFFBOARD

    def _tick(self, now: float) -> None:
        dt = 0.0 if self._last_tick is None else now - self._last_tick
        self._last_tick = now
        if self.sysid is not None and now - self._last_hb_out >= 1.0:
            self._last_hb_out = now
            kind = (
                mav.MAV_TYPE_ONBOARD_CONTROLLER
                if self.config.heartbeat_type == "onboard_controller"
                else mav.MAV_TYPE_GCS
            )
            self._conn.mav.heartbeat_send(kind, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        if self.sysid is not None and self.missing_telemetry(now):
            self._request_streams(now)
        self.status = status = self._decide(now)
        if status in (S.WAITING_FOR_OFFBOARD, S.PILOT_CONTROL):
            self.gate.reset(self.position_ned, self.heading)  # hold here
            self.primed_since = self.primed_since or now
            self._send_setpoint(now, 0.0)
            if self._may_request(now):
                self._request_control(now)
        elif status == S.FLYING:
            self._steer()
            self._send_setpoint(now, dt)
            self._point_gimbal(now)
        else:
            self.gate.carrot = None

    def _request_streams(self, now: float) -> None:
        """Ask for the telemetry not arriving, as MAVSDK and MAVROS do: ``MAV_CMD_SET_MESSAGE_INTERVAL``
        per message, and for ArduPilot also ``REQUEST_DATA_STREAM`` per group (what its older
        firmware honours; the group's ``SRn_*`` rate). Again every ``stream_request_retry_s``
        while something is missing."""
        c = self.config
        if now - self.last_stream_request_s < c.stream_request_retry_s:
            return
        self.last_stream_request_s = now
        interval_us = 1e6 / c.telemetry_rate_hz
        for msg_id, _ in {**TELEMETRY_NEEDED, **TELEMETRY_WANTED}.values():
            self._conn.mav.command_long_send(
                self.sysid, self.compid, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval_us, 0, 0, 0, 0, 0
            )
        if c.autopilot == "ardupilot":
            for stream in sorted({g for _, g in TELEMETRY_NEEDED.values()}):
                self._conn.mav.request_data_stream_send(self.sysid, self.compid, stream, round(c.telemetry_rate_hz), 1)
        self.counters["stream_requests_sent"] += 1
        log.info("asked the vehicle for %s at %g Hz", ", ".join(self.missing_telemetry(now)), c.telemetry_rate_hz)

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
        self._conn.mav.command_long_send(self.sysid, self.compid, mav.MAV_CMD_DO_SET_MODE, 0, p1, p2, p3, 0, 0, 0, 0)
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
            ms, self.sysid, self.compid, mav.MAV_FRAME_LOCAL_NED, TYPE_MASK_POSITION_YAW, *map(float, p),
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, float(heading), 0.0,
        )  # fmt: skip
        self.counters["setpoints_sent"] += 1
        if self.status == S.FLYING and self.goal_s is not None and self.first_setpoint_after_goal_s is None:
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
        flags = (  # roll and pitch relative to the horizon, yaw relative to the vehicle
            mav.GIMBAL_MANAGER_FLAGS_ROLL_LOCK
            | mav.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
            | mav.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME
        )
        self._conn.mav.command_long_send(
            self.sysid,
            self.compid,
            mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
            0,
            math.degrees(pitch),
            math.degrees(yaw),
            math.nan,
            math.nan,
            flags,
            0,
            0,
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
