"""``PlannerNode``: keeps the aesthetic field up to date from ``camera/frame``, suggests views, and
on a rig (or a drone that flies its suggestions) runs the **active loop**.

The active loop, readable top to bottom in :meth:`PlannerNode._advance`::

    initial   capture the view the camera starts at (it is the baseline)
    explore   visit a few poses spread over the joint range (rig) or around the start (drone),
              capturing each
    plan      build the scorer from every capture, search, and pick the best candidate that the
              same scorer expects to beat the best captured view by ``margin``
              (none, or ``max_moves`` spent -> settle)
    move      command it (``gimbal/command``; a drone flies the top candidate of
              ``planner/suggestion``), wait for arrival (``gimbal/state``, or frames at the pose)
    verify    capture there, score the real capture with the teacher, feed it into the field -> plan
    polish    climb around the best captured view with real captures: its four neighbours
              ``polish_step_deg`` away (pan/tilt; a drone: yaw/pitch), then those of a better one,
              up to ``polish_captures`` (composition peaks are a few degrees wide, narrower than
              the field sees: docs/benchmarks.md, session 12)
    settle    go back to the best captured view, capture it once more -> done

A capture is the first frame stamped at least ``settle_s`` after arrival. Every command is
clamped to the joint limits and checked finite before it leaves; a gimbal that reports a
hardware fault stops the loop (state ``fault``) until the fault clears (a reboot request to the
gimbal node), and after ``fault_timeout_s`` the loop ends (state ``failed``) with the best view
captured so far.

Passive mode (``active: false``): integrate the newest frame of each step (older ones of the same
batch are dropped and counted), publish ``planner/suggestion`` when the field changed (at most
every ``min_suggest_period_s``) or on ``planner/request``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from aes_planner.config import require, require_numbers
from aes_planner.geometry.pantilt import PanTilt, PanTiltConfig
from aes_planner.geometry.plausible import distance_problem
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.graph.base import LaunchContext, Node, NodeError, Outputs, percentile
from aes_planner.images import downscale_frame
from aes_planner.messages import (
    Candidate,
    Diagnostics,
    GimbalCommand,
    GimbalState,
    MessageError,
    PlannerRequest,
    PosedFrame,
    ViewSuggestion,
)
from aes_planner.node.proposer import FieldProposer, Proposer
from aes_planner.runtime import MAX_THREADS, ThreadGovernor, set_threads, suggestion_threads
from aes_planner.sources import DroneBox, Platform

log = logging.getLogger(__name__)

__all__ = ["Capture", "DroneBoxConfig", "PlannerConfig", "PlannerNode"]


@dataclass
class DroneBoxConfig:
    """The flight box of a drone (world metres)."""

    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]

    def box(self) -> DroneBox:
        return DroneBox(tuple(self.bounds_min_m), tuple(self.bounds_max_m))

    def __post_init__(self):
        self.box()


@dataclass
class PlannerConfig:
    """How the planner builds its field, searches and (on a rig) drives the active loop.

    * ``scorer``: ``"field"`` (the trained aesthetic field, the default: better and faster in the
      closed loop on held-out scenes, docs/benchmarks.md) or ``"rgb"`` (RGB scoring of the
      reconstruction).
    * ``preset``: search preset (``fast``, ``balanced``, ``accurate``); ``teacher``: the teacher name.
    * ``active``: run the active loop (commands the gimbal / flies the drone); false = suggest only.
    * ``explore_views``: captures spread over the range before the first suggestion.
    * ``max_moves``: suggestion-driven moves at most; ``margin``: the gain (teacher units) a
      suggestion must promise over the best captured view to be worth a move. The promise is the
      scorer's prediction calibrated on the captures (their true teacher scores: ``true = pred +
      offset``, offset the median residual) plus ``optimism`` times the residuals' spread (at
      least ``min_sigma``): a scorer that is often wrong earns more checks. Errors at captures
      within about ``residual_length_deg`` of a candidate correct it most (and shrink its spread).
    * ``min_move_deg``: a candidate closer than this (view direction) to a captured view, with
      no more than ``min_move_m`` of translation, is not a new view.
    * ``polish_captures``: captures spent, after the last move, on a hill climb around the best
      captured view (neighbours ``polish_step_deg`` away in pan and tilt, or yaw and pitch for a
      drone; the climb moves to a better neighbour and stops when none is better); 0 = settle
      at once. ``polish_step_deg`` should exceed ``arrival_tolerance_deg``.
    * ``top_k``: candidates per published suggestion.
    * ``max_frames``: frames the field holds (memory bound); captures are kept before passive frames.
    * ``arrival_tolerance_deg`` / ``arrival_tolerance_m``: how close counts as arrived;
      ``settle_s``: wait after arrival before a frame counts as the capture;
      ``move_timeout_s``: give up on a target after this long; a camera that sends no frame
      for this long after an arrival ends the loop (``failed``, the captures so far kept).
    * ``max_stamp_ahead_s``: a frame or gimbal state stamped further ahead of this node's clock
      is rejected and counted: kept as the newest, it would hide every later one (a publisher
      whose clock is wrong; synchronise the machines' clocks, e.g. with chrony).
    * ``fault_timeout_s``: how long a hardware fault may last before the loop ends.
    * ``min_suggest_period_s``: passive mode, the shortest time between suggestions.
    * ``diagnostics_period_s``: how often ``planner/diagnostics`` is published.
    * ``rig`` / ``drone``: the platform (a sim launch fills it from the scene).
    * ``mode``: ``auto`` (the platform given or the scene's), ``rig`` or ``free`` (a drone; on a
      rig scene, a box around the rig's base).
    * ``seed``: for the search's sampling.
    * ``threads``: CPU threads for the planner's torch and numba work (torch's count is
      process-wide); 0 = torch's default, all cores. 1 keeps a suggestion steady beside busy
      processes (``balanced``, 2 cores, one busy process beside: 0.86 s with 1 thread, 2.1 s with
      2; idle 0.76 s against 0.62 s; docs/benchmarks.md, "Threading layer").
    * ``adapt_threads``: with ``threads: 0``, let a :class:`~aes_planner.runtime.ThreadGovernor`
      try one thread when the suggestions do not get the cores (a busy neighbour), keep whichever
      count runs them faster, and probe all cores again now and then; diagnostics report
      ``threads``, ``cpu_efficiency`` and ``thread_changes``.
    """

    scorer: str = "field"
    preset: str = "balanced"
    teacher: str = "composition"
    active: bool = True
    explore_views: int = 6
    max_moves: int = 6
    margin: float = 0.01
    optimism: float = 1.0
    min_sigma: float = 0.02
    residual_length_deg: float = 15.0
    min_move_deg: float = 3.0
    min_move_m: float = 0.1
    polish_captures: int = 8
    polish_step_deg: float = 2.5
    top_k: int = 3
    max_frames: int = 24
    arrival_tolerance_deg: float = 1.5
    arrival_tolerance_m: float = 0.05
    settle_s: float = 0.05
    move_timeout_s: float = 20.0
    max_stamp_ahead_s: float = 5.0
    fault_timeout_s: float = 10.0
    min_suggest_period_s: float = 0.5
    diagnostics_period_s: float = 1.0
    rig: PanTiltConfig | None = None
    drone: DroneBoxConfig | None = None
    mode: str = "auto"
    seed: int = 0
    threads: int = 0
    adapt_threads: bool = True

    def __post_init__(self):
        require(self.scorer in ("field", "rgb"), "scorer", f"must be 'field' or 'rgb', got {self.scorer!r}")
        require(
            self.preset in ("fast", "balanced", "accurate"),
            "preset",
            f"must be fast, balanced or accurate, got {self.preset!r}",
        )
        for name in ("explore_views", "max_moves", "top_k", "max_frames", "threads", "polish_captures"):
            v = getattr(self, name)
            require(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0, name, f"must be an integer >= 0, got {v!r}"
            )
        require(self.top_k >= 1, "top_k", f"must be >= 1, got {self.top_k}")
        from aes_planner.messages.suggestion import MAX_CANDIDATES

        # a suggestion message holds at most MAX_CANDIDATES (more failed every publish)
        require(self.top_k <= MAX_CANDIDATES, "top_k", f"must be <= {MAX_CANDIDATES}, got {self.top_k}")
        for name, most in (
            ("explore_views", 64),
            ("polish_captures", 64),
            ("max_moves", 10_000),
            ("max_frames", 1024),
            ("threads", MAX_THREADS),
        ):
            v = getattr(self, name)
            require(v <= most, name, f"must be <= {most}, got {v}")
        require(self.max_frames >= 2, "max_frames", f"must be >= 2, got {self.max_frames}")
        require_numbers(
            self, ("margin", "optimism", "min_sigma", "min_move_deg", "min_move_m", "settle_s"), strict=False
        )
        require_numbers(self, ("residual_length_deg", "polish_step_deg"))
        require(self.polish_step_deg <= 30.0, "polish_step_deg", f"must be <= 30, got {self.polish_step_deg}")
        require_numbers(
            self,
            (
                "arrival_tolerance_deg",
                "arrival_tolerance_m",
                "move_timeout_s",
                "max_stamp_ahead_s",
                "fault_timeout_s",
                "min_suggest_period_s",
                "diagnostics_period_s",
            ),
        )
        for name, most in (  # time-like knobs: an hour at most (1e6 s waited as good as forever)
            ("settle_s", 60.0),
            ("move_timeout_s", 3600.0),
            ("max_stamp_ahead_s", 3600.0),
            ("fault_timeout_s", 3600.0),
            ("min_suggest_period_s", 3600.0),
            ("diagnostics_period_s", 3600.0),
        ):
            v = getattr(self, name)
            require(v <= most, name, f"must be <= {most:g} s, got {v}")
        require(self.rig is None or self.drone is None, "drone", "give a rig or a drone, not both")
        require(self.mode in ("auto", "rig", "free"), "mode", f"must be auto, rig or free, got {self.mode!r}")


@dataclass
class Capture:
    """A view the active loop captured and scored with the teacher (the real image)."""

    kind: str  # initial | explore | move | polish | settle
    cam2world: np.ndarray  # [4, 4]
    score: float
    stamp_s: float
    pan_rad: float | None = None
    tilt_rad: float | None = None
    predicted: float | None = None
    image: np.ndarray | None = field(default=None, repr=False)  # [H, W, 3] uint8


@dataclass
class _Target:
    kind: str
    cam2world: np.ndarray  # [4, 4]
    pan_rad: float | None = None
    tilt_rad: float | None = None
    predicted: float | None = None
    sent_s: float = -1.0
    arrived_s: float | None = None
    resent: bool = False


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two rotations' optical axes, degrees."""
    za, zb = a[:3, 2], b[:3, 2]
    return math.degrees(math.atan2(np.linalg.norm(np.cross(za, zb)), float(np.dot(za, zb))))


class PlannerNode(Node):
    """The planner; see the module docstring. ``proposer`` replaces the field + search (tests)."""

    config_class = PlannerConfig
    inputs = {
        "camera/frame": (PosedFrame, 4),
        "gimbal/state": (GimbalState, 8),
        "planner/request": (PlannerRequest, 8),
    }
    outputs = {
        "gimbal/command": (GimbalCommand, False),
        "planner/suggestion": (ViewSuggestion, True),
        "planner/diagnostics": (Diagnostics, False),
    }

    def __init__(
        self,
        config: PlannerConfig | None = None,
        node_id: str = "planner",
        context: LaunchContext | None = None,
        proposer: Proposer | None = None,
        teacher=None,
    ):
        config = config or PlannerConfig()
        if config.rig is None and config.drone is None and context is not None and context.scene is not None:
            config = _platform_from_scene(config, context.load_scene())
        super().__init__(config, node_id, context)
        c = self.config
        self.kinematics = PanTilt(c.rig) if c.rig is not None else None
        self.mode = "rig" if c.rig is not None else "free"
        self._teacher = teacher
        self.proposer = proposer
        self.state = "waiting"
        self.platform: Platform | None = None
        self.captures: list[Capture] = []
        self.suggestions: list[ViewSuggestion] = []  # every suggestion published (bounded)
        self.moves = 0
        self.counters = dict.fromkeys(
            (
                "frames_in",
                "frames_dropped",
                "frames_rejected",
                "frames_used",
                "states_in",
                "states_rejected",
                "requests_in",
                "commands_sent",
                "commands_refused",
                "suggestions",
                "captures",
                "moves",
                "move_timeouts",
                "capture_timeouts",
                "faults",
            ),
            0,
        )
        self.latencies_s: deque[float] = deque(maxlen=256)
        self._threads_set_in: int | None = None  # ident of the thread whose numba count was set
        self.governor: ThreadGovernor | None = None  # threads 0 + adapt_threads: made on the first step
        self.cpu_clock = time.process_time  # CPU seconds of the whole process (tests replace it)
        self._intrinsics = None
        self._kernels_warm = False  # the rasterizer's kernels compiled or loaded (start())
        self._ahead_seen = 0  # messages rejected for stamps ahead of the clock
        self._frame: PosedFrame | None = None  # newest accepted frame
        self._gimbal: GimbalState | None = None  # newest gimbal state
        self._queue: list[_Target] = []
        self._target: _Target | None = None
        self._polish_left = 0
        self._polish_centre: Capture | None = None
        self._fault_since: float | None = None
        self._last_diag = -math.inf
        self._last_suggest = -math.inf
        self._dirty = False
        self._suggest_requested = False
        self._seq = {"cmd": 0, "sugg": 0, "diag": 0}
        self.started_s: float | None = None
        self.finished_s: float | None = None

    # ------------------------------------------------------------------------------ lifecycle
    @property
    def period_s(self) -> float:
        return 0.02

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed")

    @property
    def teacher(self):
        if self._teacher is None:
            from aes_planner.teachers import get_teacher

            self._teacher = get_teacher(self.config.teacher).freeze()
        return self._teacher

    def start(self) -> None:
        if self.proposer is None:
            c = self.config
            self.proposer = FieldProposer(c.scorer, c.preset, self.teacher, c.max_frames, c.seed)
        _ = self.teacher
        if isinstance(self.proposer, FieldProposer) and not self._kernels_warm:  # now, not in the first plan
            from aes_planner.gaussians.warmup import warm_kernels

            warm_kernels()
            self._kernels_warm = True

    # ----------------------------------------------------------------------------------- step
    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        out: Outputs = {"gimbal/command": [], "planner/suggestion": [], "planner/diagnostics": []}
        if self.proposer is None:
            self.start()
        if self.config.threads and self._threads_set_in != threading.get_ident():
            set_threads(self.config.threads)  # numba's count is per thread: set where the steps run
            self._threads_set_in = threading.get_ident()
        elif not self.config.threads and self.config.adapt_threads and self.governor is None:
            self.governor = ThreadGovernor(torch.get_num_threads())  # torch's default: all cores
        if self.started_s is None:
            self.started_s = now
        self._take_inputs(inputs, now)
        if self.config.active:
            if not self.finished:
                self._advance(now, out)
        else:
            self._passive(now, out)
        if self._suggest_requested and self.suggestions and not out["planner/suggestion"]:
            out["planner/suggestion"].append(self.suggestions[-1])
        self._suggest_requested = False
        if now - self._last_diag >= self.config.diagnostics_period_s or (self.finished and self.finished_s == now):
            self._last_diag = now
            out["planner/diagnostics"].append(self.diagnostics(now))
        return out

    def _take_inputs(self, inputs: Mapping[str, list], now: float) -> None:
        frames = list(inputs.get("camera/frame", ()))
        self.counters["frames_in"] += len(frames)
        if len(frames) > 1:  # dropped to the latest: only the newest of a batch is looked at
            self.counters["frames_dropped"] += len(frames) - 1
        if frames:
            if self._ahead(frames[-1], now):
                self.counters["frames_rejected"] += 1
            else:
                self._accept_frame(frames[-1])
        states = list(inputs.get("gimbal/state", ()))
        self.counters["states_in"] += len(states)
        for s in states:
            if not isinstance(s, GimbalState) or self._ahead(s, now):
                self.counters["states_rejected"] += 1
            elif self._gimbal is None or s.stamp_s >= self._gimbal.stamp_s:
                self._gimbal = s
        for req in inputs.get("planner/request", ()):
            self.counters["requests_in"] += 1
            self._on_request(req)

    def _ahead(self, msg, now: float) -> bool:
        """Stamped more than ``max_stamp_ahead_s`` after ``now`` (said in the log, sparingly)."""
        ahead_s = getattr(msg, "stamp_s", now) - now
        if not ahead_s > self.config.max_stamp_ahead_s:
            return False
        self._ahead_seen += 1
        if self._ahead_seen in (1, 10, 100) or self._ahead_seen % 1000 == 0:
            log.warning(
                "%s: %s stamped %.3g s ahead of this node's clock: rejected (%d so far); synchronise the clocks",
                self.node_id,
                type(msg).__name__,
                ahead_s,
                self._ahead_seen,
            )
        return True

    def _accept_frame(self, frame) -> None:
        if not isinstance(frame, PosedFrame):
            self.counters["frames_rejected"] += 1
            return
        frame = downscale_frame(frame)  # a 12 MP camera held at full size: gigabytes the field cannot see
        k = frame.intrinsics
        if self._intrinsics is None:
            self._intrinsics = k
        elif (k.width, k.height) != (self._intrinsics.width, self._intrinsics.height):
            self.counters["frames_rejected"] += 1
            log.warning(
                "%s: frame %s is %dx%d, the field is %dx%d: rejected",
                self.node_id,
                frame.frame_id,
                k.width,
                k.height,
                self._intrinsics.width,
                self._intrinsics.height,
            )
            return
        if self._frame is not None and frame.stamp_s < self._frame.stamp_s:
            self.counters["frames_rejected"] += 1  # out of order: older than what we have
            return
        if self._frame is not None and distance_problem(frame.cam2world, self._frame.cam2world):
            self.counters["frames_rejected"] += 1  # not the scene the field models (plausibility bounds)
            return
        self._frame = frame
        if self.platform is None:
            self.platform = self._make_platform(k)

    def _make_platform(self, intrinsics) -> Platform:
        c = self.config
        if c.rig is not None:
            return Platform("rig", intrinsics, rig=c.rig)
        if c.drone is not None:
            return Platform("drone", intrinsics, drone=c.drone.box())
        raise NodeError(
            f"{self.node_id}: no platform: give the planner a 'rig' (pan_tilt kinematics and limits) or a 'drone' box, "
            "or a 'scene' in the launch file"
        )

    def _on_request(self, req) -> None:
        kind = getattr(req, "kind", "suggest")
        if kind == "suggest":
            self._suggest_requested = True
            self._dirty = self._dirty or not self.config.active
        elif kind == "reset":
            if self.proposer is not None:
                self.proposer.reset()
            self.captures.clear()
            self._queue.clear()
            self._target = None
            self.moves = 0
            self.state = "waiting"
        elif kind == "stop" and self.config.active and not self.finished:
            self._queue.clear()
            self._target = None
            self._begin_settle()

    # ------------------------------------------------------------------------- active loop
    def _advance(self, now: float, out: Outputs) -> None:
        if self.mode == "rig" and self._gimbal_fault(now):
            return
        if self.state == "waiting":
            if self._frame is None or (self.mode == "rig" and (self._gimbal is None or self._gimbal.moving)):
                return
            self._target = self._here("initial")
            self._target.sent_s = now
            self._target.arrived_s = now
            self.state = "initial"
        if self._target is not None:
            if self._target.arrived_s is None:
                self._check_arrival(now, out)
                return
            frame = self._frame
            if frame is None or frame.stamp_s < self._target.arrived_s + self.config.settle_s:
                if now - self._target.arrived_s > self.config.settle_s + self.config.move_timeout_s:
                    self._capture_timeout(now)
                return
            self._record_capture(self._target, frame)
            finished_target = self._target
            self._target = None
            if finished_target.kind == "settle":
                self._finish(now, "done")
                return
        # choose what comes next
        if self.state == "initial":
            self._queue = self._explore_targets()
            self.state = "exploring"
        if self.state == "exploring" and not self._queue:
            self.state = "planning"
        if self.state == "planning":
            t0 = time.perf_counter()
            nxt = self._plan(now, out)
            now += time.perf_counter() - t0  # the command leaves after the planning, not before
            if nxt is None:
                self._begin_polish()
            else:
                self._queue = [nxt]
                self.state = "moving"
        elif self.state == "moving" and not self._queue:
            self.state = "planning"
            return
        elif self.state == "polishing" and not self._queue:
            self._polish_step()
        if self._queue:
            self._target = self._queue.pop(0)
            self._send(self._target, now, out)

    def _capture_timeout(self, now: float) -> None:
        """No frame since the arrival: the camera is silent, and nothing can be captured."""
        self.counters["capture_timeouts"] += 1
        log.error(
            "%s: no usable camera frame %.1f s after arriving for the %s capture (is the camera running? %d "
            "frames rejected so far, see the warnings); the loop ends",
            self.node_id,
            now - self._target.arrived_s,
            self._target.kind,
            self.counters["frames_rejected"],
        )
        self._finish(now, "failed")

    def _here(self, kind: str) -> _Target:
        f = self._frame
        g = self._gimbal
        if self.mode == "rig" and g is not None:
            return _Target(kind, self.kinematics.forward(g.pan_rad, g.tilt_rad), g.pan_rad, g.tilt_rad)
        return _Target(kind, f.cam2world.copy())

    def _explore_targets(self) -> list[_Target]:
        n = self.config.explore_views
        if n == 0:
            return []
        if self.mode == "rig":
            joints = self.kinematics.sweep(n)  # [n, 2] left to right
            start = self.captures[-1].pan_rad if self.captures else 0.0
            if start is not None and abs(joints[-1, 0] - start) < abs(joints[0, 0] - start):
                joints = joints[::-1]
            return [_Target("explore", self.kinematics.forward(p, t), float(p), float(t)) for p, t in joints]
        # free: turn in place at the start position, yaw spread around the circle, level
        x, y, z, yaw0, _ = cam2world_to_view(self._frame.cam2world)
        targets = []
        for i in range(1, n + 1):
            yaw = yaw0 + 2 * math.pi * i / (n + 1)
            pitch = math.radians(-10.0) if i % 2 else math.radians(5.0)
            if self.config.drone is not None:
                x, y, z = self.config.drone.box().clamp([x, y, z])
            view = torch.tensor([x, y, z, math.atan2(math.sin(yaw), math.cos(yaw)), pitch], dtype=torch.float64)
            targets.append(_Target("explore", view_to_cam2world(view).numpy()))
        return targets

    def _plan(self, now: float, out: Outputs) -> _Target | None:
        """Search on the field of every capture; the best candidate worth a move, or None."""
        c = self.config
        if self.moves >= c.max_moves:
            return None
        captured = np.stack([cap.cam2world for cap in self.captures])  # [M, 4, 4]
        try:
            best = int(np.argmax([cap.score for cap in self.captures]))
            proposal = self._propose(captured, max(c.top_k, 4), keep_near=best)
        except Exception:
            log.exception("%s: planning failed; settling on the best captured view", self.node_id)
            return None
        cands = [cd for cd in proposal.candidates if self._safe_candidate(cd)]
        out["planner/suggestion"].append(self._suggestion(cands[: c.top_k], proposal.field_version, now))
        hopes = self._hopes(cands, proposal.captured_pred)
        best_true = max(cap.score for cap in self.captures)
        for i in np.argsort(-hopes, kind="stable"):
            cd = cands[int(i)]
            if hopes[i] - best_true < c.margin:
                break  # sorted by hope: no later one promises more
            if self._near_captured(cd.cam2world):
                continue
            return _Target("move", cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=float(hopes[i]))
        return None

    def _hopes(self, cands: list[Candidate], captured_pred: np.ndarray) -> np.ndarray:  # -> [C]
        """What each candidate may score (teacher units): the scorer's prediction corrected by its
        errors at the captures (true teacher score - prediction; the median error everywhere, the
        nearby captures' errors on top, by a Gaussian kernel of ``residual_length_deg`` on the view
        direction), plus ``optimism`` times the errors' spread, shrinking near the captures."""
        c = self.config
        scores = np.array([cd.score for cd in cands], dtype=np.float64)
        true = np.array([cap.score for cap in self.captures], dtype=np.float64)
        pred = np.asarray(captured_pred, dtype=np.float64)
        if not len(cands) or pred.shape != true.shape or not len(true) or not np.all(np.isfinite(pred)):
            return scores
        resid = true - pred
        offset = float(np.median(resid))
        sigma = max(float(np.sqrt(np.mean((resid - offset) ** 2))) if len(resid) > 1 else 0.0, c.min_sigma)
        hopes = np.empty(len(cands))
        for j, cd in enumerate(cands):
            ang = np.array([_angle_deg(cd.cam2world, cap.cam2world) for cap in self.captures])
            w = np.exp(-((ang / c.residual_length_deg) ** 2))
            local = float(np.sum(w * (resid - offset)) / (1.0 + np.sum(w)))
            hopes[j] = cd.score + offset + local + c.optimism * sigma / math.sqrt(1.0 + float(np.sum(w)))
        return hopes

    def _safe_candidate(self, cd: Candidate) -> bool:
        if not np.all(np.isfinite(cd.cam2world)) or not math.isfinite(cd.score):
            return False
        if self.mode == "rig":
            if cd.pan_rad is None or not (math.isfinite(cd.pan_rad) and math.isfinite(cd.tilt_rad)):
                self.counters["commands_refused"] += 1
                return False
            pan, tilt = self.kinematics.clamp(cd.pan_rad, cd.tilt_rad)
            cd.pan_rad, cd.tilt_rad = pan, tilt
            cd.cam2world = self.kinematics.forward(pan, tilt)
        elif self.config.drone is not None:
            box = self.config.drone.box()
            if not box.contains(cd.cam2world[:3, 3]):
                cd.cam2world = cd.cam2world.copy()
                cd.cam2world[:3, 3] = box.clamp(cd.cam2world[:3, 3])
        return True

    def _near_captured(self, cam2world: np.ndarray, limit_deg: float | None = None) -> bool:
        """Whether a capture looks (almost) the same way from (almost) the same place: closer than
        ``limit_deg`` (default ``min_move_deg``) with at most ``min_move_m`` between them."""
        c = self.config
        limit_deg = c.min_move_deg if limit_deg is None else limit_deg
        for cap in self.captures:
            if (
                _angle_deg(cap.cam2world, cam2world) < limit_deg
                and np.linalg.norm(cap.cam2world[:3, 3] - cam2world[:3, 3]) <= c.min_move_m
            ):
                return True
        return False

    def _begin_polish(self) -> None:
        self._polish_left = self.config.polish_captures
        self._polish_centre = None
        self.state = "polishing"
        self._polish_step()

    def _polish_step(self) -> None:
        """Queue the unvisited neighbours of the best capture when it is new (the climb moved), or
        settle: the budget is spent, or no neighbour beat the centre."""
        best = max(self.captures, key=lambda cap: cap.score) if self.captures else None
        if best is None or best is self._polish_centre or self._polish_left <= 0:
            self._begin_settle()
            return
        self._polish_centre = best
        half_step_deg = 0.5 * self.config.polish_step_deg
        targets = [t for t in self._polish_neighbours(best) if not self._near_captured(t.cam2world, half_step_deg)]
        self._queue = targets[: self._polish_left]
        self._polish_left -= len(self._queue)
        if not self._queue:
            self._begin_settle()

    def _polish_neighbours(self, cap: Capture) -> list[_Target]:
        """The four views ``polish_step_deg`` from ``cap`` in pan and tilt (a drone: yaw and pitch,
        position kept), inside the joint limits or the pitch range."""
        step = math.radians(self.config.polish_step_deg)
        offsets = ((step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step))
        out = []
        if self.mode == "rig":
            if cap.pan_rad is None or cap.tilt_rad is None:
                return []
            for dp, dt in offsets:
                pan, tilt = self.kinematics.clamp(cap.pan_rad + dp, cap.tilt_rad + dt)
                out.append(_Target("polish", self.kinematics.forward(pan, tilt), pan, tilt))
            return out
        from aes_planner.search import SearchConfig

        lo, hi = (math.radians(v) for v in SearchConfig().pitch_limits_deg)
        x, y, z, yaw, pitch = (float(v) for v in cam2world_to_view(cap.cam2world))
        for dy, dp in offsets:
            view = torch.tensor([x, y, z, yaw + dy, min(max(pitch + dp, lo), hi)], dtype=torch.float64)
            out.append(_Target("polish", view_to_cam2world(view).numpy()))
        return out

    def _begin_settle(self) -> None:
        if not self.captures:
            self._finish(time.time(), "failed")
            return
        best = max(self.captures, key=lambda cap: cap.score)
        self._queue = [_Target("settle", best.cam2world.copy(), best.pan_rad, best.tilt_rad, predicted=best.score)]
        self.state = "settling"

    def _finish(self, now: float, state: str) -> None:
        self.state = state
        self.finished_s = now
        self._queue.clear()
        self._target = None

    def _send(self, target: _Target, now: float, out: Outputs) -> None:
        target.sent_s = now
        target.arrived_s = None
        if target.kind == "move":
            self.moves += 1
            self.counters["moves"] += 1
        if self.mode == "rig":
            try:
                pan, tilt = self.kinematics.clamp(target.pan_rad, target.tilt_rad)
                cmd = GimbalCommand("move", pan, tilt, stamp_s=now, sequence=self._next("cmd"))
            except (MessageError, ValueError) as exc:
                self.counters["commands_refused"] += 1
                log.warning("%s: refused to command %s: %s", self.node_id, target, exc)
                target.arrived_s = None
                self._target = None
                return
            target.pan_rad, target.tilt_rad = pan, tilt
            target.cam2world = self.kinematics.forward(pan, tilt)
            out["gimbal/command"].append(cmd)
            self.counters["commands_sent"] += 1
        else:
            cand = Candidate(target.cam2world, target.predicted if target.predicted is not None else 0.0)
            out["planner/suggestion"].append(
                self._suggestion([cand], self.proposer.version if self.proposer else 0, now, "waypoint")
            )

    def _check_arrival(self, now: float, out: Outputs) -> None:
        t, c = self._target, self.config
        if self.mode == "rig":
            g = self._gimbal
            tol = math.radians(c.arrival_tolerance_deg)
            if g is not None and g.stamp_s > t.sent_s and not g.moving:
                at_goal = abs(g.pan_rad - g.goal_pan_rad) < tol and abs(g.tilt_rad - g.goal_tilt_rad) < tol
                goal_ok = abs(g.goal_pan_rad - t.pan_rad) < tol and abs(g.goal_tilt_rad - t.tilt_rad) < tol
                # a goal other than ours: the device clamped it (narrower limits), or this state
                # predates our command; accept it only once the device had time to see the command
                if at_goal and (goal_ok or (now - t.sent_s > 2.0 and g.stamp_s > t.sent_s + 1.0)):
                    t.arrived_s = now
                    return
        else:
            f = self._frame
            if f is not None and f.stamp_s > t.sent_s:
                close = _angle_deg(f.cam2world, t.cam2world) < c.arrival_tolerance_deg
                near = np.linalg.norm(f.cam2world[:3, 3] - t.cam2world[:3, 3]) < c.arrival_tolerance_m
                if close and near:
                    t.arrived_s = now
                    return
        waited = now - t.sent_s
        if waited > c.move_timeout_s / 2 and not t.resent:
            t.resent = True
            log.warning("%s: no arrival after %.1f s; sending the command again", self.node_id, waited)
            if t.kind == "move":
                self.moves -= 1
                self.counters["moves"] -= 1
            self._send(t, now, out)
            t.sent_s = now - waited
        elif waited > c.move_timeout_s:
            self.counters["move_timeouts"] += 1
            log.warning("%s: target %s not reached in %.1f s; skipped", self.node_id, t.kind, waited)
            self._target = None
            if t.kind == "settle":
                self._finish(now, "failed")

    def _gimbal_fault(self, now: float) -> bool:
        g = self._gimbal
        faulty = g is not None and (bool(g.hardware_error) or g.status == "fault")
        if not faulty:
            if self._fault_since is not None:
                log.warning("%s: gimbal fault cleared; resuming", self.node_id)
                self._fault_since = None
                if self._target is not None and self._target.arrived_s is None:
                    self._target.resent = False
                    self._target.sent_s = now  # re-command below on the timeout path
                    self._queue.insert(0, self._target)
                    self._target = None
            return False
        if self._fault_since is None:
            self._fault_since = now
            self.counters["faults"] += 1
            log.error("%s: gimbal reports %s; commands stopped", self.node_id, ", ".join(g.hardware_error) or g.status)
        if now - self._fault_since > self.config.fault_timeout_s and not self.finished:
            self._finish(now, "failed")
        return True

    def _record_capture(self, target: _Target, frame: PosedFrame) -> None:
        img = torch.from_numpy(np.ascontiguousarray(frame.image)).permute(2, 0, 1)[None].float() / 255.0
        with torch.no_grad():
            score = float(self.teacher.score(img)[0])
        pan = frame.pan_rad if getattr(frame, "pan_rad", None) is not None else target.pan_rad
        tilt = frame.tilt_rad if getattr(frame, "tilt_rad", None) is not None else target.tilt_rad
        if self.mode == "rig" and self._gimbal is not None and pan is None:
            pan, tilt = self._gimbal.pan_rad, self._gimbal.tilt_rad
        cap = Capture(
            target.kind, frame.cam2world.copy(), score, frame.stamp_s, pan, tilt, target.predicted, frame.image
        )
        self.captures.append(cap)
        self.counters["captures"] += 1
        self.counters["frames_used"] += 1
        self.proposer.add_frame(frame, keep=True)
        log.info(
            "%s: captured (%s) score %.3f%s",
            self.node_id,
            target.kind,
            score,
            f" (predicted {target.predicted:.3f})" if target.predicted is not None else "",
        )

    # ---------------------------------------------------------------------------- passive
    def _passive(self, now: float, out: Outputs) -> None:
        f = self._frame
        if f is not None and (not self.captures or f.stamp_s > self.captures[-1].stamp_s):
            self.proposer.add_frame(f)
            self.counters["frames_used"] += 1
            self.captures.append(Capture("passive", f.cam2world.copy(), math.nan, f.stamp_s))
            del self.captures[:-1]  # passive mode keeps only the last pose seen
            self._dirty = True
        due = now - self._last_suggest >= self.config.min_suggest_period_s
        if self.platform is not None and self._dirty and (due or self._suggest_requested):
            self._dirty = False
            self._last_suggest = now
            try:
                proposal = self._propose(np.zeros((0, 4, 4)), self.config.top_k)
            except Exception:
                log.exception("%s: suggestion failed", self.node_id)
                return
            cands = [cd for cd in proposal.candidates if self._safe_candidate(cd)]
            out["planner/suggestion"].append(self._suggestion(cands[: self.config.top_k], proposal.field_version, now))
            self.state = "suggesting"

    def _propose(self, captured: np.ndarray, k: int, **kw):
        """The proposer's search, timed: its latency, and its CPU efficiency for the governor."""
        # the governor's count, learnt from here (threads: N pinned it; adapt_threads: false leaves it)
        with suggestion_threads(self.governor, self.cpu_clock, adapt=self.config.adapt_threads) as job:
            proposal = self.proposer.propose(self.platform, captured, k, **kw)
        self.latencies_s.append(job.wall_s)
        return proposal

    # ---------------------------------------------------------------------------- messages
    def _suggestion(self, candidates: list[Candidate], version: int, now: float, kind="search") -> ViewSuggestion:
        msg = ViewSuggestion(now, list(candidates), int(version), self._next("sugg"), "world", self.mode, kind)
        self.suggestions.append(msg)
        del self.suggestions[:-64]
        self.counters["suggestions"] += 1
        return msg

    def _next(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    def diagnostics(self, now: float) -> Diagnostics:
        lat = list(self.latencies_s)
        values = {
            "field_frames": float(self.proposer.size if self.proposer else 0),
            "field_version": float(self.proposer.version if self.proposer else 0),
            "latency_p50_s": percentile(lat, 50),
            "latency_p95_s": percentile(lat, 95),
            "threads": float(
                self.governor.threads if self.governor else self.config.threads or torch.get_num_threads()
            ),
        }
        if self.governor is not None and math.isfinite(self.governor.last_efficiency):
            values["cpu_efficiency"] = self.governor.last_efficiency
            values["thread_changes"] = float(self.governor.changes)
        scored = [cap for cap in self.captures if math.isfinite(cap.score)]
        if scored:
            values["initial_score"] = scored[0].score
            values["best_captured_score"] = max(cap.score for cap in scored)
        return Diagnostics(now, self.node_id, self.state, dict(self.counters), values, self._next("diag"))

    # ------------------------------------------------------------------------------ results
    def result(self) -> dict:
        """The loop's outcome: initial and best captured views (teacher scores of the real captures)."""
        scored = [cap for cap in self.captures if math.isfinite(cap.score)]
        if not scored:
            return {"state": self.state, "moves": self.moves}
        best = max(scored, key=lambda cap: cap.score)
        final = scored[-1] if scored[-1].kind == "settle" else best
        return {
            "state": self.state,
            "moves": self.moves,
            "captures": len(scored),
            "initial": scored[0],
            "best": best,
            "final": final,
        }

    def outcome(self) -> str | None:
        """One line for a person: how the loop ended (None before anything was captured)."""
        res = self.result()
        if res.get("best") is None:
            return None
        moves = res["moves"]
        return (
            f"{self.node_id}: {res['state']} after {moves} move{'' if moves == 1 else 's'}; "
            f"best captured score {res['best'].score:.3f}"
        )


def _platform_from_scene(config: PlannerConfig, scene) -> PlannerConfig:
    import dataclasses

    from aes_planner.node.sim_drone import _drone_box

    if scene.rig is not None and config.mode != "free":
        return dataclasses.replace(config, rig=scene.rig.pan_tilt)
    if config.mode == "rig":
        raise NodeError(f"scene {scene.name!r} has a drone, not a rig: use mode free")
    box = _drone_box(scene)
    return dataclasses.replace(config, drone=DroneBoxConfig(tuple(box.bounds_min_m), tuple(box.bounds_max_m)))
