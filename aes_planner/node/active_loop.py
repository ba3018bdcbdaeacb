"""The planner's active loop: its states (:class:`LoopState`) and its one transition function,
:meth:`ActiveLoop._advance`, read top to bottom::

    waiting    until the camera (and on a rig the gimbal, standing still) reports
    initial    capture the view the camera starts at (it is the baseline)
    exploring  visit a few poses spread over the joint range (rig) or around the start (drone),
               capturing each
    planning   build the scorer from every capture, search, and pick the best candidate that the
               same scorer expects to beat the best captured view by ``margin``; none, while the
               search's inputs cover too little of the space: its exploratory candidate
               (``explore_below_covered``, ``explore_moves``); none of those with moves left: the
               best candidate within ``spare_gap`` of the best captured score that no capture looks
               within ``spare_apart_deg`` of (a prediction never verified is not stopped on); else
               (or ``max_moves`` spent) -> polishing
    moving     command it (``gimbal/command``; a drone flies the top candidate of
               ``planner/suggestion``), wait for arrival (``gimbal/state``, or frames at the pose),
               capture there and score the real capture with the teacher (it verifies the
               prediction and feeds the field) -> planning
    polishing  first one capture of the search's best predicted view on each of up to
               ``verify_hills`` hills no capture lies on (ranked by hope) and, on a drone, of the
               field's best turn from each of up to ``verify_turns`` places captured at, then
               a coarse-to-fine compass search with real captures around the best captured view,
               then around up to ``polish_starts - 1`` other captured hills nearly as good (more
               of them than climbs, up to ``polish_hills``: one coarsest round on each first, and
               the climbs go to the hills whose rounds found the most; a rig's moves that are
               none of those hills, a 10-deg and a 5-deg round each, on top of the budget, and
               such a hill joins the choice when a round comes near the best: ``short_hills``):
               its four neighbours ``polish_step_deg * 2**k`` away (pan/tilt; a drone: yaw/pitch;
               k from ``polish_scales - 1`` down to 0), moving to a better one, halving the step
               when none is better, up to ``polish_captures`` (composition peaks are a few degrees
               wide, narrower than the field sees: docs/journal/benchmarks.md, "The rasterizer in
               place"; the field finds the hill, real captures climb it); after the climbs, where
               half the finest step exceeds the arrival tolerance (a rig), rounds at that half
               step around the best view (``polish_fine_captures``)
    settling   go back to the best captured view, capture it once more -> done
    done / failed   the end (failed: a camera gone silent, a fault that outlasted
               ``fault_timeout_s``, or a settle target not reached; the captures are kept)

Decisions do not hinge on rounding: candidates are ranked by their hope rounded to
``hope_quantum`` and then by where they look (:func:`~aes_planner.node.captures.decision_order`),
and a capture displaces the best one only by more than ``tie_tolerance``; what the field predicts
is only trusted after a real capture verified it (moves and polish are scored on the real image).

A capture is the first frame stamped at least ``settle_s`` after arrival. A gimbal that reports a
hardware fault pauses the loop in its state (counter ``faults``) until the fault clears (a reboot
request to the gimbal node). Time comes only from the step's ``now``: a command leaves in the step
after the planning that chose it, stamped with that step's clock.

What differs between a rig and a drone is asked of the motion adapter (:mod:`.motion`).
:class:`ActiveLoop` is the active half of :class:`~aes_planner.node.planner.PlannerNode`.
"""

from __future__ import annotations

import enum
import logging
import math

import numpy as np
import torch

from aes_planner.graph.base import Outputs
from aes_planner.messages import Candidate, PosedFrame
from aes_planner.node.captures import (
    Capture,
    CaptureKind,
    Target,
    decision_order,
    hopes,
    look_distance_m,
    near_captured,
    shortfall,
)
from aes_planner.platform import view_angle_deg

log = logging.getLogger(__name__)

#: The most grid points a loop's search takes (``SearchConfig.grid_points``' limit)
MAX_GRID_POINTS = 10_000
#: With ``plan_grid_deg``, stage 2 refines this many distinct stage-1 views (the preset's loop
#: search: 4): a grid puts two of them on one broad hill, which refine onto one view, and a hill
#: nearly as good was left out (dev outdoor:201's first planning: pan 88 tilt 13, 0.78 predicted,
#: listed from 6 on)
PLAN_GRID_HILLS = 8
#: After the climbs, this many probes of the flanks' rounds (``PlannerConfig.flank_hills``) that
#: beat their flank capture are climbed, best first: the best probe can be on another spike than
#: the oracle's (dev gallery:243: candidate 1 climbed one probe, 0.763 at pan -29, and ended at
#: 0.890 of the oracle; with two, 0.748 at pan -14 climbed to 0.783, 0.932)
FLANK_CLIMBS = 2

#: A move's or a hill verification's miss below its hope that ``shortfall_length_deg`` counts is
#: what lies beyond this (teacher units): the hopes are optimistic by design (``optimism`` times the
#: residuals' spread), and the median dev rig move fell 0.09 short of its hope (session 28's runs)
SHORTFALL_SLACK = 0.1

__all__ = ["ActiveLoop", "LoopState"]


def _where(cd: Candidate) -> str:
    """Where a candidate looks, for the log: pan/tilt in degrees on a rig, else its position."""
    if cd.pan_rad is not None and cd.tilt_rad is not None:
        return f"pan {math.degrees(cd.pan_rad):.1f} tilt {math.degrees(cd.tilt_rad):.1f} deg"
    return "at " + " ".join(f"{v:.2f}" for v in cd.cam2world[:3, 3]) + " m"


class LoopState(str, enum.Enum):
    """The planner's state word (``planner/diagnostics``' ``state``); ``suggesting`` is passive mode's."""

    WAITING = "waiting"
    INITIAL = "initial"
    EXPLORING = "exploring"
    PLANNING = "planning"
    MOVING = "moving"
    POLISHING = "polishing"
    SETTLING = "settling"
    DONE = "done"
    FAILED = "failed"
    SUGGESTING = "suggesting"

    def __str__(self) -> str:
        return self.value

    __format__ = str.__format__


class ActiveLoop:
    """The active loop's transition function and its helpers (a mixin of ``PlannerNode``)."""

    # ---------------------------------------------------------------- the transition function
    def _advance(self, now: float, out: Outputs) -> None:
        if self.motion is None or self._gimbal_fault(now):
            return
        if self.state is LoopState.WAITING:
            if not self.motion.ready(self._frame, self._gimbal):
                return
            self._target = self.motion.here("initial", self._frame, self._gimbal)
            self._target.sent_s = now
            self._target.arrived_s = now
            self.state = LoopState.INITIAL
        if self._target is not None:  # going to a view, or there and waiting for its frame
            if self._target.arrived_s is None:
                self._check_arrival(now, out)
                return
            frame = self._frame
            waited = now - self._target.arrived_s
            if frame is None or frame.stamp_s < self._target.arrived_s + self.config.settle_s:
                if waited > self.config.settle_s + self.config.move_timeout_s:
                    self._capture_timeout(now)
                return
            if not self.motion.holds(self._target, frame, self.config):
                # a drone that arrived while passing through the target view: the capture is a
                # frame that shows it there (for half a move's timeout; then the frame there is)
                if waited <= self.config.settle_s + 0.5 * self.config.move_timeout_s:
                    return
                log.warning(
                    "%s: the %s capture is not at its target (the camera did not hold it)",
                    self.node_id,
                    self._target.kind,
                )
            self._record_capture(self._target, frame)
            finished_target = self._target
            self._target = None
            if finished_target.kind == "settle":
                self._finish(now, LoopState.DONE)
                return
        # choose what comes next
        if self.state is LoopState.INITIAL:
            self._queue = self.motion.explore(self.config.explore_views, self._frame, self.captures)
            ends = self._setting("survey_pitch_views")
            self._queue += self.motion.survey_pitch_ends(ends, self._frame)
            self._positions_explored = False
            self.state = LoopState.EXPLORING
        if self.state is LoopState.EXPLORING and not self._queue and not self._positions_explored:
            # after the turn (a drone): positions across the box, looking the best way seen so far,
            # then places far from them all (their captures feed the field, off the search's path)
            self._positions_explored = True
            places = self._setting("explore_places")
            self._queue = self.motion.explore_positions(self.config.explore_positions, self.captures)
            self._queue += self.motion.far_places(places, self.captures, [t.cam2world[:3, 3] for t in self._queue])
        if self.state is LoopState.EXPLORING and not self._queue:
            self.state = LoopState.PLANNING
        if self.state is LoopState.PLANNING:
            nxt = self._plan(now, out)
            if nxt is None:
                self._begin_polish(now)
            else:
                self._queue = [nxt]
                self.state = LoopState.MOVING
            return  # the command leaves in the next step, stamped after the planning
        if self.state is LoopState.MOVING and not self._queue:
            self.state = LoopState.PLANNING
            return
        if self.state is LoopState.POLISHING and not self._queue:
            self._polish_step(now)
        if self._queue:
            self._target = self._queue.pop(0)
            self._send(self._target, now, out)

    # ---------------------------------------------------------------------------- planning
    def _plan(self, now: float, out: Outputs) -> Target | None:
        """Search on the field of every capture; the best candidate worth a move, or None."""
        c = self.config
        if self.moves >= c.max_moves:
            return None
        captured = np.stack([cap.cam2world for cap in self.captures])  # [M, 4, 4]
        try:
            top = self._best_capture()
            best = next(i for i, cap in enumerate(self.captures) if cap is top)
            proposal = self._propose(captured, max(c.top_k, 4), keep_near=best, search=self._plan_search())
        except Exception:
            log.exception("%s: planning failed; settling on the best captured view", self.node_id)
            return None
        cands = [cd for cd in proposal.candidates if self._safe_candidate(cd)]
        out["planner/suggestion"].append(
            self._suggestion(cands[: c.top_k], proposal.field_version, now, proposal=proposal)
        )
        hope = self._hopes(cands, self.captures, proposal.captured_pred)
        best_true = self._value(self._best_capture())
        order = decision_order(hope, cands, c.hope_quantum, self._tie_margin())
        self._log_decision(cands, hope, order, best_true, proposal)
        far_left = self._far_moves_left()
        tied = self._tie_margin() > 0  # the order within a tie is by place: a later one may promise more
        for i in order:
            cd = cands[i]
            if hope[i] - best_true < c.margin:
                if tied:
                    continue
                break  # in order of hope: no later one promises more
            if near_captured(self.captures, cd.cam2world, c.min_move_deg, c.min_move_m):
                continue
            far = self._unvisited(cd.cam2world)
            if far and far_left <= 0:
                log.info(
                    "%s: not moving to %s (hope %.3f): no capture within %.2f m and %.0f deg, and %d such moves missed",
                    self.node_id,
                    _where(cd),
                    hope[i],
                    c.far_m,
                    c.far_deg,
                    self.far_misses,
                )
                continue
            log.info("%s: move %d: %s, hope %.3f", self.node_id, self.moves + 1, _where(cd), hope[i])
            target = Target("move", cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=float(hope[i]))
            if far:  # its capture is compared with the best captured view then (_record_capture)
                target.far_best = best_true
            return target
        explore = self._explore_target(proposal)
        if explore is not None:
            return explore
        return self._spare_target(cands, hope, order, best_true)

    def _spare_target(
        self, cands: list[Candidate], hope: np.ndarray, order: list[int], best_true: float
    ) -> Target | None:
        """Before stopping with moves left (``spare_gap``; unset: the motion's default, None = off):
        the best-ranked candidate whose hope lies within ``spare_gap`` of the best captured score
        (it may promise a little more, less than ``margin``) and that no capture looks within
        ``spare_apart_deg`` of (from within ``far_m``): a prediction no capture verified is
        checked with a move while the budget allows, rather than stopped on; else None."""
        c = self.config
        gap = self._setting("spare_gap")
        if gap is None or self.moves >= c.max_moves:
            return None
        for i in order:
            if not hope[i] >= best_true - gap:  # NaN: never
                if self._tie_margin() > 0:
                    continue
                break  # in order of hope
            cd = cands[i]
            if near_captured(self.captures, cd.cam2world, max(c.spare_apart_deg, c.min_move_deg), c.far_m):
                continue
            log.info(
                "%s: move %d: spare %s, hope %.3f (best captured %.3f; no capture within %.0f deg)",
                self.node_id,
                self.moves + 1,
                _where(cd),
                hope[i],
                best_true,
                c.spare_apart_deg,
            )
            return Target("move", cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=float(hope[i]))
        return None

    def _hopes(self, cands: list[Candidate], captures: list[Capture], captured_pred) -> np.ndarray:  # -> [C]
        """:func:`~aes_planner.node.captures.hopes` with the loop's settings: ``captured_pred`` [M],
        the scorer's prediction at each of ``captures``."""
        c = self.config
        hope = hopes(
            cands, captures, captured_pred, c.optimism, c.min_sigma, c.residual_length_deg, self._residual_length_m()
        )
        length = self._setting("shortfall_length_deg")
        if length > 0.0:  # a region whose captures fell short of their hopes: its views hope less
            hope = hope + shortfall(cands, captures, length, SHORTFALL_SLACK, c.shortfall_gate)
        return hope

    def _setting(self, name: str):
        """The config's ``name``, or the motion's default of that name when the config leaves it
        unset (None): how every per-platform loop setting is read."""
        value = getattr(self.config, name)
        return getattr(self.motion, name) if value is None else value

    def _residual_length_m(self) -> float | None:
        """``residual_length_m`` on a drone (unset: the motion's default); None (the view direction
        alone) on a rig, whose views share one place."""
        if self.motion.suggestion_mode == "rig":
            return None
        return self._setting("residual_length_m")

    def _tie_margin(self) -> float:
        """``hope_tie_margin`` (unset: the motion's default)."""
        return self._setting("hope_tie_margin")

    def _far_moves_left(self) -> float:
        """How many more moves may go to a place no capture was taken at or near (``far_moves``;
        unset: the motion's default, None = no limit) before one of them has to beat the best
        captured view: the field's prediction from such a place is checked once before the moves
        trust it again."""
        most = self._setting("far_moves")
        return math.inf if most is None else most - self.far_misses

    def _unvisited(self, cam2world: np.ndarray) -> bool:  # [4, 4]
        """Whether no capture was taken within ``far_m`` of a view's place looking within
        ``far_deg`` of its way (a drone's; 180: any way)."""
        c = self.config
        return bool(self.captures) and not any(
            np.linalg.norm(cap.cam2world[:3, 3] - cam2world[:3, 3]) <= c.far_m
            and (c.far_deg >= 180.0 or view_angle_deg(cap.cam2world, cam2world) < c.far_deg)
            for cap in self.captures
        )

    def _plan_search(self) -> dict | None:
        """The loop's stage 1 on a rig (``plan_grid_deg``; unset: the motion's default): a pan x
        tilt grid at that spacing over the joint range, no random neighbours and
        ``PLAN_GRID_HILLS`` views refined, as :class:`~aes_planner.search.SearchConfig` fields;
        on a drone with ``plan_draws`` false: the neighbours and coverage points of a fixed
        pattern (``fixed_draws``), and ``plan_adam_eps`` as stage 2's ``adam_eps``; None: the preset's."""
        step_deg = self._setting("plan_grid_deg")
        kinematics = getattr(self.platform, "kinematics", None)  # a rig's; a drone has none
        if kinematics is None:
            draws = self._setting("plan_draws")
            eps = self._setting("plan_adam_eps")
            fields = ({} if draws else {"fixed_draws": True}) | ({} if eps is None else {"adam_eps": eps})
            return fields or None
        if not step_deg:
            return None
        step_rad = math.radians(step_deg)
        (pan_lo, pan_hi), (tilt_lo, tilt_hi) = kinematics.pan_limits_rad, kinematics.tilt_limits_rad
        n_pan = max(math.ceil((pan_hi - pan_lo) / step_rad - 1e-9), 1)  # no cell more for a last bit
        n_tilt = max(math.ceil((tilt_hi - tilt_lo) / step_rad - 1e-9), 1)
        return {"grid_points": min(n_pan * n_tilt, MAX_GRID_POINTS), "neighbours": 0, "top_k": PLAN_GRID_HILLS}

    def _explore_target(self, proposal) -> Target | None:
        """Before stopping on the views it has: the search's exploratory candidate when its inputs
        cover less than ``explore_below_covered`` of the space (the best predicted view is then
        unverified where nothing was seen), up to ``explore_moves`` times; else None."""
        c = self.config
        cd = proposal.explore
        covered = proposal.covered_fraction
        if cd is None or covered is None or covered >= c.explore_below_covered or self.explored >= c.explore_moves:
            return None
        if near_captured(self.captures, cd.cam2world, c.min_move_deg, c.min_move_m):  # checked in _propose
            return None
        self.explored += 1
        log.info(
            "%s: move %d: explore %s (inputs cover %.2f of the space; the predictions are unverified beyond)",
            self.node_id,
            self.moves + 1,
            _where(cd),
            covered,
        )
        return Target("move", cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=None)

    def _log_decision(self, cands, hope, order, best_true, proposal) -> None:
        """The planning's evidence, one line: the best captured score, the ranked candidates with
        their prediction and hope, the coverage and the exploratory candidate (what a flip between
        two runs is read from)."""
        if not log.isEnabledFor(logging.INFO):
            return
        ranked = "; ".join(f"{_where(cands[i])} pred {cands[i].score:.3f} hope {hope[i]:.3f}" for i in order[:4])
        covered = proposal.covered_fraction
        log.info(
            "%s: planning after %d moves: best captured %.3f; %s; covered %s; explore %s",
            self.node_id,
            self.moves,
            best_true,
            ranked or "no candidate",
            "-" if covered is None else f"{covered:.2f}",
            "-" if proposal.explore is None else _where(proposal.explore),
        )

    def _best_capture(self) -> Capture:
        """The best captured view; a later capture displaces an earlier one only by more than
        ``tie_tolerance`` (a tie is not decided by the last bits of two scores). Under a framing,
        by :meth:`_value` (a view that cuts a kept subject is never the best unless none holds it)."""
        best = self.captures[0]
        values = self._values()
        if values is None:
            for cap in self.captures[1:]:
                if cap.score > best.score + self.config.tie_tolerance:
                    best = cap
            return best
        for cap in self.captures[1:]:
            if values[id(cap)] > values[id(best)] + self.config.tie_tolerance:
                best = cap
        return best

    # -------------------------------------------------------------- the framing in force
    def _values(self) -> dict[int, float] | None:
        """Under a framing (the proposer's :meth:`~aes_planner.node.proposer.Proposer.framed_views`),
        each capture's value to the loop by ``id``: its score plus the framing's soft terms when it
        holds every kept subject (the search's rule), else -inf; None: no framing (the score)."""
        framed = self._framed_views()
        if framed is None or not self.captures:
            return None
        # the object itself (an id may be reused once it is freed), and which captures
        key = (framed, len(self.captures), id(self.captures[0]), id(self.captures[-1]))
        old = getattr(self, "_values_key", None)
        if old is None or old[0] is not framed or old[1:] != key[1:]:
            ok, soft = framed.judge(np.stack([cap.cam2world for cap in self.captures]))  # [M], [M]
            self._values_cache = {
                id(cap): (cap.score + float(s) if fine else -math.inf) for cap, fine, s in zip(self.captures, ok, soft)
            }
            self._values_key = key
        return self._values_cache

    def _framed_views(self):
        """The proposer's :class:`~aes_planner.node.proposer.FramedViews` (None: no framing in force)."""
        get = getattr(self.proposer, "framed_views", None)
        return get() if get is not None else None

    def _value(self, cap: Capture) -> float:
        """A capture's score to the loop (:meth:`_values`; framing off: its score)."""
        values = self._values()
        return cap.score if values is None else values[id(cap)]

    def reported_best(self, scored: list[Capture]) -> Capture:
        """The best of the ``scored`` captures as the loop reports it: by score, or under a
        framing by :meth:`_value` when one of them holds every kept subject."""
        best = max(scored, key=lambda cap: cap.score)
        values = self._values() if self.config.active else None
        if values is None:
            return best
        held = [cap for cap in scored if values.get(id(cap), -math.inf) > -math.inf]
        return max(held, key=lambda cap: values[id(cap)]) if held else best

    def _feasible_targets(self, targets: list[Target]) -> list[Target]:
        """The polish's targets that hold every kept subject (framing off: all of them): a
        capture is not spent on a view the loop may not settle on."""
        framed = self._framed_views()
        if framed is None or not targets:
            return targets
        ok, _ = framed.judge(np.stack([t.cam2world for t in targets]))
        return [t for t, fine in zip(targets, ok) if fine]

    def _safe_candidate(self, cd: Candidate) -> bool:
        """A finite candidate, clamped into the platform's range (refusals counted)."""
        if not np.all(np.isfinite(cd.cam2world)) or not math.isfinite(cd.score):
            return False
        if not self.motion.safe(cd):
            self.counters["commands_refused"] += 1
            return False
        return True

    # --------------------------------------------------------------------- polish and settle
    def _begin_polish(self, now: float) -> None:
        c = self.config
        self._polish_left = c.polish_captures
        self._fine_left = c.polish_fine_captures
        self._fine_centres = []  # every view a fine round was centred on
        self.state = LoopState.POLISHING
        self._polish_centre = None
        self._climbs = None  # chosen once the hills' verifications are captured
        self._stood_on = []
        self._spares = 0
        self._flank_probe = None  # (flank captures, first probe's index) while their rounds are captured
        self._flank_done = False  # the flanks' rounds (and their climb) were taken, or there were none
        self._flank_climb = False  # the climbs from flanks' probes are on (no spare hill after them)
        self._turns = None  # a drone's turns verified one by one (_next_turn), while some are left
        self._flank_from = None  # the first capture of the flanks' rounds (first pass)
        self._flank_repeats = 0  # flank passes taken again (``flank_repeats``)
        self._repeat_round = None  # the capture index the coarse round of a repeat began at
        self._flank_among = 0  # the flanks are chosen among the captures from this index on
        # the hills the moves never reached: one real capture of each one's best predicted view
        # (on top of the polish's budget), so the hill climbed first is chosen on captures, not on
        # the field's (over-)estimate
        self._queue = self._verify_targets()
        if not self._queue:
            self._polish_step(now)

    def _verify_targets(self) -> list[Target]:
        """Up to ``verify_hills`` targets: the search's best predicted views on hills no capture
        lies on (at least a coarsest polish step from every capture, two from each other), ranked by hope
        (:func:`~aes_planner.node.captures.decision_order`), each hoping for at least the best
        captured score minus ``polish_start_gap`` (a hill that could be climbed)."""
        c = self.config
        if c.verify_hills <= 0 or c.polish_captures <= 0 or not self.captures:
            return []
        step_deg = self._coarsest_step_deg()
        captured = np.stack([cap.cam2world for cap in self.captures])  # [M, 4, 4]
        try:
            proposal = self._propose(captured, max(c.top_k, c.verify_hills + 2), search=self._plan_search())
        except Exception:
            log.exception("%s: the hills' verification failed; polishing the captured hills", self.node_id)
            return []
        cands = [cd for cd in proposal.candidates if self._safe_candidate(cd)]
        hope = self._hopes(cands, self.captures, proposal.captured_pred)
        floor = self._value(self._best_capture()) - c.polish_start_gap
        targets: list[Target] = []
        tied = self._tie_margin() > 0
        for i in decision_order(hope, cands, c.hope_quantum, self._tie_margin()):
            cd = cands[i]
            if len(targets) >= c.verify_hills:
                break
            if hope[i] < floor:
                if tied:
                    continue
                break
            if near_captured(self.captures, cd.cam2world, step_deg, c.min_move_m):
                continue  # within a coarse polish step of a capture: its climb can reach it
            if any(view_angle_deg(cd.cam2world, t.cam2world) < 2.0 * step_deg for t in targets):
                continue
            log.info("%s: verify a hill: %s, pred %.3f hope %.3f", self.node_id, _where(cd), cd.score, hope[i])
            targets.append(Target(CaptureKind.VERIFY, cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=float(hope[i])))
        unseen = self._unseen_target(proposal, step_deg, targets)
        targets += [unseen] if unseen is not None else []
        return targets + self._turn_targets(proposal, step_deg, targets, floor)

    def _turn_targets(self, proposal, step_deg: float, targets: list[Target], floor: float) -> list[Target]:
        """Up to ``verify_turns`` (unset: the motion's default) captures of the field's best view
        from a place the loop captured at, turning only (:meth:`Motion.turns`; places
        ``min_move_m`` or more apart, in the order they were first captured at): each place's
        best by hope, skipped within a coarsest polish step of a capture there or within two of
        another target, the places' bests ranked by hope
        (:func:`~aes_planner.node.captures.decision_order`), each hoping for at least ``floor``.
        A drone's captures look one way from each place; the climbs start only where a capture
        is (docs/benchmarks.md, "A drone looks one way from each place")."""
        c = self.config
        most = self._setting("verify_turns")
        if most <= 0:
            return []
        places: list[np.ndarray] = []
        for cap in self.captures:
            p = cap.cam2world[:3, 3]
            if all(np.linalg.norm(p - q) >= c.min_move_m for q in places):
                places.append(p)
        extra = self._setting("verify_places")
        if extra > 0:  # and the box's places never visited (Motion.unvisited_places): this many more turns
            places += self.motion.unvisited_places(self.captures, c.far_m)
            most += extra
        views = [self.motion.turns(p) for p in places]  # each [V, 4, 4]
        if not places or not sum(len(v) for v in views):
            return []
        try:
            pred = self.proposer.score_views(np.concatenate(views))  # [sum V]
        except Exception:
            log.exception("%s: scoring the places' turns failed; no turn verified", self.node_id)
            return []
        if pred is None or not np.all(np.isfinite(pred)):
            return []
        per_place, start = [], 0
        for v in views:
            per_place.append([Candidate(p, float(s)) for p, s in zip(v, pred[start : start + len(v)])])
            start += len(v)
        if self._turns_one_by_one():
            self._turns = {
                "places": per_place,
                "captures": list(self.captures),  # calibrated by proposal.captured_pred
                "pred": np.asarray(proposal.captured_pred, dtype=np.float64),  # [M]
                "verified": [],  # (capture, the scorer's prediction of its view)
                "pending": None,  # (target, its prediction, how many captures there were)
                "left": most,
                "step_deg": step_deg,
                "others": list(targets),
            }
            first = self._next_turn()
            return [first] if first is not None else []
        bests = self._place_bests(per_place, self.captures, proposal.captured_pred, step_deg)
        hope = self._hopes(bests, self.captures, proposal.captured_pred)
        out: list[Target] = []
        for i in decision_order(hope, bests, c.hope_quantum):
            cd = bests[i]
            if len(out) >= most or hope[i] < floor:
                break
            if self._near_turn(cd, targets + out, step_deg):
                continue
            log.info("%s: verify a turn: %s, pred %.3f hope %.3f", self.node_id, _where(cd), cd.score, hope[i])
            out.append(Target(CaptureKind.VERIFY, cd.cam2world, None, None, predicted=float(hope[i])))
        return self._feasible_targets(out)

    def _place_bests(
        self, places: list[list[Candidate]], captures: list[Capture], captured_pred, step_deg: float
    ) -> list[Candidate]:
        """Each place's best turn by hope (calibrated on ``captures`` and ``captured_pred`` [M]): not
        within a coarsest polish step (``step_deg``) of a capture there, and safe; a place with
        none gives none."""
        c = self.config
        bests: list[Candidate] = []
        for cands in places:
            hope = self._hopes(cands, captures, captured_pred)
            for i in decision_order(hope, cands, c.hope_quantum):
                cd = cands[i]
                if near_captured(self.captures, cd.cam2world, step_deg, c.min_move_m):
                    continue  # a capture there looks this way already: its climb can reach it
                if not self._safe_candidate(cd):
                    continue
                bests.append(cd)
                break
        return bests

    def _near_turn(self, cd: Candidate, others: list[Target], step_deg: float) -> bool:
        """``cd`` looks as one of ``others`` does (within two coarsest polish steps) from its place
        (within ``min_move_m``)."""
        return any(
            view_angle_deg(cd.cam2world, o.cam2world) < 2.0 * step_deg
            and np.linalg.norm(cd.cam2world[:3, 3] - o.cam2world[:3, 3]) <= self.config.min_move_m
            for o in others
        )

    def _turns_one_by_one(self) -> bool:
        """``turns_one_by_one`` on a drone (unset: the motion's default); never on a rig (no turns)."""
        if self.motion.suggestion_mode == "rig":
            return False
        return bool(self._setting("turns_one_by_one"))

    def _next_turn(self) -> Target | None:
        """The next turn verification when they are taken one by one (``turns_one_by_one``): the
        places' best turns ranked as :meth:`_turn_targets` ranks them, by a hope calibrated also on
        the turns verified so far (the scorer's prediction of each against its capture). The
        field's errors go by view direction (dev tabletop:208@drone: its best turn at five places
        was yaw -120 pitch 10, hope 0.64-0.65, each captured 0.32): one such miss lowers the
        same way's hope at the other places, and the next capture looks another way. None: no
        turn left (the count, or none hoping for the floor)."""
        t = self._turns
        if t is None:
            return None
        c = self.config
        if t["pending"] is not None:  # the pending turn's capture, when it was taken (not: skipped)
            target, raw, n_before = t["pending"]
            t["pending"] = None
            for cap in self.captures[n_before:]:
                if (
                    cap.kind is CaptureKind.VERIFY
                    and np.linalg.norm(cap.cam2world[:3, 3] - target.cam2world[:3, 3]) <= c.min_move_m
                    and view_angle_deg(cap.cam2world, target.cam2world) < c.min_move_deg
                ):
                    t["verified"].append((cap, raw))
                    break
        if t["left"] <= 0:
            self._turns = None
            return None
        caps = t["captures"] + [cap for cap, _ in t["verified"]]
        pred = np.concatenate([t["pred"], np.array([raw for _, raw in t["verified"]], dtype=np.float64)])  # [M']
        step_deg = t["step_deg"]
        bests = self._place_bests(t["places"], caps, pred, step_deg)
        hope = self._hopes(bests, caps, pred)
        floor = self._value(self._best_capture()) - c.polish_start_gap
        for i in decision_order(hope, bests, c.hope_quantum):
            cd = bests[i]
            if hope[i] < floor:
                break
            if self._near_turn(cd, t["others"], step_deg):
                continue
            target = Target(CaptureKind.VERIFY, cd.cam2world, None, None, predicted=float(hope[i]))
            if not self._feasible_targets([target]):
                continue
            log.info("%s: verify a turn: %s, pred %.3f hope %.3f", self.node_id, _where(cd), cd.score, hope[i])
            t["left"] -= 1
            t["others"].append(target)
            t["pending"] = (target, float(cd.score), len(self.captures))  # its capture comes later
            return target
        self._turns = None
        return None

    def _unseen_target(self, proposal, step_deg: float, targets: list[Target]) -> Target | None:
        """One verification of the search's exploratory candidate (the edge of what was seen) when
        its inputs cover less than ``explore_below_covered`` of the space and no capture or other
        verification lies within a coarsest polish step of it (``verify_unseen``; unset: the
        motion's default): the moves may have spent the budget before the loop explored, and a
        hill there is then climbed only if a capture shows it."""
        c = self.config
        on = self._setting("verify_unseen")
        cd, covered = proposal.explore, proposal.covered_fraction
        if not on or cd is None or covered is None or covered >= c.explore_below_covered:
            return None
        if near_captured(self.captures, cd.cam2world, step_deg, c.min_move_m):
            return None
        if any(view_angle_deg(cd.cam2world, t.cam2world) < step_deg for t in targets):
            return None
        log.info("%s: verify the unseen: %s (inputs cover %.2f of the space)", self.node_id, _where(cd), covered)
        return Target(CaptureKind.VERIFY, cd.cam2world, cd.pan_rad, cd.tilt_rad, predicted=None)

    def _begin_climbs(self) -> None:
        """The best hill and the runners-up nearly as good, each climbed in turn: a hill captured
        second (or on its flank, or only verified) is not lost to the local optimum captured first.
        More such hills than climbs (up to ``polish_hills``): first one coarsest round on each
        (queued here), and the climbs go to the hills whose rounds found the most
        (:meth:`_rank_probed`): a capture on a hill's flank says little of its peak. Moves that
        fell short (:meth:`_short_hills`) get a coarsest and a half-coarsest round each first
        (on top of the budget), and join that choice when a round comes near the best."""
        c = self.config
        step_deg = self._coarsest_step_deg()
        hills = self._polish_starts(2.0 * step_deg, max(c.polish_starts, c.polish_hills))
        probes: list[Target] = []
        if len(hills) > c.polish_starts:
            for hill in hills:
                probes += self._round(hill, step_deg, c.polish_step_m * 2.0 ** (c.polish_scales - 1), probes)
            probes = self._feasible_targets(probes)[: self._polish_left]
            self._polish_left -= len(probes)
        short = self._short_hills(hills, 2.0 * step_deg)
        extra: list[Target] = []
        for hill in short:
            for ring_deg in (step_deg, 0.5 * step_deg):
                extra += self._feasible_targets(self._round(hill, ring_deg, 0.0, probes + extra))
        if probes or extra:
            log.info(
                "%s: %d hills nearly as good as the best, %d moves that fell short: %d probe captures first",
                self.node_id,
                len(hills),
                len(short),
                len(probes) + len(extra),
            )
            self._probed = (hills + short, len(self.captures), len(hills))
            self._queue = probes + extra
            self._climbs = []
            return
        self._set_climbs(hills[: c.polish_starts])

    def _round(self, centre: Capture, step_deg: float, step_m: float, taken: list[Target]) -> list[Target]:
        """The polish neighbours ``step_deg`` from ``centre`` that no capture and none of ``taken``
        lies within half a step of."""
        half = 0.5 * step_deg
        return [
            t
            for t in self.motion.polish(centre, math.radians(step_deg), step_m)
            if not near_captured(self.captures, t.cam2world, half, self.config.min_move_m)
            and not any(view_angle_deg(t.cam2world, q.cam2world) < half for q in taken)
        ]

    def _short_hills(self, hills: list[Capture], apart_deg: float) -> list[Capture]:
        """Up to ``short_hills`` (unset: the motion's default) moves that are none of ``hills``,
        ``apart_deg`` or more from each of them and from each other, highest hope first: the
        field expected each to beat every capture, and its one capture may have landed on the
        flank of a peak narrower than the field sees."""
        c = self.config
        most = self._setting("short_hills")
        if most <= 0:
            return []
        moves = [
            cap
            for cap in self.captures
            if cap.kind is CaptureKind.MOVE and cap.predicted is not None and math.isfinite(self._value(cap))
        ]
        moves.sort(key=lambda cap: -round(cap.predicted / c.hope_quantum))  # stable: earlier first on a tie
        short: list[Capture] = []
        for cap in moves:
            if len(short) >= most:
                break
            if all(view_angle_deg(cap.cam2world, h.cam2world) >= apart_deg for h in hills + short):
                short.append(cap)
        return short

    def _coarsest_step_deg(self) -> float:
        """The polish's coarsest step: ``polish_step_deg * 2**(polish_scales - 1)``."""
        return self.config.polish_step_deg * 2.0 ** (self.config.polish_scales - 1)

    def _set_climbs(self, starts: list[Capture]) -> None:
        self._climbs = starts
        self._climb_budget = max(self._polish_left // max(len(starts), 1), 1)

    def _rank_probed(self) -> None:
        """After the hills' coarse rounds: each round's captures go to the hill they lie nearest
        (view direction, then position); the ``polish_starts`` hills whose best capture (the
        hill's own or its round's) scored highest are climbed, best first, each from that capture.
        A short move's hill (:meth:`_short_hills`, listed after the others) is one of them only
        when its best capture lies within ``polish_start_gap`` of the best capture."""
        hills, first, regular = self._probed
        self._probed = None
        best = list(hills)
        for cap in self.captures[first:]:
            j = min(
                range(len(hills)),
                key=lambda k: (
                    view_angle_deg(cap.cam2world, hills[k].cam2world)
                    + 100.0 * float(np.linalg.norm(cap.cam2world[:3, 3] - hills[k].cam2world[:3, 3]))
                ),
            )
            if self._value(cap) > self._value(best[j]) + self.config.tie_tolerance:
                best[j] = cap
        floor = self._value(self._best_capture()) - self.config.polish_start_gap
        ranked = [k for k in range(len(hills)) if k < regular or self._value(best[k]) >= floor]
        order = sorted(ranked, key=lambda k: -self._value(best[k]))  # stable: the hill ranked first on a tie
        chosen = [best[k] for k in order[: self.config.polish_starts]]
        log.info(
            "%s: hills after their coarse rounds: %s; climbing %d",
            self.node_id,
            ", ".join(f"{hills[k].score:.3f} -> {best[k].score:.3f}{'' if k < regular else ' (short)'}" for k in order),
            len(chosen),
        )
        self._set_climbs(chosen)

    def _spare_climb(self) -> bool:
        """Every climb ended with polish captures left: queue one more hill to climb with all that
        is left (up to ``spare_hills`` such climbs; unset: the motion's default), the best capture,
        verifications included, within ``polish_start_gap`` of the best and two coarsest steps or
        more from every view a climb stood on. False when there is none."""
        c = self.config
        most = self._setting("spare_hills")
        if self._spares >= most or self._polish_left <= 0:
            return False
        apart_deg = 2.0 * self._coarsest_step_deg()
        floor = self._value(self._best_capture()) - c.polish_start_gap
        for cap in sorted(self.captures, key=lambda cap: -self._value(cap)):  # stable: earlier first on a tie
            if self._value(cap) < floor or self._value(cap) == -math.inf:
                return False
            if all(view_angle_deg(cap.cam2world, s.cam2world) >= apart_deg for s in self._stood_on):
                self._spares += 1
                log.info(
                    "%s: %d polish captures left: climbing a spare hill (%.3f, best %.3f)",
                    self.node_id,
                    self._polish_left,
                    cap.score,
                    self._best_capture().score,
                )
                self._set_climbs([cap])  # the whole of what is left (one climb)
                return True
        return False

    def _polish_starts(self, apart_deg: float, most: int) -> list[Capture]:
        """The best capture, then up to ``most - 1`` others scoring within
        ``polish_start_gap`` of it, each at least ``apart_deg`` from those before (other hills).
        A verification is a start only when it is the best capture: one real sample of a hill
        does not displace a runner-up the moves found (and the field's ranking of the two is
        what it over-rates); then a move's capture is another hill from ``verify_apart_deg`` of it
        (unset: the motion's default; unset both: ``apart_deg``)."""
        c = self.config
        best = self._best_capture()
        ranked = sorted(self.captures, key=lambda cap: -self._value(cap))  # stable: earlier first on a tie
        starts = [best]
        # a verified best view: a move is another hill from ``verify_apart_deg`` of it (unset: ``apart_deg``)
        verify_apart = self._setting("verify_apart_deg")
        if verify_apart is None or best.kind is not CaptureKind.VERIFY:
            verify_apart = apart_deg
        for cap in ranked:
            if cap.kind is CaptureKind.VERIFY:
                continue
            if len(starts) >= most or self._value(cap) < self._value(best) - c.polish_start_gap:
                break
            if self._value(cap) == -math.inf:
                break
            if all(
                view_angle_deg(cap.cam2world, s.cam2world)
                >= (verify_apart if s is best and cap.kind is CaptureKind.MOVE else apart_deg)
                for s in starts
            ):
                starts.append(cap)
        return starts

    def _polish_step(self, now: float) -> None:
        """One round of a coarse-to-fine compass search on real captures around the current hill's
        centre: its four neighbours ``polish_step_deg * 2**scale`` away (scales ``polish_scales - 1``
        down to 0); the centre moves to a neighbour of the round that beat it by more than
        ``tie_tolerance`` (the same step again), else the step halves; the climb ends after the
        finest step or its share of the budget, and the next hill's climb begins; settle when
        every climb ended."""
        c = self.config
        if self._climbs is None and self._turns is not None:  # a drone's next turn, one by one
            nxt = self._next_turn()
            if nxt is not None:
                self._queue = [nxt]
                return
        if self._climbs is None:
            self._begin_climbs()
            if self._queue:  # the hills' coarse rounds go first
                return
        if self._probed is not None:
            self._rank_probed()
        while self._polish_left > 0:
            if self._polish_centre is None:  # the next climb
                if not self._climbs and (self._flank_climb or not self._spare_climb()):
                    break
                self._polish_centre = self._climbs.pop(0)
                self._stood_on.append(self._polish_centre)
                # a flank's probe is climbed from a quarter of the coarsest step (its round was at half)
                self._polish_scale = max(c.polish_scales - 3, 0) if self._flank_climb else c.polish_scales - 1
                self._climb_left = self._climb_budget
                self._round_from = None
                self._polish_previous = None
            elif self._round_from is not None:  # the round just captured
                top = self._polish_centre
                # a coarse step moves the centre only on a material gain (a narrow peak beside it)
                gain = c.tie_tolerance if self._polish_scale == 0 else max(c.tie_tolerance, c.polish_coarse_gain)
                for cap in self.captures[self._round_from :]:
                    if self._value(cap) > self._value(top) + gain:
                        top = cap
                self._round_from = None
                if top is not self._polish_centre:
                    previous, self._polish_centre = self._polish_centre, top
                    self._polish_previous = previous
                    self._stood_on.append(top)
                else:
                    self._polish_scale -= 1
                if self._polish_scale < 0 or self._climb_left <= 0:
                    self._polish_centre = None
                    continue
            centre = self._polish_centre
            step_deg = c.polish_step_deg * 2.0**self._polish_scale
            step_m = c.polish_step_m * 2.0**self._polish_scale
            neighbours = self.motion.polish(centre, math.radians(step_deg), step_m)
            previous = self._polish_previous
            if previous is not None and previous is not centre:  # keep going the way the last step went
                neighbours.sort(key=lambda t: -view_angle_deg(t.cam2world, previous.cam2world))
            half_step_deg = 0.5 * step_deg
            same_m = min(c.min_move_m, 0.5 * step_m) if step_m > 0 else c.min_move_m  # a translated neighbour is new
            targets = [t for t in neighbours if not near_captured(self.captures, t.cam2world, half_step_deg, same_m)]
            targets = self._feasible_targets(targets)
            if not targets:  # every neighbour at this step was captured already: a finer step
                self._polish_scale -= 1
                if self._polish_scale < 0:
                    self._polish_centre = None
                continue
            self._queue = targets[: min(self._polish_left, self._climb_left)]
            self._polish_left -= len(self._queue)
            self._climb_left -= len(self._queue)
            self._round_from = len(self.captures)
            return
        if self._flank_step():
            if not self._queue:  # the climbs from flanks' probes: the first one's first round
                self._polish_step(now)
            return
        if self._flank_repeat(now):
            return
        if self._fine_round():
            return
        self._begin_settle(now)

    def _flank_step(self) -> bool:
        """After the climbs (on top of the budget): up to ``flank_hills`` captures (unset: the
        motion's default) within ``polish_start_gap`` of the best, 0.75 of a coarsest step or more
        from every view a climb stood on and from each other, best first, get one round at half
        the coarsest step; then up to ``FLANK_CLIMBS`` probes that beat their own flank capture
        (by more than ``tie_tolerance``), best first, are climbed from a quarter of the coarsest
        step down, sharing ``flank_captures``. A coarse round's capture can lie on the flank of
        another peak narrower than the step (dev outdoor:242: 0.731 at 4.5 deg from the oracle's
        0.830, while the climb went the other way), and no capture came within 5 deg of that
        peak; a move that fell short beside a climbed hill is the same (dev tabletop:233: 0.609,
        5 deg from the oracle's 0.760). False: nothing (more) to take; True: a round was queued,
        or the climbs set (their first round is the caller's)."""
        c = self.config
        if self._flank_done:
            return False
        if self._flank_probe is None:
            flanks = self._flank_hills()
            ring_deg = 0.5 * self._coarsest_step_deg()
            targets: list[Target] = []
            for flank in flanks:
                targets += self._feasible_targets(self._round(flank, ring_deg, 0.0, targets))
            if not targets:
                self._flank_done = True
                return False
            log.info(
                "%s: %d near-best captures beside the climbed hills: %d probe captures",
                self.node_id,
                len(flanks),
                len(targets),
            )
            self._flank_probe = (flanks, len(self.captures))
            if self._flank_from is None:
                self._flank_from = len(self.captures)
            self._queue = targets
            return True
        flanks, first = self._flank_probe
        self._flank_probe = None
        self._flank_done = True
        risen: list[Capture] = []
        for cap in self.captures[first:]:
            j = min(range(len(flanks)), key=lambda k: view_angle_deg(cap.cam2world, flanks[k].cam2world))
            if self._value(cap) > self._value(flanks[j]) + c.tie_tolerance:
                risen.append(cap)
        risen.sort(key=lambda cap: -self._value(cap))  # stable: earlier first on a tie
        tops = risen[:FLANK_CLIMBS]
        if not tops or c.flank_captures <= 0:
            return False
        log.info(
            "%s: climbing %d flanks' probes (%s; best %.3f)",
            self.node_id,
            len(tops),
            ", ".join(f"{cap.score:.3f}" for cap in tops),
            self._best_capture().score,
        )
        self._flank_climb = True
        self._polish_left = c.flank_captures
        self._polish_centre = None
        self._set_climbs(tops)
        return True

    def _flank_repeat(self, now: float) -> bool:
        """After the flanks' pass (on top of the budget), up to ``flank_repeats`` times (unset: the
        motion's default), when the best capture came from that pass (its climbs start a quarter
        of the coarsest step out, so no coarse round was ever taken around the top they reached):
        one round at the coarsest step around the best capture, then the flanks' pass again (its
        rounds and climbs, :meth:`_flank_step`) over the captures that round added. A hill beside
        the top a flank climb reached, behind a valley narrower than the coarsest step, was never
        probed (dev photo_ring_room: the flank climb topped 0.762 at pan 76, the oracle 0.834 at
        pan 59, the valley at pan 67.5). False: nothing (more) to take."""
        most = self._setting("flank_repeats")
        if self._repeat_round is None:
            if self._flank_repeats >= most or self._flank_from is None:
                return False
            best = self._best_capture()
            if not any(best is cap for cap in self.captures[self._flank_from :]):
                return False
            self._flank_repeats += 1
            targets = self._feasible_targets(self._round(best, self._coarsest_step_deg(), 0.0, []))
            if not targets:
                return False
            log.info(
                "%s: the flanks' climbs topped the best (%.3f): a coarse round around it", self.node_id, best.score
            )
            self._repeat_round = len(self.captures)
            self._queue = targets
            return True
        self._flank_among, self._repeat_round = self._repeat_round, None
        self._flank_done = False  # the flanks' pass again, over what the round added
        self._flank_probe = None
        self._polish_step(now)
        return True

    def _flank_hills(self) -> list[Capture]:
        """The captures :meth:`_flank_step` takes a round around (see there), best first."""
        c = self.config
        most = self._setting("flank_hills")
        if most <= 0 or c.polish_captures <= 0 or not self.captures:
            return []
        apart_deg = 0.75 * self._coarsest_step_deg()
        floor = self._value(self._best_capture()) - c.polish_start_gap
        flanks: list[Capture] = []
        among = self.captures[self._flank_among :]  # a repeat's pass: the captures its coarse round added
        for cap in sorted(among, key=lambda cap: -self._value(cap)):  # stable: earlier first on a tie
            if len(flanks) >= most or self._value(cap) < floor or not math.isfinite(self._value(cap)):
                break
            if all(view_angle_deg(cap.cam2world, s.cam2world) >= apart_deg for s in self._stood_on + flanks):
                flanks.append(cap)
        return flanks

    def _fine_round(self) -> bool:
        """After the climbs (on top of ``polish_captures``): the four neighbours half the finest
        step from the best captured view, again from a better one, then (nothing better) around
        each capture within ``polish_fine_gap`` of the best that no round was centred on, up to
        ``polish_fine_captures``;
        only where that half step exceeds ``arrival_tolerance_deg`` (a rig), else the camera
        cannot tell it from the view. Composition peaks are narrower than the finest step (dev
        tabletop:210: 0.741-0.776 within 0.5 deg), so where a climb stops on such a peak
        depends on where it began, which changes with the search's seed. False: none to take."""
        c = self.config
        step_deg = 0.5 * c.polish_step_deg
        if c.polish_captures <= 0 or self._fine_left <= 0 or step_deg <= c.arrival_tolerance_deg:
            return False
        best = self._best_capture()
        centres = [best]
        if any(best is f for f in self._fine_centres):
            # the last round found nothing better: a near-best capture no round was centred on
            # (a tie at the finest step decided by a few thousandths), best first; under a framing
            # only captures that hold the kept subjects (a finite value)
            floor = self._value(best) - c.polish_fine_gap
            centres = [
                cap
                for cap in sorted(self.captures, key=lambda cap: -self._value(cap))  # stable: earlier first on a tie
                if math.isfinite(self._value(cap))
                and self._value(cap) >= floor
                and not any(cap is f for f in self._fine_centres)
            ]
        for centre in centres:
            self._fine_centres.append(centre)
            targets = self._feasible_targets(self._round(centre, step_deg, 0.0, []))[: self._fine_left]
            if targets:
                if centre is not best:
                    log.info(
                        "%s: fine rounds around a near-best capture (%.3f, best %.3f)",
                        self.node_id,
                        centre.score,
                        best.score,
                    )
                self._fine_left -= len(targets)
                self._queue = targets
                return True
        return False

    def _begin_settle(self, now: float) -> None:
        if not self.captures:
            self._finish(now, LoopState.FAILED)
            return
        best = self._best_capture()
        framed = self._framed_views()
        if framed is None and getattr(self.proposer, "framing", None) is not None:
            # a framing set after the last search (or no search at all): one search applies it
            try:
                self._propose(np.stack([cap.cam2world for cap in self.captures]), self.config.top_k)
            except Exception:
                log.exception("%s: the framing's search before settling failed", self.node_id)
            framed = self._framed_views()
        if framed is not None and self._value(best) == -math.inf and framed.fallback is not None:
            # no capture holds every kept subject: the search's feasible suggestion, never a capture that cuts one
            cd = framed.fallback
            self.count("framing_settled_on_suggestion")
            log.warning(
                "%s: no captured view holds the kept subject; settling on the search's suggestion %s",
                self.node_id,
                _where(cd),
            )
            self._queue = [Target("settle", cd.cam2world.copy(), cd.pan_rad, cd.tilt_rad, predicted=cd.score)]
        else:
            self._queue = [Target("settle", best.cam2world.copy(), best.pan_rad, best.tilt_rad, predicted=best.score)]
        self.state = LoopState.SETTLING

    def _finish(self, now: float, state: LoopState) -> None:
        self.state = state
        self.finished_s = now
        self._queue.clear()
        self._target = None

    # ------------------------------------------------------------------ moving and arriving
    def _send(self, target: Target, now: float, out: Outputs) -> None:
        target.sent_s = now
        target.arrived_s = None
        if target.kind == "move":
            self.moves += 1
            self.counters["moves"] += 1
        if not self.motion.send(self, target, now, out):
            self.counters["commands_refused"] += 1
            self._target = None

    def _check_arrival(self, now: float, out: Outputs) -> None:
        t, c = self._target, self.config
        if self.motion.arrived(t, now, self._frame, self._gimbal, c):
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
                self._finish(now, LoopState.FAILED)

    def _gimbal_fault(self, now: float) -> bool:
        """Whether a device fault pauses the loop now (and the loop's end when it lasts)."""
        g = self._gimbal
        if not self.motion.faulty(g):
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
            self._finish(now, LoopState.FAILED)
        return True

    # ----------------------------------------------------------------------------- capturing
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
        self._finish(now, LoopState.FAILED)

    def _record_capture(self, target: Target, frame: PosedFrame) -> None:
        img = torch.from_numpy(np.ascontiguousarray(frame.image)).permute(2, 0, 1)[None].float() / 255.0
        with torch.no_grad():
            score = float(self.teacher.score(img)[0])
        pan = frame.pan_rad if getattr(frame, "pan_rad", None) is not None else target.pan_rad
        tilt = frame.tilt_rad if getattr(frame, "tilt_rad", None) is not None else target.tilt_rad
        if pan is None:
            pan, tilt = self.motion.joints_now(self._gimbal)
        cap = Capture(
            target.kind,
            frame.cam2world.copy(),
            score,
            frame.stamp_s,
            pan,
            tilt,
            target.predicted,
            frame.image,
            look_distance_m(frame.depth_m),
        )
        if target.far_best is not None and score <= target.far_best + self.config.tie_tolerance:
            self.far_misses += 1  # a move to an unvisited place that did not beat the best
        self.captures.append(cap)
        self.counters["captures"] += 1
        self.counters["frames_used"] += 1
        self.proposer.add_frame(frame, keep=True, **({} if target.on_path else {"on_path": False}))
        log.info(
            "%s: captured (%s) score %.3f%s",
            self.node_id,
            target.kind,
            score,
            f" (predicted {target.predicted:.3f})" if target.predicted is not None else "",
        )
