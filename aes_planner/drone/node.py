"""``MavlinkDroneNode`` (type ``mavlink_drone``): a flight controller on the bus, in place of
``sim_drone``.

In: ``planner/suggestion`` (the top candidate is the view to fly to, as for ``sim_drone``) and
``planner/diagnostics`` (a planner that is ``done`` or ``failed`` stops the setpoint stream).
Out: ``drone/state`` (:class:`~aes_planner.messages.DroneState`: the vehicle's pose and the
camera's, in the ENU world, stamped with the telemetry's arrival) and ``drone/diagnostics``.
The link and its rules live in :class:`~aes_planner.drone.link.MavlinkLink`; with ``emulate``
the node also runs the package's :class:`~aes_planner.drone.emulator.VehicleEmulator` (a dry run).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from aes_planner.config import ConfigError, from_dict, require, require_numbers
from aes_planner.drone import frames as fr
from aes_planner.drone.modes import AUTOPILOTS
from aes_planner.graph.base import LaunchContext, Node, NodeError, Outputs
from aes_planner.messages import Diagnostics, DroneState, ViewSuggestion
from aes_planner.node.scene import launch_scene
from aes_planner.platform import DroneBox

log = logging.getLogger(__name__)

__all__ = ["GimbalConfig", "MavlinkDroneConfig", "MavlinkDroneNode"]

DEFAULT_ENGAGE_MODES = {"px4": ["AUTO.LOITER", "POSCTL"], "ardupilot": ["LOITER", "POSHOLD", "BRAKE"]}


@dataclass
class GimbalConfig:
    """* ``axes``: 2 (pitch only; the vehicle yaws to the view) or 3 (the gimbal yaws too).
    * ``pitch_limits_deg``, ``yaw_limits_deg``: commands are clamped to these.
    * ``feedback``: ``auto`` (pose the camera with ``GIMBAL_DEVICE_ATTITUDE_STATUS`` when it is
      fresh, else with the last command) or ``none`` (always the last command).
    * ``start_pitch_deg``: the camera's pitch before any report or command.
    * ``mount_frd_m``: the camera's offset from the vehicle's origin, body FRD."""

    axes: int = 2
    pitch_limits_deg: tuple[float, float] = (-90.0, 30.0)
    yaw_limits_deg: tuple[float, float] = (-170.0, 170.0)
    feedback: str = "auto"
    start_pitch_deg: float = 0.0
    mount_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        require(self.axes in (2, 3), "axes", f"must be 2 or 3, got {self.axes!r}")
        require(self.feedback in ("auto", "none"), "feedback", f"must be auto or none, got {self.feedback!r}")
        for name in ("pitch_limits_deg", "yaw_limits_deg"):
            lo, hi = getattr(self, name)
            require(-180 <= lo < hi <= 180, name, f"must be (min, max) within [-180, 180], got {(lo, hi)}")


@dataclass
class MavlinkDroneConfig:
    """How the node talks to the vehicle and what it may do (docs/guides/drone.md).

    * ``connection``: a pymavlink connection string (``udpin:127.0.0.1:14540``: PX4 SITL's
      offboard port; ``serial:/dev/ttyUSB0:921600``, ``tcp:HOST:PORT``...).
    * ``autopilot``: ``px4`` (OFFBOARD) or ``ardupilot`` (GUIDED).
    * ``request_offboard``: switch to OFFBOARD/GUIDED itself (false: wait for the pilot);
      ``reengage_after_link_loss``: with it, switch again after a link loss left the vehicle in hold.
    * ``engage_modes``: modes from which control may begin (default PX4 ``AUTO.LOITER``,
      ``POSCTL``; ArduPilot ``LOITER``, ``POSHOLD``, ``BRAKE``); in any other mode nothing is sent.
    * ``vehicle_system_id``: the vehicle to fly (0: the first autopilot heard; others are ignored
      and counted); ``source_system`` (0: the vehicle's, as a companion), ``source_component``,
      ``heartbeat_type`` (``onboard_controller`` or ``gcs``).
    * ``stream_rate_hz``: setpoints per second (PX4 needs > 2; 30 by default: a stall of 70 ms still leaves 10 Hz).
    * ``heartbeat_timeout_s``, ``pose_timeout_s``: link loss; ``link_loss_abort_s``: a loss (or no
      vehicle at all) this long ends the run (``aborted``).
    * ``telemetry_rate_hz``: the rate asked for the telemetry the bridge needs (``LOCAL_POSITION_NED``,
      ``ATTITUDE``; with ``MAV_CMD_SET_MESSAGE_INTERVAL``, and for ArduPilot ``REQUEST_DATA_STREAM``),
      asked again every ``stream_request_retry_s`` while missing; ``telemetry_wait_s``: a vehicle
      heard whose position has not arrived this long after its first heartbeat ends the run,
      naming the missing message.
    * ``max_vehicle_speed_m_s``: a position jumping faster than this is garbage (as is one beyond
      the plausibility bound): nothing is flown on it, and setpoints pause until
      ``telemetry_hold_s`` of sane telemetry has arrived.
    * ``prime_s``: setpoints streamed before the switch is requested; ``offboard_retry_s``.
    * ``max_speed_m_s``, ``max_yaw_rate_deg_s``: the streamed setpoint's speed limits;
      ``lead_m``: how far it may run ahead of the vehicle.
    * ``bounds_min_m``, ``bounds_max_m``: the box (world ENU; default the scene's flight box);
      ``box_margin_m``: setpoints stay this far inside it; ``max_entry_m``: a vehicle further
      outside is not flown.
    * ``origin_m``: the world position (ENU) of the vehicle's local NED origin.
    * ``gimbal``: :class:`GimbalConfig`.
    * ``emulate``: also run the package's vehicle emulator at ``connection`` (a dry run);
      ``emulator``: its settings (:class:`~aes_planner.drone.emulator.EmulatorConfig`: faults...).
    """

    connection: str = "udpin:127.0.0.1:14540"
    autopilot: str = "px4"
    request_offboard: bool = False
    reengage_after_link_loss: bool = True
    engage_modes: list | None = None
    vehicle_system_id: int = 0
    source_system: int = 0
    source_component: int = 191
    heartbeat_type: str = "onboard_controller"
    stream_rate_hz: float = 30.0
    heartbeat_timeout_s: float = 2.5
    pose_timeout_s: float = 1.0
    link_loss_abort_s: float = 20.0
    telemetry_rate_hz: float = 30.0
    stream_request_retry_s: float = 2.0
    telemetry_wait_s: float = 15.0
    max_vehicle_speed_m_s: float = 40.0
    telemetry_hold_s: float = 2.0
    prime_s: float = 1.0
    offboard_retry_s: float = 1.5
    max_speed_m_s: float = 1.0
    max_yaw_rate_deg_s: float = 60.0
    lead_m: float = 1.0
    bounds_min_m: tuple[float, float, float] | None = None
    bounds_max_m: tuple[float, float, float] | None = None
    box_margin_m: float = 0.02
    max_entry_m: float = 1.0
    origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gimbal: dict = field(default_factory=dict)
    state_rate_hz: float = 30.0
    diagnostics_period_s: float = 1.0
    emulate: bool = False
    emulator: dict = field(default_factory=dict)

    def __post_init__(self):
        from aes_planner.drone.connection import parse_connection

        self.connection_parsed = parse_connection(self.connection, "connection")
        require(self.autopilot in AUTOPILOTS, "autopilot", f"must be {' or '.join(AUTOPILOTS)}, got {self.autopilot!r}")
        require(
            self.heartbeat_type in ("onboard_controller", "gcs"),
            "heartbeat_type",
            f"must be onboard_controller or gcs, got {self.heartbeat_type!r}",
        )
        for name, lo in (("vehicle_system_id", 0), ("source_system", 0), ("source_component", 1)):
            v = getattr(self, name)
            require(isinstance(v, int) and lo <= v <= 255, name, f"must be an integer in {lo}-255, got {v!r}")
        require_numbers(
            self,
            (
                "stream_rate_hz",
                "heartbeat_timeout_s",
                "pose_timeout_s",
                "link_loss_abort_s",
                "telemetry_rate_hz",
                "stream_request_retry_s",
                "telemetry_wait_s",
                "max_vehicle_speed_m_s",
                "telemetry_hold_s",
                "offboard_retry_s",
                "max_speed_m_s",
                "max_yaw_rate_deg_s",
                "lead_m",
                "state_rate_hz",
                "diagnostics_period_s",
            ),
        )
        require_numbers(self, ("prime_s", "box_margin_m", "max_entry_m"), strict=False)
        require(
            2.5 <= self.stream_rate_hz <= 100,
            "stream_rate_hz",
            f"must be in [2.5, 100] (PX4 needs > 2), got {self.stream_rate_hz}",
        )
        require(self.max_speed_m_s <= 20, "max_speed_m_s", f"must be <= 20, got {self.max_speed_m_s}")
        require(
            0.5 <= self.telemetry_rate_hz <= 100,
            "telemetry_rate_hz",
            f"must be in [0.5, 100], got {self.telemetry_rate_hz}",
        )
        require(
            self.max_speed_m_s <= self.max_vehicle_speed_m_s <= 1000,
            "max_vehicle_speed_m_s",
            f"must be in [max_speed_m_s, 1000], got {self.max_vehicle_speed_m_s}",
        )
        for name in (
            "heartbeat_timeout_s",
            "pose_timeout_s",
            "link_loss_abort_s",
            "telemetry_wait_s",
            "telemetry_hold_s",
        ):
            require(getattr(self, name) <= 3600, name, f"must be at most 3600 s, got {getattr(self, name)}")
        modes = self.engage_modes if self.engage_modes is not None else DEFAULT_ENGAGE_MODES[self.autopilot]
        require(
            isinstance(modes, list) and all(isinstance(m, str) for m in modes),
            "engage_modes",
            f"expected a list of mode names, got {modes!r}",
        )
        self.engage_mode_list = list(modes)
        require(
            (self.bounds_min_m is None) == (self.bounds_max_m is None), "bounds_max_m", "give both bounds or neither"
        )
        if self.bounds_min_m is not None:
            DroneBox(tuple(self.bounds_min_m), tuple(self.bounds_max_m))
        require(all(math.isfinite(v) for v in self.origin_m), "origin_m", f"must be finite, got {self.origin_m}")
        self.gimbal_config = from_dict(GimbalConfig, self.gimbal, "gimbal")
        if self.emulate:
            from aes_planner.drone.emulator import EmulatorConfig

            from_dict(EmulatorConfig, self.emulator, "emulator")  # a bad key fails here, named
            require(
                self.connection_parsed.scheme == "udpin",
                "emulate",
                f"the emulator sends to a udpin connection; got {self.connection!r}",
            )


class MavlinkDroneNode(Node):
    """See the module docstring."""

    config_class = MavlinkDroneConfig
    inputs = {"planner/suggestion": (ViewSuggestion, 8), "planner/diagnostics": (Diagnostics, 8)}
    outputs = {"drone/state": (DroneState, False), "drone/diagnostics": (Diagnostics, False)}

    @classmethod
    def sim_clock_problem(cls, config) -> str | None:
        return "talks MAVLink to a vehicle (or its emulator), which flies in real time"

    def __init__(
        self, config: MavlinkDroneConfig | None = None, node_id: str = "drone", context: LaunchContext | None = None
    ):
        super().__init__(config or MavlinkDroneConfig(), node_id, context)
        c = self.config
        if c.bounds_min_m is not None:
            self.box = DroneBox(tuple(c.bounds_min_m), tuple(c.bounds_max_m))
        elif self.context.scene is not None:
            from aes_planner.sim.source import platform_of

            self.box = platform_of(launch_scene(self.context)).free_box()  # a rig scene: around its base
        else:
            raise ConfigError(
                f"{node_id}.bounds_min_m", "give the flight box (bounds_min_m, bounds_max_m; world ENU) or a scene"
            )
        corners = fr.enu_to_ned(np.array([self.box.bounds_min_m, self.box.bounds_max_m]) - np.asarray(c.origin_m))
        self.lo_ned, self.hi_ned = corners.min(0), corners.max(0)
        self.link = None
        self.emulator = None
        self._last_state_s = -math.inf
        self._last_position_s = -math.inf
        self._last_diag = -math.inf
        self._seq = {"state": 0, "diagnostics": 0}  # per topic: each counts its own messages from 1
        self.planner_state = ""

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.state_rate_hz

    @property
    def aborted(self) -> bool:
        """The link has been lost (or never came up) for ``link_loss_abort_s``, or the vehicle was
        heard but its position never arrived within ``telemetry_wait_s``: the run should end."""
        return self.abort_reason() is not None

    def abort_reason(self) -> str | None:
        """Why the run should end (one line naming what is missing), or None."""
        link, c = self.link, self.config
        if link is None:
            return None
        now = link.clock()
        if link.sysid is None:
            if now - link.started_s > c.link_loss_abort_s:
                return (
                    f"no MAVLink vehicle heard on {c.connection} within {c.link_loss_abort_s:g} s (link_loss_abort_s); "
                    "is it sending there (PX4 SITL: udp 14540)?"
                )
            return None
        if link.last_position_s == -math.inf and link.first_heartbeat_s is not None:
            if now - link.first_heartbeat_s > c.telemetry_wait_s:
                missing = ", ".join(link.missing) or "LOCAL_POSITION_NED"
                garbage = link.counters.get("telemetry_implausible", 0)
                if garbage:
                    return (
                        f"the vehicle (system {link.sysid}) sent only implausible positions ({garbage} LOCAL_POSITION_NED "
                        f"refused) within {c.telemetry_wait_s:g} s (telemetry_wait_s); check its position estimate"
                    )
                return (
                    f"the vehicle (system {link.sysid}) sends heartbeats but no {missing} within {c.telemetry_wait_s:g} s "
                    f"(telemetry_wait_s) after {link.counters.get('stream_requests_sent', 0)} requests "
                    "(MAV_CMD_SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM); give the port those streams (ArduPilot: "
                    "SRn_POSITION and SRn_EXTRA1 of its port, the MAVn_* stream rates on newer firmware) and check "
                    "that it has a position estimate"
                )
            return None
        if link.lost_since is not None and now - link.lost_since > c.link_loss_abort_s:
            return (
                f"the vehicle's link was lost for more than {c.link_loss_abort_s:g} s; the run ends (the vehicle holds)"
            )
        return None

    def start(self) -> None:
        from aes_planner.drone.process import EmulatorProcess, LinkProxy

        c = self.config
        if c.emulate and self.emulator is None:
            self.emulator = EmulatorProcess(self._emulator_config()).start()
        self.link = LinkProxy(c, self.lo_ned, self.hi_ned)  # in its own process: no GIL stalls
        try:
            self.link.start()
        except Exception as exc:
            self.stop()
            raise NodeError(f"{self.node_id}: cannot open {c.connection!r}: {exc}") from exc

    def stop(self) -> None:
        if self.link is not None:
            self.link.stop()  # the stream stops: PX4 falls back to its offboard-loss action (hold)
        if self.emulator is not None:
            self.emulator.stop()

    def _emulator_config(self):
        from aes_planner.drone.emulator import EmulatorConfig
        from aes_planner.node.sim_drone import _survey_start

        c = self.config
        conn = c.connection_parsed
        start = _survey_start(self.box)  # the sim drone's start: the box's centre, looking east
        defaults = {
            "connection": f"udpout:{'127.0.0.1' if conn.host in ('0.0.0.0', 'localhost') else conn.host}:{conn.port}",
            "autopilot": c.autopilot,
            "start_ned_m": tuple(fr.enu_to_ned(start[:3, 3] - np.asarray(c.origin_m)).tolist()),
            "start_heading_deg": 90.0,
            "start_gimbal_pitch_deg": -5.0,
            "fence_min_ned_m": tuple(self.lo_ned.tolist()),
            "fence_max_ned_m": tuple(self.hi_ned.tolist()),
            "gimbal_axes": c.gimbal_config.axes,
        }
        return from_dict(EmulatorConfig, {**defaults, **c.emulator}, "emulator")

    # ------------------------------------------------------------------------------ step
    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        out: Outputs = {"drone/state": [], "drone/diagnostics": []}
        link = self.link
        if link is None:
            return out
        for d in inputs.get("planner/diagnostics", ()):
            self.planner_state = d.state
            link.set_planner_stopped(d.state in ("done", "failed"))
        for s in inputs.get("planner/suggestion", ()):
            if s.candidates:
                link.set_view_goal(s.candidates[0].view, now)
        with link.lock:
            state = self._state(link, now)
        if state is not None:
            out["drone/state"].append(state)
        if now - self._last_diag >= self.config.diagnostics_period_s:
            self._last_diag = now
            out["drone/diagnostics"].append(self.diagnostics(now))
        return out

    def _state(self, link, now: float) -> DroneState | None:
        """The newest telemetry as a DroneState (None when nothing new arrived)."""
        if link.last_position_s <= self._last_position_s or link.sysid is None:
            return None
        self._last_position_s = link.last_position_s
        c = self.config
        r_cam, pitch, yaw = link.camera_rotation_ned(now)
        c2w = fr.pose_to_cam2world(link.position_ned, r_cam, link.r_ned_frd, c.gimbal_config.mount_frd_m, c.origin_m)
        att = fr.matrix_to_quat(fr.body_flu_in_enu(link.r_ned_frd))
        self._seq["state"] += 1
        try:
            return DroneState(
                link.last_position_s,
                c2w,
                fr.ned_to_enu(link.position_ned) + np.asarray(c.origin_m),
                fr.ned_to_enu(link.velocity_ned),
                att,
                pitch,
                -yaw,
                link.mode[:64],
                link.armed,
                link.sysid,
                "lost" if link.status == "link_lost" else "ok",
                link.status,
                self._seq["state"],
            )
        except Exception as exc:  # non-finite telemetry that slipped through: counted, not published
            link.counters["telemetry_rejected"] += 1
            log.warning("%s: state not published: %s", self.node_id, exc)
            return None

    def diagnostics(self, now: float) -> Diagnostics:
        link = self.link
        with link.lock:
            counters = {**link.counters, **link.gate.counters}
            lat = list(link.goal_latencies_s)
            values = {
                "setpoint_latency_p50_s": (float(np.percentile(lat, 50)) if len(lat) else 0.0),
                "telemetry_age_s": min(now - link.last_position_s, 1e6),
                "heartbeat_age_s": min(now - link.last_heartbeat_s, 1e6),
            }
            if link.lost_since is not None:
                values["link_lost_s"] = now - link.lost_since
            status = f"{link.status} mode={link.mode or '?'} armed={link.armed}"
        return Diagnostics(now, self.node_id, status[:256], counters, values, self._next("diagnostics"))

    def _next(self, topic: str) -> int:
        self._seq[topic] += 1
        return self._seq[topic]
