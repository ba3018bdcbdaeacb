"""How the planner's active loop moves the camera: one adapter per platform.

* :class:`RigMotion` -- a pan-tilt rig: targets are joints, a command is ``gimbal/command``
  (checked by :meth:`RigPlatform.check <aes_planner.platform.RigPlatform.check>`: a target
  beyond the joint limits is refused and counted, never clamped -- the device applies the one
  clamp), arrival is the gimbal's own state, a hardware fault pauses the loop.
* :class:`DroneMotion` -- a drone that flies the top candidate of ``planner/suggestion``:
  targets are poses inside the box, arrival is a frame seen at the pose.

The loop (:mod:`aes_planner.node.active_loop`) asks the adapter and never the platform's kind.
The platform needs the camera's intrinsics, so an adapter is made from the config and bound to
its platform when the first frame arrives (:meth:`Motion.bind`).
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from typing import Protocol

import numpy as np
import torch

from aes_planner.geometry.poses import cam2world_to_view, direction_to_yaw_pitch, view_to_cam2world
from aes_planner.geometry.rig import JointCommandError, PanTiltConfig
from aes_planner.graph.base import Outputs
from aes_planner.messages import Candidate, GimbalCommand, GimbalState, MessageError, PosedFrame, ViewSuggestion
from aes_planner.node.captures import Capture, CaptureKind, Target
from aes_planner.platform import DroneBox, DronePlatform, Platform, RigPlatform
from aes_planner.search.space import lattice_places, space_for

log = logging.getLogger(__name__)

__all__ = ["DroneMotion", "Motion", "RigMotion", "Sender"]

#: How far along the way to the box's wall a drone's exploration positions go.
EXPLORE_REACH = 0.7
#: The lattice cells of the box a drone's exploration places are chosen among (DroneMotion.explore_places).
EXPLORE_LATTICE = 18
#: The yaw and pitch spacing (degrees) of the views a drone's place is scored at for its best turn
#: (``PlannerConfig.verify_turns``): 24 yaws x up to 10 pitches inside the searched range.
TURN_YAW_DEG = 15.0
TURN_PITCH_DEG = 10.0


class Sender(Protocol):
    """What a motion adapter may ask of the planner that sends its targets, and nothing more (the
    planner node implements it; an adapter never reaches into the node's own state)."""

    node_id: str

    def next_command_sequence(self) -> int:
        """The next ``gimbal/command`` sequence number (1 for the first)."""

    def waypoint(self, candidate: Candidate, now: float) -> ViewSuggestion:
        """A ``waypoint`` suggestion of ``candidate``, numbered and kept as the planner's own."""

    def count(self, name: str) -> None:
        """Add one to the planner's counter ``name``."""


class Motion(ABC):
    """The platform-specific half of the active loop."""

    #: ``PlannerConfig.spare_hills`` when the config leaves it unset (spare polish captures climb
    #: this many more hills)
    spare_hills: int = 0
    #: ``PlannerConfig.short_hills`` when the config leaves it unset (moves whose capture fell
    #: short get probe rounds before the climbs)
    short_hills: int = 0
    #: ``PlannerConfig.verify_apart_deg`` when the config leaves it unset (None: two coarsest
    #: polish steps, as between any two captures)
    verify_apart_deg: float | None = None
    #: ``PlannerConfig.flank_hills`` when the config leaves it unset (near-best captures beside
    #: the climbed hills get a round at half the coarsest step after the climbs)
    flank_hills: int = 0
    #: ``PlannerConfig.verify_unseen`` when the config leaves it unset
    verify_unseen: bool = False
    #: ``PlannerConfig.search_grid_points`` when the config leaves it unset
    search_grid_points: int = 0
    #: ``PlannerConfig.explore_places`` when the config leaves it unset
    explore_places: int = 0
    #: ``PlannerConfig.plan_grid_deg`` when the config leaves it unset (0: the preset's stage 1)
    plan_grid_deg: float = 0.0
    #: ``PlannerConfig.far_moves`` when the config leaves it unset (None: no limit)
    far_moves: int | None = None
    #: ``PlannerConfig.plan_draws`` when the config leaves it unset
    plan_draws: bool = True
    #: ``PlannerConfig.plan_adam_eps`` when the config leaves it unset (None: the preset's)
    plan_adam_eps: float | None = None
    #: ``PlannerConfig.hope_tie_margin`` when the config leaves it unset (0: quanta alone)
    hope_tie_margin: float = 0.0
    #: ``PlannerConfig.verify_turns`` when the config leaves it unset (0: none)
    verify_turns: int = 0
    #: ``PlannerConfig.residual_length_m`` when the config leaves it unset (None: the hope's
    #: residual kernel on the view direction alone)
    residual_length_m: float | None = None
    #: ``PlannerConfig.turns_one_by_one`` when the config leaves it unset
    turns_one_by_one: bool = False
    #: ``PlannerConfig.settle_tolerance_deg`` when the config leaves it unset (a drone's; a rig's
    #: arrival waits for the joints to stand still)
    settle_tolerance_deg: float = 180.0
    #: ``PlannerConfig.verify_places`` when the config leaves it unset (0: turns only from the
    #: places captured at)
    verify_places: int = 0
    #: ``PlannerConfig.flank_repeats`` when the config leaves it unset (0: one flanks' pass)
    flank_repeats: int = 0
    #: ``PlannerConfig.shortfall_length_deg`` when the config leaves it unset (0: off)
    shortfall_length_deg: float = 0.0
    #: ``PlannerConfig.survey_pitch_views`` when the config leaves it unset (0: the survey's
    #: turn alone)
    survey_pitch_views: int = 0
    #: ``PlannerConfig.spare_gap`` when the config leaves it unset (None: off)
    spare_gap: float | None = None

    #: ``ViewSuggestion.mode``'s word for the platform (the wire format's: ``rig`` or ``free``)
    suggestion_mode: str
    platform: Platform | None = None

    @abstractmethod
    def bind(self, intrinsics) -> Platform:
        """Make (once) and return the platform, with the camera's intrinsics."""

    def faulty(self, gimbal: GimbalState | None) -> bool:
        """Whether the device reports a hardware fault (the loop pauses)."""
        return False

    @abstractmethod
    def ready(self, frame: PosedFrame | None, gimbal: GimbalState | None) -> bool:
        """Whether the loop can take its first capture."""

    def here(self, kind: str, frame: PosedFrame, gimbal: GimbalState | None) -> Target:
        """A target at the view the camera shows now."""
        return Target(kind, frame.cam2world.copy())

    @abstractmethod
    def explore(self, n: int, frame: PosedFrame, captures: list[Capture]) -> list[Target]:
        """``n`` exploration targets."""

    def survey_pitch_ends(self, n: int, frame: PosedFrame) -> list[Target]:
        """``n`` more survey targets at the ends of the searched pitch range (a drone); none on a
        rig (its exploration already spans the tilt range)."""
        return []

    def holds(self, target: Target, frame: PosedFrame, config) -> bool:
        """Whether ``frame``, after the arrival, still shows ``target`` (a capture is taken of a
        frame that does); a rig's arrival already waited for the joints to stand still."""
        return True

    def explore_positions(self, n: int, captures: list[Capture]) -> list[Target]:
        """Captures away from the start after the exploration's turn (a drone); none on a rig."""
        return []

    def far_places(self, n: int, captures: list[Capture], queued_m=()) -> list[Target]:
        """Captures from places far from every capture and from the places ``queued_m`` (``[3]``
        each) still to be captured, after the exploration's positions (a drone); none on a rig."""
        return []

    def unvisited_places(self, captures: list[Capture], far_m: float) -> list[np.ndarray]:
        """Places (``[3]`` each) the platform can look from that no capture was taken within
        ``far_m`` of (a drone's: its box's lattice); none on a rig."""
        return []

    def turns(self, place_m: np.ndarray) -> np.ndarray:  # [3] -> [V, 4, 4]
        """The views from ``place_m`` turning only, spread over the platform's range (a drone's;
        none on a rig, whose one place its pan x tilt grid covers)."""
        return np.zeros((0, 4, 4))

    @abstractmethod
    def polish(self, cap: Capture, step_rad: float, step_m: float = 0.0) -> list[Target]:
        """The neighbours ``step_rad`` from a capture (and ``step_m`` for a platform that
        translates), inside the platform's range."""

    @abstractmethod
    def safe(self, cd: Candidate) -> bool:
        """Clamp a finite candidate into the platform's range (in place); False to drop it."""

    @abstractmethod
    def send(self, node: Sender, target: Target, now: float, out: Outputs) -> bool:
        """Command the move to ``target`` (stamped ``now``) through ``node`` (its :class:`Sender` side only); False when the command was refused."""

    @abstractmethod
    def arrived(self, target: Target, now: float, frame, gimbal, config) -> bool:
        """Whether the camera reached ``target`` (``config``: the planner's tolerances)."""

    def joints_now(self, gimbal: GimbalState | None) -> tuple[float | None, float | None]:
        """The joints to record with a capture that carries none."""
        return None, None


class RigMotion(Motion):
    suggestion_mode = "rig"
    spare_hills = 2  # PlannerConfig.spare_hills when unset: measured on dev rigs (docs/decisions.md)
    short_hills = 2  # PlannerConfig.short_hills when unset: measured on dev rigs
    verify_apart_deg = 15.0  # PlannerConfig.verify_apart_deg when unset: measured on dev rigs
    flank_hills = 6  # PlannerConfig.flank_hills when unset: measured on dev rigs
    verify_unseen = True  # PlannerConfig.verify_unseen when unset: measured on dev rigs
    plan_grid_deg = 4.0  # PlannerConfig.plan_grid_deg when unset: measured on dev rigs
    # PlannerConfig.flank_repeats when unset: 0, main's path. 1 lifted dev photo_ring_room 0.878 -> 0.990
    # and changed no other dev rig's score, but the scene's noise:1e-6 run stays 0.920 (another path
    # from move 1): its ship rule's spread condition failed (docs/benchmarks.md, session 28)
    flank_repeats = 0
    # PlannerConfig.shortfall_length_deg when unset: 0, main's path. 30 lifted dev photo_ring_room 0.878 -> 1.000
    # (noise 0.992, torch 0.992) but one move's miss on a narrow peak's flank pushed dev tabletop:236 off
    # its hill (1.000 -> 0.880): its ship rule failed (docs/benchmarks.md, session 29)
    shortfall_length_deg = 0.0
    # PlannerConfig.spare_gap when unset: a stop with moves left spends one on an unverified view within
    # 0.01 of the best capture; dev tabletop:269 0.880 -> 0.991 / 0.998 (base / noise:1e-6), the 55 dev
    # runs that stopped early none lower by more than 0.003 (docs/benchmarks.md, session 29, "Moves left")
    spare_gap = 0.01

    def __init__(self, rig: PanTiltConfig):
        self.rig = rig
        self.platform: RigPlatform | None = None

    def bind(self, intrinsics) -> RigPlatform:
        if self.platform is None:
            self.platform = RigPlatform(intrinsics, self.rig)
        return self.platform

    def faulty(self, gimbal):
        return gimbal is not None and (bool(gimbal.hardware_error) or gimbal.status == "fault")

    def ready(self, frame, gimbal):
        return frame is not None and gimbal is not None and not gimbal.moving

    def here(self, kind, frame, gimbal):
        if gimbal is None:
            return super().here(kind, frame, gimbal)
        kin = self.platform.kinematics
        return Target(kind, kin.forward(gimbal.pan_rad, gimbal.tilt_rad), gimbal.pan_rad, gimbal.tilt_rad)

    def explore(self, n, frame, captures):
        """A survey sweep over the joint range, starting at the end nearer the last capture (none: ``explore_views: 0``)."""
        if n == 0:
            return []
        kin = self.platform.kinematics
        joints = kin.sweep(n)  # [n, 2] left to right
        start = captures[-1].pan_rad if captures else 0.0
        if start is not None and abs(joints[-1, 0] - start) < abs(joints[0, 0] - start):
            joints = joints[::-1]
        return [Target(CaptureKind.EXPLORE, kin.forward(p, t), float(p), float(t)) for p, t in joints]

    def polish(self, cap, step_rad, step_m=0.0):
        """The four joint neighbours ``step_rad`` away that lie inside the limits (one beyond them
        is not a place the rig can look: left out, not clamped onto the limit)."""
        if cap.pan_rad is None or cap.tilt_rad is None:
            return []
        out = []
        for dp, dt in ((step_rad, 0.0), (-step_rad, 0.0), (0.0, step_rad), (0.0, -step_rad)):
            pan, tilt = cap.pan_rad + dp, cap.tilt_rad + dt
            if self.platform.kinematics.within_limits(pan, tilt):  # strictly: the neighbour is ours to pick
                out.append(Target(CaptureKind.POLISH, self.platform.kinematics.forward(pan, tilt), pan, tilt))
        return out

    def safe(self, cd):
        """A candidate whose joints pass :meth:`RigPlatform.check` (finite, inside the limits);
        its pose is made the joints' own. One beyond the limits is refused, not clamped."""
        if cd.pan_rad is None or cd.tilt_rad is None:
            return False
        try:
            self.platform.check(cd.pan_rad, cd.tilt_rad)
        except JointCommandError as exc:
            log.warning("candidate refused: %s", exc)
            return False
        cd.cam2world = self.platform.kinematics.forward(cd.pan_rad, cd.tilt_rad)
        return True

    def send(self, node: Sender, target, now, out):
        try:
            pan, tilt = self.platform.check(target.pan_rad, target.tilt_rad)
            cmd = GimbalCommand("move", pan, tilt, stamp_s=now, sequence=node.next_command_sequence())
        except (MessageError, ValueError) as exc:  # JointCommandError: NaN/Inf, beyond the limits
            log.warning("%s: refused to command %s: %s", node.node_id, target, exc)
            return False
        out["gimbal/command"].append(cmd)
        node.count("commands_sent")
        return True

    def arrived(self, target, now, frame, gimbal, config):
        if gimbal is None or gimbal.stamp_s <= target.sent_s:
            return False
        # a goal other than ours: the device clamped it (narrower limits), or this state
        # predates our command; accept it only once the device had time to see the command
        any_goal = now - target.sent_s > 2.0 and gimbal.stamp_s > target.sent_s + 1.0
        tol = math.radians(config.arrival_tolerance_deg)
        return self.platform.arrived(gimbal, target.pan_rad, target.tilt_rad, tol, any_goal=any_goal)

    def joints_now(self, gimbal):
        return (gimbal.pan_rad, gimbal.tilt_rad) if gimbal is not None else (None, None)


class DroneMotion(Motion):
    suggestion_mode = "free"
    # PlannerConfig.spare_hills / flank_hills when unset: after the climbs, the captures they left climb up to
    # 2 more hills, and up to 6 near-best captures no climb stood on get a round and their probes a climb, with
    # the settle held within settle_tolerance_deg (docs/decisions.md; dev drones, 39 paired runs: mean 0.9423 ->
    # 0.9436, below 0.9 7 -> 6, none lower, spread per scene 0.0194 -> 0.0177)
    spare_hills = 2
    flank_hills = 6
    short_hills = 0  # not measured on drones yet
    verify_unseen = False  # nor this
    # PlannerConfig.search_grid_points when unset: 9 places of the box x 24 views (docs/decisions.md);
    # dev drones, 21 paired runs: mean 0.922 -> 0.937, below 0.9 5 -> 4 (432: 0.933, 6 below)
    search_grid_points = 216
    plan_grid_deg = 0.0  # no pan x tilt grid: a drone's grid is search_grid_points' lattice of places
    # PlannerConfig.far_moves / plan_draws when unset: one unvisited view that misses, then only views
    # near a capture; no random draws in the loop's searches (docs/decisions.md; dev drones, 39 paired
    # runs: mean 0.917 -> 0.924, below 0.9 12 -> 11, spread per scene 0.052 -> 0.013)
    far_moves = 1
    plan_draws = False
    # PlannerConfig.verify_turns when unset: the field's best turn from up to 6 captured places before the
    # climbs (docs/decisions.md; dev drones, 39 paired runs: mean 0.924 -> 0.934, below 0.9 11 -> 7,
    # spread per scene 0.013 -> 0.010; 3: 0.932, 7 below, spread 0.013)
    verify_turns = 6
    # PlannerConfig.turns_one_by_one when unset: each turn verification chosen by a hope calibrated on the
    # turns verified before it (docs/decisions.md; dev drones, 39 paired runs with torch: mean 0.934 -> 0.942,
    # below 0.9 9 -> 7, spread per scene 0.037 -> 0.019)
    turns_one_by_one = True
    # PlannerConfig.settle_tolerance_deg when unset: the settle's capture waits until the drone holds
    # the best captured view this closely (the arrival tolerance is 2 deg; composition peaks can be
    # 1 deg wide: dev gallery:203@drone noise, a settle 1.8 deg off its target, 0.907 -> 0.824)
    settle_tolerance_deg = 0.3
    # PlannerConfig.survey_pitch_views when unset: 0, the turn alone (-10 / +5 deg). 6 lifted the 10 s29 dev
    # drones (30 cells: 0.937 -> 0.972, below 0.9 7 -> 0) but moved dev tabletop:212 0.989 -> 0.826 and
    # tabletop:207 1.000 -> 0.910 (base): its ship rule failed, as did 2's (docs/benchmarks.md, session 29)
    survey_pitch_views = 0

    def __init__(self, box: DroneBox, search_config):
        self.box = box
        self.search_config = search_config  # the proposer's: its pitch range bounds the polish
        self.platform: DronePlatform | None = None
        self.space = None

    def bind(self, intrinsics) -> DronePlatform:
        if self.platform is None:
            self.platform = DronePlatform(intrinsics, self.box)
            self.space = space_for(self.platform, self.search_config)
        return self.platform

    def ready(self, frame, gimbal):
        return frame is not None

    def _pose(self, x, y, z, yaw, pitch) -> np.ndarray:  # -> [4, 4], position in the box
        x, y, z = self.box.clamp([x, y, z])
        return view_to_cam2world(torch.tensor([x, y, z, yaw, pitch], dtype=torch.float64)).numpy()

    def explore(self, n, frame, captures):
        """Turn in place at the start position: yaw spread around the circle, pitched alternately
        10 deg down and 5 deg up."""
        x, y, z, yaw0, _ = cam2world_to_view(frame.cam2world)
        targets = []
        for i in range(1, n + 1):
            yaw = yaw0 + 2 * math.pi * i / (n + 1)
            pitch = math.radians(-10.0) if i % 2 else math.radians(5.0)
            targets.append(
                Target(CaptureKind.EXPLORE, self._pose(x, y, z, math.atan2(math.sin(yaw), math.cos(yaw)), pitch))
            )
        return targets

    def survey_pitch_ends(self, n, frame):
        """``n`` more turns in place at the start position, at the ends of the searched pitch
        range (``search_config.pitch_limits_deg``, as the search space holds them), alternately the
        lower and the upper end, their yaws spread around the circle from the start's (the first
        looks the start's way, down): the turn's -10 / +5 deg leave a band no capture looked at, and
        the field rates what it never saw as poor (dev s29_ground_drone: every good view looks 60
        deg down, the field built from the survey scores the start's best one 0.16, truth 0.84)."""
        if n <= 0:
            return []
        x, y, z, yaw0, _ = (float(v) for v in cam2world_to_view(frame.cam2world))
        lo_p, hi_p = float(self.space.lower[4]), float(self.space.upper[4])
        targets = []
        for i in range(n):
            yaw = yaw0 + 2 * math.pi * i / n
            pitch = lo_p if i % 2 == 0 else hi_p
            targets.append(
                Target(CaptureKind.EXPLORE, self._pose(x, y, z, math.atan2(math.sin(yaw), math.cos(yaw)), pitch))
            )
        return targets

    def explore_positions(self, n, captures):
        """``n`` positions spread across the box around the start (to its sides, ahead and
        behind, along the best capture's view; each ``EXPLORE_REACH`` of the way to the box's
        wall, at the start's height), each looking at what the best capture looks at (the point
        its depth puts in the middle of its view; without depth: the way it looks)."""
        if n <= 0 or not captures:
            return []
        start = captures[0].cam2world[:3, 3]
        best = max(captures, key=lambda cap: cap.score)  # stable: the earliest on a tie
        yaw = float(cam2world_to_view(best.cam2world)[3])
        fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        side = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        lo, hi = np.asarray(self.box.bounds_min_m), np.asarray(self.box.bounds_max_m)
        targets = []
        look = self._looker(captures)
        for i in range(n):
            a = 2 * math.pi * i / n  # left, ahead, right, behind for n = 4 ...
            d = math.cos(a) * side + math.sin(a) * fwd  # [3], unit, horizontal
            # how far the box lets the drone go from the start along d
            with np.errstate(divide="ignore", invalid="ignore"):
                room = np.where(d > 1e-9, (hi - start) / d, np.where(d < -1e-9, (lo - start) / d, np.inf))
            reach = EXPLORE_REACH * float(np.min(room))
            if not math.isfinite(reach) or reach <= 0.0:
                continue
            targets.append(Target(CaptureKind.EXPLORE, look(self.box.clamp(start + reach * d))))
        return targets

    def _looker(self, captures):
        """``place [3] -> cam2world [4, 4]``: a view from ``place`` of what the best capture looks at
        (the point its depth puts in the middle of its view; without depth, or from that very
        point: the way it looks), its pitch inside the searched range."""
        best = max(captures, key=lambda cap: cap.score)  # stable: the earliest on a tie
        _, _, _, yaw, pitch = (float(v) for v in cam2world_to_view(best.cam2world))
        aim = None  # [3], what the best capture looks at
        if best.look_m is not None and math.isfinite(best.look_m) and best.look_m > 0:
            aim = best.cam2world[:3, 3] + best.look_m * best.cam2world[:3, 2]
        lo_p, hi_p = float(self.space.lower[4]), float(self.space.upper[4])

        def look(p: np.ndarray) -> np.ndarray:
            if aim is None or np.linalg.norm(aim - p) <= 1e-3:
                return self._pose(*p, yaw, pitch)
            y_, p_ = direction_to_yaw_pitch(torch.as_tensor(aim - p))
            return self._pose(*p, float(y_), min(max(float(p_), lo_p), hi_p))

        return look

    def far_places(self, n, captures, queued_m=()):
        """``n`` captures from the places of a lattice of the box (:func:`lattice_places`, height
        included: 18 cells of a 1.6 x 1.6 x 0.6 m box, 3 x 3 x 2) farthest from every capture so
        far and from each other (chosen one by one; ties: the lattice's order), each looking at
        what the best capture looks at; their captures feed the field but stay off the search's
        input trajectory (``Target.on_path``): the search's grid proposes views from these places
        (:meth:`FreeSpace.grid <aes_planner.search.space.FreeSpace.grid>`), and stage 1's samples
        stay where they were (docs/benchmarks.md, "Where the drone's search can look": two far
        captures on the path spread those samples over the box and lost tabletop:202's view)."""
        if n <= 0 or not captures:
            return []
        places = lattice_places(self.box.bounds_min_m, self.box.bounds_max_m, EXPLORE_LATTICE)  # [P, 3]
        seen = [cap.cam2world[:3, 3] for cap in captures] + [np.asarray(q, dtype=np.float64) for q in queued_m]
        look = self._looker(captures)
        targets = []
        for _ in range(min(n, len(places))):
            gap = np.min(np.linalg.norm(places[:, None, :] - np.asarray(seen)[None], axis=-1), axis=1)  # [P]
            i = int(np.argmax(np.round(gap, 6)))  # rounded: a tie is the lattice's order, not the last bits
            seen.append(places[i])
            targets.append(Target(CaptureKind.EXPLORE, look(places[i]), on_path=False))
        return targets

    def unvisited_places(self, captures, far_m):
        """The places of a lattice of the box (:func:`lattice_places`, ``EXPLORE_LATTICE`` cells,
        height included) that no capture lies within ``far_m`` of, in the lattice's order."""
        places = lattice_places(self.box.bounds_min_m, self.box.bounds_max_m, EXPLORE_LATTICE)  # [P, 3]
        seen = np.asarray([cap.cam2world[:3, 3] for cap in captures], dtype=np.float64).reshape(-1, 3)  # [M, 3]
        if not len(seen):
            return list(places)
        gap = np.min(np.linalg.norm(places[:, None, :] - seen[None], axis=-1), axis=1)  # [P]
        return [p for p, g in zip(places, gap) if g > far_m]

    def turns(self, place_m):
        """Views from ``place_m`` (inside the box): every ``TURN_YAW_DEG`` of yaw x every
        ``TURN_PITCH_DEG`` of pitch inside the searched range (from its lowest), yaw fastest."""
        lo, hi = float(self.space.lower[4]), float(self.space.upper[4])
        step = math.radians(TURN_PITCH_DEG)
        pitches = lo + step * np.arange(int(math.floor((hi - lo) / step + 1e-9)) + 1)  # [P]
        yaws = np.radians(np.arange(-180.0, 180.0, TURN_YAW_DEG))  # [Y]
        x, y, z = (float(v) for v in self.box.clamp(np.asarray(place_m, dtype=np.float64)))
        views = torch.tensor([[x, y, z, yw, pt] for pt in pitches for yw in yaws], dtype=torch.float64)  # [P*Y, 5]
        return view_to_cam2world(views).numpy()

    def polish(self, cap, step_rad, step_m=0.0):
        """Yaw and pitch ``step_rad`` away, the position kept, the pitch inside the searched range;
        with ``step_m`` > 0 also ``step_m`` to either side and forward and back (inside the box)."""
        lo, hi = float(self.space.lower[4]), float(self.space.upper[4])
        x, y, z, yaw, pitch = (float(v) for v in cam2world_to_view(cap.cam2world))
        offsets = ((step_rad, 0.0), (-step_rad, 0.0), (0.0, step_rad), (0.0, -step_rad))
        out = [
            Target(CaptureKind.POLISH, self._pose(x, y, z, yaw + dy, min(max(pitch + dp, lo), hi)))
            for dy, dp in offsets
        ]
        if step_m > 0.0:
            fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0]) * step_m
            side = np.array([-math.sin(yaw), math.cos(yaw), 0.0]) * step_m
            here = np.array([x, y, z])
            for d in (side, -side, fwd, -fwd):
                p = here + d
                if self.box.contains(p):  # one beyond the wall is left out, not clamped onto it
                    out.append(Target(CaptureKind.POLISH, self._pose(*p, yaw, pitch)))
        return out

    def safe(self, cd):
        cd.cam2world = self.platform.clamp(cd.cam2world)
        return True

    def send(self, node: Sender, target, now, out):
        cand = Candidate(target.cam2world, target.predicted if target.predicted is not None else 0.0)
        out["planner/suggestion"].append(node.waypoint(cand, now))
        return True

    def holds(self, target, frame, config):
        """The frame's pose within the arrival tolerances of the target: a drone's arrival is
        one frame within them, and a frame ``settle_s`` later can show it elsewhere (still
        turning: up to ~6 deg on at 120 deg/s), so arriving is not holding. The settle's view
        within ``settle_tolerance_deg`` (unset: ``settle_tolerance_deg`` here) when that is
        tighter: the final view is the best capture's, and a peak can be narrower than the
        arrival tolerance."""
        tol_deg = config.arrival_tolerance_deg
        if target.kind == "settle":
            settle = self.settle_tolerance_deg if config.settle_tolerance_deg is None else config.settle_tolerance_deg
            tol_deg = min(tol_deg, settle)
        return self.platform.arrived(frame.cam2world, target.cam2world, tol_deg, config.arrival_tolerance_m)

    def arrived(self, target, now, frame, gimbal, config):
        if frame is None or frame.stamp_s <= target.sent_s:
            return False
        return self.platform.arrived(
            frame.cam2world, target.cam2world, config.arrival_tolerance_deg, config.arrival_tolerance_m
        )
