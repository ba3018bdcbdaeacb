"""``PlannerNode``: keeps the aesthetic field up to date from ``camera/frame``, suggests views, and
on a rig (or a drone that flies its suggestions) runs the **active loop**.

This file holds the node's input gating (stamps ahead of the clock, frames out of order or of
another size, the newest of a batch), passive mode, diagnostics and threads. The active loop --
its states and its one transition function -- is :mod:`aes_planner.node.active_loop`; what
differs between a rig and a drone is its motion adapter (:mod:`aes_planner.node.motion`); the
knobs are :class:`~aes_planner.node.planner_config.PlannerConfig`; captures and targets are
:mod:`aes_planner.node.captures`. ``step(inputs, now)`` takes time only from ``now`` (it times the
search for the latency figures and the thread governor, nothing else).

Passive mode (``active: false``): integrate the newest frame of each step (older ones of the same
batch are dropped and counted), publish ``planner/suggestion`` when the field changed (at most
every ``min_suggest_period_s``) or on ``planner/request``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Mapping

import numpy as np
import torch

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.plausible import distance_problem
from aes_planner.graph.base import LaunchContext, Node, NodeError, Outputs
from aes_planner.images import downscale_frame
from aes_planner.messages import (
    Candidate,
    Diagnostics,
    GimbalCommand,
    GimbalState,
    PlannerRequest,
    PosedFrame,
    ViewSuggestion,
)
from aes_planner.node.active_loop import ActiveLoop, LoopState
from aes_planner.node.captures import Capture, Target
from aes_planner.node.motion import DroneMotion, Motion, RigMotion
from aes_planner.node.planner_config import PlannerConfig
from aes_planner.node.proposer import FieldProposer, Proposer
from aes_planner.node.scene import launch_scene
from aes_planner.platform import DronePlatform, DronePlatformConfig, Platform, RigPlatform, RigPlatformConfig
from aes_planner.runtime import ThreadGovernor, set_threads, suggestion_threads

log = logging.getLogger(__name__)

__all__ = ["Capture", "PlannerConfig", "PlannerNode"]


class PlannerNode(ActiveLoop, Node):
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
            config = _platform_from_scene(config, launch_scene(context))
        super().__init__(config, node_id, context)
        c = self.config
        self.motion: Motion | None = _motion(c)
        self.kind = RigPlatform.kind if c.rig is not None else DronePlatform.kind
        self._teacher = teacher
        self.proposer = proposer
        self.state = LoopState.WAITING
        self.platform: Platform | None = None  # made by the motion adapter at the first frame
        self.captures: list[Capture] = []
        self.suggestions: list[ViewSuggestion] = []  # every suggestion published (bounded)
        self.moves = 0
        self.explored = 0  # moves spent on the search's exploratory candidate
        self.far_misses = 0  # moves to unvisited places that did not beat the best capture (far_moves)
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
                "framing_rejected",
                "framing_failed",
            ),
            0,
        )
        self.latencies_s: deque[float] = deque(maxlen=256)
        self._threads_set_in: int | None = None  # ident of the thread whose numba count was set
        self.governor: ThreadGovernor | None = None  # threads 0 + adapt_threads: made on the first step
        self.cpu_clock = time.process_time  # CPU seconds of the whole process (tests replace it)
        self.wall_clock = time.perf_counter  # a search's wall seconds (tests replace it)
        self._intrinsics = None
        self._kernels_warm = False  # the rasterizer's kernels compiled or loaded (start())
        self._ahead_seen = 0  # messages rejected for stamps ahead of the clock
        self._frame: PosedFrame | None = None  # newest accepted frame
        self._gimbal: GimbalState | None = None  # newest gimbal state
        self._queue: list[Target] = []
        self._positions_explored = False  # a drone's exploration positions queued (after the turn)
        self._target: Target | None = None
        self._polish_left = 0
        self._polish_scale = 0
        self._polish_previous: Capture | None = None
        self._climbs: list[Capture] | None = []  # None: chosen after the hills' verifications
        self._stood_on: list[Capture] = []  # every centre a climb stood on (spare hills lie away from them)
        self._spares = 0  # spare hills climbed (PlannerConfig.spare_hills)
        self._flank_probe: tuple[list[Capture], int] | None = (
            None  # (flank captures, first probe): PlannerConfig.flank_hills
        )
        self._flank_done = False
        self._flank_climb = False
        self._climb_budget = 0
        self._probed: tuple[list[Capture], int, int] | None = None  # (hills, first probe, not short): to rank
        self._climb_left = 0
        self._fine_left = 0  # captures left for the rounds half the finest polish step (after the climbs)
        self._fine_centres: list[Capture] = []  # every view those rounds were around
        self._round_from: int | None = None
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
        return self.state in (LoopState.DONE, LoopState.FAILED)

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
        if isinstance(self.proposer, FieldProposer):
            settings = {}
            if self.config.search_steps is not None:  # every search of the node, passive ones too
                settings["steps"] = self.config.search_steps
            if self.motion is not None and self.config.active:  # the active loop's (passive: not measured)
                grid = self.config.search_grid_points
                grid = self.motion.search_grid_points if grid is None else grid
                if grid > 0:  # 0: the preset's
                    settings["grid_points"] = grid
            self.proposer.search_settings = settings
        _ = self.teacher
        if isinstance(self.proposer, FieldProposer) and not self._kernels_warm:  # now, not in the first plan
            from aes_planner.gaussians.warmup import warm_kernels

            warm_kernels()
            warm = getattr(self.teacher, "warm", None)  # Teacher.warm: e.g. the composition head's kernel
            if callable(warm):
                warm()
            self._kernels_warm = True

    # ----------------------------------------------------------------------------------- step
    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        out: Outputs = {"gimbal/command": [], "planner/suggestion": [], "planner/diagnostics": []}
        if self.proposer is None:
            self.start()
        if self.config.threads and self._threads_set_in != threading.get_ident():
            set_threads(self.config.threads)  # numba's count is per thread: set where the steps run
            self._threads_set_in = threading.get_ident()
        elif not self.config.threads and self._adapt_threads and self.governor is None:
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
            self._on_request(req, now)

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
        if self.motion is not None:
            return self.motion.bind(intrinsics)
        raise NodeError(
            f"{self.node_id}: no platform: give the planner platform: {{type: rig, <the rig's keys>}} or "
            "platform: {type: drone, box: {...}}, or a 'scene' in the launch file"
        )

    def _on_request(self, req, now: float) -> None:
        kind = getattr(req, "kind", "suggest")
        if getattr(req, "set_framing", False) and not self._set_framing(req):
            return  # refused: counted, the framing in force stays
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
            self.explored = 0
            self.far_misses = 0
            self.state = LoopState.WAITING
        elif kind == "stop" and self.config.active and not self.finished:
            self._queue.clear()
            self._target = None
            self._begin_settle(now)

    def _set_framing(self, req) -> bool:
        """Apply a request's keep/avoid regions to the next searches (both empty: none); False, counted
        and logged, when a region names no held frame or lies outside its image."""
        from aes_planner.search.framing import FramingConfig, Region

        try:
            keep = [Region(r.frame, r.x0, r.y0, r.x1, r.y1) for r in req.keep]
            avoid = [Region(r.frame, r.x0, r.y0, r.x1, r.y1) for r in req.avoid]
            fc = FramingConfig(margin_frac=req.keep_margin, photo_rank=self.config.photo_rank)
            self.proposer.set_framing(keep, avoid, fc)
        except AesPlannerError as exc:
            self.counters["framing_rejected"] += 1
            log.warning("%s: framing request refused: %s", self.node_id, exc)
            return False
        self._dirty = True  # the next search applies it
        regions = [f"keep {r.text()}" for r in keep] + [f"avoid {r.text()}" for r in avoid]
        log.info("%s: framing %s", self.node_id, ", ".join(regions) or "off")
        return True

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
            out["planner/suggestion"].append(
                self._suggestion(cands[: self.config.top_k], proposal.field_version, now, proposal=proposal)
            )
            self.state = LoopState.SUGGESTING

    @property
    def _adapt_threads(self) -> bool:
        """Whether the thread count follows measured CPU efficiency: not on a simulated clock,
        where nothing may depend on how busy the machine is (the count could change the numerics)."""
        return self.config.adapt_threads and self.context.clock != "sim"

    def _propose(self, captured: np.ndarray, k: int, **kw):
        """The proposer's search, timed: its latency, and its CPU efficiency for the governor."""
        # the governor's count, learnt from here (threads: N pinned it; adapt_threads: false leaves it)
        from aes_planner.search.framing import FramingError

        try:
            with suggestion_threads(
                self.governor, self.cpu_clock, adapt=self._adapt_threads, wall_clock=self.wall_clock
            ) as job:
                proposal = self.proposer.propose(self.platform, captured, k, **kw)
        except FramingError:  # e.g. no reachable view holds the kept subject: counted, the caller goes on
            self.counters["framing_failed"] += 1
            raise
        self.latencies_s.append(job.wall_s)
        if proposal.explore is not None and not self._safe_candidate(proposal.explore):
            proposal.explore = None  # checked once, as the candidates are: refused (counted), never sent
        return proposal

    # ---------------------------------------------------------------------------- messages
    def _suggestion(
        self, candidates: list[Candidate], version: int, now: float, kind="search", proposal=None
    ) -> ViewSuggestion:
        """``proposal``: the search's :class:`~aes_planner.node.proposer.Proposal` (from
        :meth:`_propose`, its exploratory candidate checked), whose coverage and exploratory
        candidate the message carries too."""
        mode = self.motion.suggestion_mode
        covered = None if proposal is None else proposal.covered_fraction
        explore = None if proposal is None else proposal.explore
        msg = ViewSuggestion(
            now, list(candidates), int(version), self._next("sugg"), "world", mode, kind, covered, explore
        )
        self.suggestions.append(msg)
        del self.suggestions[:-64]
        self.counters["suggestions"] += 1
        return msg

    # -- what a motion adapter may ask (aes_planner.node.motion.Sender) ------------------------
    def next_command_sequence(self) -> int:
        return self._next("cmd")

    def waypoint(self, candidate: Candidate, now: float) -> ViewSuggestion:
        version = self.proposer.version if self.proposer else 0
        return self._suggestion([candidate], version, now, "waypoint")

    def count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    def _next(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    def diagnostics(self, now: float) -> Diagnostics:
        lat = list(self.latencies_s)
        values = {
            "field_frames": float(self.proposer.size if self.proposer else 0),
            "field_version": float(self.proposer.version if self.proposer else 0),
            "latency_p50_s": (float(np.percentile(lat, 50)) if len(lat) else 0.0),
            "latency_p95_s": (float(np.percentile(lat, 95)) if len(lat) else 0.0),
            "threads": float(
                self.governor.threads if self.governor else self.config.threads or torch.get_num_threads()
            ),
        }
        if self.governor is not None and math.isfinite(self.governor.last_efficiency):
            values["cpu_efficiency"] = self.governor.last_efficiency
            values["thread_changes"] = float(self.governor.changes)
        framing = getattr(self.proposer, "framing", None)
        if framing is not None:  # which regions are active, and how much of each kept subject the last view held
            keep, avoid = framing[0], framing[1]
            held = getattr(self.proposer, "framing_held", [])
            for i, r in enumerate(keep):
                values[diag_name(f"framing.keep.{r.text()}")] = held[i] if i < len(held) else -1.0
            for r in avoid:
                values[diag_name(f"framing.avoid.{r.text()}")] = 1.0
            for i, (kind, sub) in enumerate(getattr(self.proposer, "framing_boxes", [])[:8]):
                values.update(box_values(f"framing.box{i}.{kind}", sub))  # drawn by the Foxglove view
        scored = [cap for cap in self.captures if math.isfinite(cap.score)]
        if scored:
            values["initial_score"] = scored[0].score
            values["best_captured_score"] = self.reported_best(scored).score  # under a framing: one that holds it
        return Diagnostics(now, self.node_id, self.state.value, dict(self.counters), values, self._next("diag"))

    # ------------------------------------------------------------------------------ results
    def result(self) -> dict:
        """The loop's outcome: initial and best captured views (teacher scores of the real captures)."""
        scored = [cap for cap in self.captures if math.isfinite(cap.score)]
        if not scored:
            return {"state": self.state.value, "moves": self.moves}
        best = self.reported_best(scored)  # under a framing: the best that holds the kept subjects
        final = scored[-1] if scored[-1].kind == "settle" else best
        return {
            "state": self.state.value,
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


def box_values(prefix: str, subject) -> dict[str, float]:
    """A lifted subject's 3D box as diagnostics values ``<prefix>.cx/cy/cz`` (centre, m),
    ``.sx/sy/sz`` (size along its axes, m) and ``.yaw_rad`` (its first axis from world x, about z):
    what :func:`aes_planner.transport.foxglove_view.framing_boxes` reads back."""
    c, size, ax = subject.centre_m, subject.size_m, subject.axes[0]
    out = {"cx": c[0], "cy": c[1], "cz": c[2], "sx": size[0], "sy": size[1], "sz": size[2]}
    out["yaw_rad"] = math.atan2(ax[1], ax[0])
    return {f"{prefix}.{k}": float(v) for k, v in out.items()}


def diag_name(text: str) -> str:
    """``text`` as a diagnostics name (1-64 chars of ``[A-Za-z0-9_.:/-]``; others become ``_``)."""
    import re

    return re.sub(r"[^A-Za-z0-9_.:/-]", "_", text)[:64] or "_"


def _motion(config: PlannerConfig) -> Motion | None:
    """The motion adapter of the configured platform (None: none configured yet)."""
    if config.rig is not None:
        return RigMotion(config.rig)
    if config.drone is not None:
        from aes_planner.search import SearchConfig

        return DroneMotion(config.drone, SearchConfig.preset(config.preset, mode=DronePlatform.kind))
    return None


def _platform_from_scene(config: PlannerConfig, scene) -> PlannerConfig:
    """The platform the config leaves to the scene: ``{type: rig}`` (or none, on a rig scene) the
    scene's rig; ``{type: drone}`` (or none, on a drone scene) the scene's box, or the box around a
    rig scene's base."""
    kind = config.platform.kind if config.platform is not None else None
    if scene.rig is not None and kind != DronePlatform.kind:
        return dataclasses.replace(config, platform=RigPlatformConfig(scene.rig.pan_tilt))
    if kind == RigPlatform.kind:
        raise NodeError(
            f"planner.platform: scene {scene.name!r} has a drone, not a rig: "
            "write platform: {type: drone}, or give the rig's keys"
        )
    from aes_planner.sim.source import platform_of

    return dataclasses.replace(config, platform=DronePlatformConfig(platform_of(scene).free_box()))
