"""The MAVLink link (and the emulator of a dry run) each in a process of its own.

A setpoint stream must not stall: PX4 drops offboard after 0.5 s without one. In the planner's
process, compiled rasterizer kernels hold the GIL for up to a few hundred milliseconds (measured:
gaps of 0.2 s at 20 Hz with the link in a thread), so the link runs in a child process (spawned:
it imports numpy and pymavlink only) and talks to the node over a pipe: goals and the planner's
state go down, snapshots of the vehicle (at each new position, at least every 0.1 s) come up.
:class:`LinkProxy` mirrors the snapshot under the attribute names of
:class:`~aes_planner.drone.link.MavlinkLink`, so the node reads either the same way.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import os
import threading
import time
from types import SimpleNamespace

import numpy as np

from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)

__all__ = ["DroneProcessError", "EmulatorProcess", "LinkProxy"]


class DroneProcessError(AesPlannerError):
    """The link's (or the emulator's) process did not start: its reason, and what to check."""


_SNAPSHOT = (
    "status",
    "sysid",
    "mode",
    "armed",
    "last_position_s",
    "last_heartbeat_s",
    "lost_since",
    "started_s",
    "position_ned",
    "velocity_ned",
    "r_ned_frd",
    "heading",
    "goal_latencies_s",
    "first_heartbeat_s",
)


def _raise_priority(what: str) -> None:
    """Ask the scheduler to run this process before compute (nice -10; allowed for root or with
    CAP_SYS_NICE, else it keeps the default and says so once): a loaded machine otherwise stalls
    the stream for longer than a setpoint period (0.185 s measured at load 9 on 2 cores)."""
    try:
        os.nice(-10)
    except OSError:
        log.info("%s: cannot raise its priority (not root, no CAP_SYS_NICE); it runs at the default", what)


def _link_main(config: dict, lo, hi, pipe, log_level: int) -> None:  # the child process
    from aes_planner.drone.link import MavlinkLink

    logging.basicConfig(level=log_level, format="%(levelname)s %(name)s: %(message)s")
    _raise_priority("the MAVLink link")
    cfg = SimpleNamespace(**config)
    cfg.gimbal_config = SimpleNamespace(**config["gimbal_config"])
    link = MavlinkLink(cfg, lo, hi)
    try:
        link.start()
    except Exception as exc:
        pipe.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    pipe.send(("started", link.started_s))
    sent_pos, sent_s = None, 0.0
    try:
        while True:
            while pipe.poll(0.005):
                kind, value = pipe.recv()
                if kind == "stop":
                    return
                if kind == "goal":
                    link.set_view_goal(value[0], value[1])
                elif kind == "planner_stopped":
                    with link.lock:
                        link.planner_stopped = bool(value)
            now = time.time()
            with link.lock:
                if link.last_position_s == sent_pos and now - sent_s < 0.1:
                    continue
                sent_pos, sent_s = link.last_position_s, now
                snap = {k: getattr(link, k) for k in _SNAPSHOT}
                snap["goal_latencies_s"] = list(link.goal_latencies_s[-64:])
                snap["counters"] = {**link.counters, **link.gate.counters}
                snap["camera"] = link.camera_rotation_ned(now)
                snap["missing"] = link.missing_telemetry(now)
            pipe.send(("state", snap))
    except (EOFError, BrokenPipeError, OSError):
        pass
    finally:
        link.stop()


class LinkProxy:
    """The parent's view of the link process (see the module docstring)."""

    def __init__(self, config, lo_ned_m, hi_ned_m):
        from dataclasses import asdict

        d = {k: v for k, v in asdict(config).items() if k not in ("gimbal", "emulator")}
        d["engage_mode_list"] = list(config.engage_mode_list)
        d["gimbal_config"] = asdict(config.gimbal_config)
        self._args = (d, np.asarray(lo_ned_m), np.asarray(hi_ned_m))
        self.config = config
        self.clock = time.time
        self.lock = threading.Lock()
        self.status, self.sysid, self.mode, self.armed = "waiting_for_vehicle", None, "", False
        self.last_position_s = self.last_heartbeat_s = -math.inf
        self.lost_since = None
        self.first_heartbeat_s: float | None = None
        self.missing: list[str] = []
        self.started_s = time.time()
        self.position_ned, self.velocity_ned, self.r_ned_frd, self.heading = np.zeros(3), np.zeros(3), np.eye(3), 0.0
        self.goal_latencies_s: list[float] = []
        self.counters: dict = {}
        self.gate = SimpleNamespace(counters={})
        self.planner_stopped = False
        self._camera = (np.eye(3), 0.0, 0.0)
        self._pipe = None
        self._proc = None
        self._reader: threading.Thread | None = None

    def start(self, timeout_s: float = 60.0) -> None:
        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_link_main, args=(*self._args, child, logging.getLogger().level), name="mavlink-link", daemon=True
        )
        self._proc.start()
        child.close()
        self._pipe = parent
        if not parent.poll(timeout_s):
            self.stop()
            raise DroneProcessError(
                f"the MAVLink link's process did not start within {timeout_s:g} s; is the machine overloaded?"
            )
        kind, value = parent.recv()
        if kind == "error":
            self.stop()
            raise DroneProcessError(f"the MAVLink link did not open: {value}; check the connection string")
        self.started_s = value
        self._reader = threading.Thread(target=self._read, name="mavlink-link-reader", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        try:
            while True:
                kind, snap = self._pipe.recv()
                with self.lock:
                    for k in _SNAPSHOT:
                        setattr(self, k, snap[k])
                    self.counters = snap["counters"]
                    self.missing = snap["missing"]
                    self._camera = snap["camera"]
        except (EOFError, OSError):
            return

    def set_view_goal(self, view, now: float) -> None:
        self._send(("goal", (np.asarray(view, dtype=np.float64), now)))

    def set_planner_stopped(self, stopped: bool) -> None:
        if stopped != self.planner_stopped:
            self.planner_stopped = stopped
            self._send(("planner_stopped", stopped))

    def _send(self, item) -> None:
        try:
            if self._pipe is not None:
                self._pipe.send(item)
        except (BrokenPipeError, OSError):
            log.error("the MAVLink link process is gone; nothing is being streamed")

    def camera_rotation_ned(self, now: float):
        return self._camera

    def stop(self) -> None:
        """Stop the process: streaming stops (the vehicle runs its offboard-loss failsafe)."""
        self._send(("stop", None))
        if self._proc is not None:
            self._proc.join(5.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(2.0)
            self._proc = None
        if self._pipe is not None:
            self._pipe.close()
            self._pipe = None


def _emulator_main(config, pipe, log_level: int) -> None:
    from aes_planner.drone.emulator import VehicleEmulator

    logging.basicConfig(level=log_level, format="%(levelname)s %(name)s: %(message)s")
    _raise_priority("the vehicle emulator")  # a vehicle's own clock does not stall
    try:
        emu = VehicleEmulator(config).start()
    except Exception as exc:
        pipe.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    try:
        pipe.send(("started", None))
        while True:
            try:
                kind, value = pipe.recv()
            except EOFError:
                return
            if kind == "cut_link":
                emu.cut_link(value)
            pipe.send(("report", emu.report()))
            if kind == "stop":
                return
    finally:
        emu.stop()


class EmulatorProcess:
    """A :class:`~aes_planner.drone.emulator.VehicleEmulator` in a spawned process."""

    def __init__(self, config):
        self.config = config
        self._proc = None
        self._pipe = None
        self.last_report: dict = {}
        self._lock = threading.Lock()

    def start(self) -> EmulatorProcess:
        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_emulator_main,
            args=(self.config, child, logging.getLogger().level),
            name="vehicle-emulator",
            daemon=True,
        )
        self._proc.start()
        child.close()
        self._pipe = parent
        if not parent.poll(60.0):
            self.stop()
            raise DroneProcessError(
                "the vehicle emulator's process did not start within 60 s; is the machine overloaded?"
            )
        kind, value = parent.recv()
        if kind == "error":
            self.stop()
            raise DroneProcessError(f"the vehicle emulator did not start: {value}")
        return self

    def report(self) -> dict:
        with self._lock:
            if self._pipe is not None:
                try:
                    self._pipe.send(("report", None))
                    if self._pipe.poll(5.0):
                        self.last_report = self._pipe.recv()[1]
                except (BrokenPipeError, EOFError, OSError):
                    pass
            return self.last_report

    def cut_link(self, duration_s: float) -> dict:
        """Cut the vehicle's link from now for ``duration_s`` (:meth:`VehicleEmulator.cut_link`);
        returns the report the emulator sent once the cut was in place."""
        with self._lock:
            if self._pipe is None:
                raise DroneProcessError("the vehicle emulator is not running: start() it before cutting its link")
            self._pipe.send(("cut_link", float(duration_s)))
            if not self._pipe.poll(30.0):
                raise DroneProcessError("the vehicle emulator did not answer within 30 s; is the machine overloaded?")
            self.last_report = self._pipe.recv()[1]
            return self.last_report

    def stop(self) -> None:
        with self._lock:
            if self._pipe is not None:
                try:
                    self._pipe.send(("stop", None))
                    if self._pipe.poll(5.0):
                        self.last_report = self._pipe.recv()[1]
                except (BrokenPipeError, EOFError, OSError):
                    pass
                self._pipe.close()
                self._pipe = None
            if self._proc is not None:
                self._proc.join(5.0)
                if self._proc.is_alive():
                    self._proc.kill()
                self._proc = None
