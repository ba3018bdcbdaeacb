"""``PlannerConfig``: every knob of :class:`~aes_planner.node.planner.PlannerNode`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from aes_planner.config import require, require_numbers, require_optional_bool, require_optional_int
from aes_planner.geometry.plausible import MAX_STAMP_AHEAD_S
from aes_planner.platform import DronePlatformConfig, RigPlatformConfig, parse_platform
from aes_planner.runtime import MAX_THREADS

__all__ = ["PlannerConfig"]


@dataclass
class PlannerConfig:
    """How the planner builds its field, searches and (on a rig) drives the active loop.

    * ``scorer``: ``"field"`` (the trained aesthetic field, the default: better and faster in the
      closed loop on held-out scenes, docs/benchmarks.md) or ``"rgb"`` (RGB scoring of the
      reconstruction).
    * ``preset``: search preset (``fast``, ``balanced``); ``teacher``: the teacher name.
    * ``active``: run the active loop (commands the gimbal / flies the drone); false = suggest only.
    * ``explore_views``: captures spread over the range before the first suggestion.
    * ``explore_positions``: a drone only (a rig ignores it): after turning in place, captures at
      this many positions spread across its box (to either side of the start and ahead of and
      behind it, each most of the way to the box's wall), each looking the way the best capture so
      far looks: the field then has seen the scene from more than one place, and the moves and the
      polish are not bound to the start (a drone that only turned stayed within ~0.2 m of it).
    * ``explore_places``: a drone only: after the exploration's positions, captures from this
      many places of a lattice of the box (height included) farthest from every capture, each
      looking at what the best capture looks at; they feed the field but not the search's input
      trajectory (stage 1 samples along the captures' path; ``search_grid_points`` proposes views
      from the lattice). Unset: the platform's default (0 on both: 4 such places with the grid
      measured worse on dev drones than the grid alone, docs/benchmarks.md).
    * ``max_moves``: suggestion-driven moves at most; ``margin``: the gain (teacher units) a
      suggestion must promise over the best captured view to be worth a move. The promise is the
      scorer's prediction calibrated on the captures (their true teacher scores: ``true = pred +
      offset``, offset the median residual) plus ``optimism`` times the residuals' spread (at
      least ``min_sigma``): a scorer that is often wrong earns more checks. Errors at captures
      within about ``residual_length_deg`` of a candidate correct it most (and shrink its spread).
    * ``min_move_deg``: a candidate closer than this (view direction) to a captured view, with
      no more than ``min_move_m`` of translation, is not a new view.
    * ``polish_captures``: captures spent, after the last move, on a coarse-to-fine compass search
      around the best captured view (neighbours ``polish_step_deg * 2**k`` away in pan and tilt,
      or yaw and pitch for a drone, k from ``polish_scales - 1`` down to 0; the search moves to a
      better neighbour, halves the step when none is better and stops after the finest step);
      0 = settle at once. ``polish_step_deg`` should exceed ``arrival_tolerance_deg``.
      ``polish_step_m``: a drone only: its polish also moves ``polish_step_m * 2**k`` to either
      side and forward and back (0 = turns only); should exceed ``arrival_tolerance_m``.
    * ``polish_fine_captures``: after the climbs, up to this many more captures (on top of
      ``polish_captures``): the four neighbours ``polish_step_deg / 2`` from the best captured
      view, and again around a better one; only when that half step exceeds
      ``arrival_tolerance_deg`` (a rig; a drone's tolerance is wider). 0 = none.
    * ``polish_fine_gap``: when a fine round finds nothing better, the fine rounds go on around
      each capture within this (teacher units) of the best that no fine round was centred on,
      best first (and again around a better one): on a peak narrower than the finest step, two
      captures a step apart can tie within a few thousandths, and the one a hair higher is not
      always the side the peak is on (dev wide_indoor_204: 0.821 and 0.818 2.5 deg apart, the
      peak 0.861 0.6 deg from the lower one). 0 = only around the best.
    * ``polish_starts``: hills the polish climbs, one after the other, each with an equal share of
      ``polish_captures``: the best captured view and up to ``polish_starts - 1`` others within
      ``polish_start_gap`` (teacher units) of it, at least two coarsest steps apart (a hill
      captured second is not lost to the local optimum captured first; three, because on dev
      tabletop:202 the oracle's hill was the third captured, touched only on its flank); the loop
      settles on the best view of all.
    * ``polish_hills``: when more captured hills than ``polish_starts`` lie within
      ``polish_start_gap`` of the best (up to this many), each first gets one round at the
      coarsest step, and the ``polish_starts`` hills whose rounds found the most are climbed
      (the captures are the polish's): a move that caught the best hill on its flank (dev
      tabletop:202: 0.68, 12 deg below a 0.80 peak) ranks below hills captured nearer their
      lower peaks. <= ``polish_starts``: the captured scores alone choose.
    * ``verify_hills``: before the climbs, up to this many captures (on top of
      ``polish_captures``) of the search's best predicted views on hills no capture lies on
      (a coarsest polish step or more from every capture; ranked by hope, each hoping for at
      least the best captured score minus ``polish_start_gap``): a verification that beats every
      capture is the first hill climbed, whichever hills the moves happened to visit. 0 = none.
    * ``verify_turns``: a drone only: before the climbs, up to this many more captures (on top of
      ``polish_captures``, after the hills' verifications): from each place the loop captured at
      (places ``min_move_m`` or more apart), the field's best view turning only (yaw every
      15 deg x pitch every 10 deg inside the searched range), ranked by hope, each hoping for at
      least the best captured score minus ``polish_start_gap`` and a coarsest polish step or more
      from every capture there. A drone visits good places but looks one way from each (the
      exploration positions all look at what the best turn saw): dev tabletop:212@drone,
      indoor:213@drone and tabletop:217@drone had a place whose best turn scores >= 0.9 of the
      oracle, never looked at, while the moves went to views over-rated by 0.15-0.25. A polish
      climbs what captures found, so one real capture per place lets it start there. Unset: the
      platform's default (a drone 6, measured on 39 dev drone runs: docs/decisions.md; a rig 0:
      its one place is the pan x tilt grid's). ``verify_hills`` 0 takes none either.
    * ``spare_hills``: when every climb ended with polish captures left (a climb that reached its
      finest step early), the rest climb up to this many more hills, one after the other, each
      with what is left: the best capture (verifications included) within ``polish_start_gap`` of
      the best that lies two coarsest polish steps or more from every view a climb stood on. A
      run's path up to there is unchanged and it settles on its best capture, so the figure can
      only rise (dev tabletop:202 ``seed:2``: two climbs spent 30 of 48 captures while a
      verified hill 0.02 below the best was never climbed). Unset: the platform's default (2 on
      both; a drone's since session 29, with ``flank_hills`` and ``settle_tolerance_deg``: dev
      drones 0.9423 -> 0.9436, below 0.9 7 -> 6, docs/decisions.md).
    * ``short_hills``: before the climbs, up to this many moves whose capture is not a hill the
      polish climbs (it fell more than ``polish_start_gap`` short of the best, or lies on none of
      the climbed hills), at least two coarsest polish steps from every such hill and from each
      other, ranked by the hope that sent the move, each get one round at the coarsest polish
      step and one at half of it (up to 8 captures each, on top of ``polish_captures``); a
      probe that comes within ``polish_start_gap`` of the best makes its hill one the climbs
      choose from (by what the rounds found, as ``polish_hills``), climbed from that probe. The
      field finds a hill but not its narrow peak: a move can land on the flank, 6-15 deg off a
      peak better than every capture (dev tabletop:217: a move at pan 9 tilt -27 scored 0.49
      against a hope of 0.77, the peak 0.80 at tilt -12.5 on a ridge 5 deg wide), and a hill
      whose one capture fell short was never climbed. Unset: the platform's default (a rig 2:
      25 dev rig runs 0.975 -> 0.990 of the oracle, none lower, docs/decisions.md; a drone 0,
      not measured there).
    * ``verify_apart_deg``: when the best capture is a verification, a move's capture counts as
      a hill of its own (a polish start) from this far of it (deg), instead of two coarsest
      polish steps (the start view, explorations and polish captures keep those; with any
      capture, dev gallery:227 fell 1.000 -> 0.885: its start view became a hill and the move
      beside it lost its probe rounds): a verification lies a coarsest step or more from every capture, and a move
      near a peak 19.5 deg beside a verified view nearly as good was taken for the same hill and
      never climbed (dev gallery:228: the move 0.683, 3.3 deg from the oracle's 0.762; the
      verification 0.697). Unset: the platform's default (a rig 15: 25 dev rig runs 0.990 ->
      0.993 of the oracle, none lower, docs/decisions.md; a drone two coarsest steps, not
      measured there).
    * ``flank_hills``: after the climbs, up to this many captures within ``polish_start_gap`` of
      the best that lie 0.75 of a coarsest polish step or more from every view a climb stood on
      (and from each other), best first, each get one round at half the coarsest step (up to 4 captures each, captured neighbours skipped, on top of
      ``polish_captures``); up to two probes that beat their own flank capture are then climbed
      from a quarter of the coarsest step down, sharing ``flank_captures`` more. A coarse
      round's capture can land on the flank of another peak narrower than the step; it scores
      below the round's centre, the climb goes elsewhere, and nothing comes within 5 deg of that
      peak (dev outdoor:242: 0.731 at 4.5 deg from the oracle's 0.830; gallery:243: 0.636 at 4
      deg from a 3-deg-wide 0.817 ridge); so does a move that fell short beside a climbed hill
      (dev tabletop:233: 0.609 at 5 deg from the oracle's 0.760). Unset: the platform's default (6 on both; a drone's
      since session 29, with ``spare_hills``). ``flank_captures``: 16.
    * ``verify_unseen``: with the hills' verifications, one capture of the search's exploratory
      candidate (the edge of what the inputs saw) when they cover less than
      ``explore_below_covered`` and no capture lies within a coarsest polish step of it: four
      moves spent on predicted hills leave the loop no move to explore with (dev tabletop:213:
      the oracle's view lay 4.5 deg from the exploratory candidate, never captured). A capture
      there that beats every capture is climbed first; nearly as good, a spare hill. Unset: the
      platform's default (a rig true; a drone false, not measured there).
    * ``search_grid_points``: the search's ``grid_points`` (:class:`~aes_planner.search.SearchConfig`)
      in the active loop's searches (passive mode keeps the preset's): about this many stage-1
      candidates spread over the whole space, independent of the captures (a drone: places on a
      lattice of its box, each looking several ways, :meth:`~aes_planner.search.space.FreeSpace.grid`),
      so a view from a place nobody visited can be proposed (and is verified by a capture before it is trusted). Unset: the
      platform's default (a drone 216: 9 places x 8 yaws x 3 pitch bands, measured on dev drones,
      docs/decisions.md; a rig 0, its stage 1 unchanged).
    * ``plan_grid_deg``: the active loop's searches on a rig (its plannings and the hills'
      verification; not a passive suggestion) score a pan x tilt grid at about this spacing
      (degrees) over the joint range in stage 1 instead of random neighbours around the inputs,
      and refine 8 views in stage 2 (``active_loop.PLAN_GRID_HILLS``, not 4: two grid views can
      lie on one broad hill): stage 1 then draws nothing at random, so which hills the loop sees
      does not depend on the search's seed (dev tabletop:202: two seeds' first plannings held different hills, within
      0.015 of hope of each other). 0 = the preset's stage 1 (random neighbours). Unset: the
      platform's default (a rig 4: with the fine rounds' ``polish_fine_gap``, 27 dev rig runs
      0.989 -> 0.991 of the oracle, the spread over three search seeds 0.020 -> 0.000 per scene;
      a drone 0: a grid over free flight is too large, and a drone ignores it).
    * ``search_steps``: the search's ``steps`` (:class:`~aes_planner.search.SearchConfig`) in
      every search of the planner node (the active loop's plannings and verifications, a passive
      node's suggestions). Unset: the preset's for the planner (``PLANNER_PRESETS``: ``balanced``
      25, where a one-shot ``suggest`` takes 20; the planner's explore pass also scores every
      partly covered view, a one-shot's the screen's best 8): with 20 steps the loop lost dev
      tabletop:210 (1.000 -> 0.878) and ``demo`` 0.93 -> 0.88 (docs/decisions.md).
    * ``far_moves`` / ``far_m`` / ``far_deg``: a drone only: at most ``far_moves`` moves to an
      unvisited view (no capture within ``far_m`` metres of its place looking within ``far_deg``
      of its way; 180: any way) whose capture did not beat the best captured view (a miss); after
      that many misses the moves go only to candidates near a capture. The field's prediction from a place nothing was captured at is its least
      trustworthy (dev tabletop:208@drone: the unvisited places it ranked first scored 0.37-0.59
      against a hope of 0.70-0.73, from places the exploration had visited looking other ways),
      and one such capture calibrates it before more moves go on its word. 30 deg: about two
      ``residual_length_deg``, beyond which the hope has no local correction. Unset: the
      platform's default (a drone 1, measured with ``plan_draws`` false on 39 dev drone runs:
      docs/decisions.md; a rig no limit: it never leaves its base).
    * ``plan_draws``: a drone only: the active loop's searches draw stage 1's neighbours and the
      coverage points at random from the search's ``seed`` (true, the preset's), or take both from
      a fixed low-discrepancy pattern (false; :class:`~aes_planner.search.SearchConfig`
      ``fixed_draws``), so that which views a planning sees does not depend on the seed. Unset:
      the platform's default (a drone false, with ``far_moves`` 1; a rig's loop searches draw
      nothing anyway, its ``plan_grid_deg``).
    * ``plan_adam_eps``: a drone only: Adam's epsilon in the active loop's stage 2
      (:class:`~aes_planner.search.SearchConfig` ``adam_eps``; the preset's 1e-8): with a larger
      one a nearly flat direction (a slope well below it) is not stepped a full ``lr`` each step,
      whose sign the last bits decide. Unset: the platform's default (the preset's).
    * ``tie_tolerance``: a capture displaces the best captured view (the polish's centre, the
      view settled on) only when it scored more than this higher (teacher units).
    * ``polish_coarse_gain``: at a polish step coarser than the finest, a neighbour displaces the
      climb's centre only when it scored more than this higher (teacher units; at the finest,
      ``tie_tolerance``): a neighbour a coarse step away on another, broader hill that is a hair
      better does not pull the climb off a narrow peak the centre sits next to -- the step halves
      and the finer steps find that peak. 0 = ``tie_tolerance`` at every step.
    * ``hope_quantum``: candidates are ranked by their hope rounded to this (teacher units), ties
      by where they look, so that near-equal predictions do not pick the move by their last bits
      (which differ between processors, backends and thread counts).
    * ``hope_tie_margin``: candidates whose hope is within this (teacher units) of the best are
      one tie with it, ranked by where they look: two hopes a thousandth apart on either side of a
      ``hope_quantum`` edge are not ranked by that edge (dev tabletop:217@drone: 0.751 / 0.752
      under numba, 0.753 / 0.752 under torch, and the first move went to the other place). 0 =
      the quanta alone. Unset: the platform's default (0 on both).
    * ``residual_length_m``: a drone only: the hope's correction by the errors at nearby captures
      (``residual_length_deg``) also weighs each capture by a Gaussian of this length (metres) on
      the distance between its place and the candidate's: a capture from across the box looking
      the same way shows other things and does not calibrate the view. Unset: the platform's
      default (None on both: the direction alone).
    * ``turns_one_by_one``: a drone only: the ``verify_turns`` captures are chosen one at a time,
      each by a hope calibrated also on the turns verified before it (the scorer's prediction of
      each against its capture), not all from the hopes before the first: the field's errors go by
      view direction, and one miss lowers the same way's hope at the other places. Unset: the
      platform's default (a drone true, measured on 39 dev drone runs: docs/decisions.md; a rig
      has no turns).
    * ``verify_places``: a drone only: the turn verifications may also look from the places of a
      lattice of the flight box (3 x 3 x 2 cells) that no capture was taken within ``far_m`` of,
      and this many more of them are taken (on top of ``verify_turns``): a good view from a place
      the loop never visited is otherwise never captured (dev tabletop:216@drone: the oracle looks
      57 deg down from 0.15 m below every capture's height). Unset: the platform's default (0 on
      both; docs/decisions.md).
    * ``settle_tolerance_deg``: a drone only: the settle's capture (the final view) is taken when
      the frame shows the best captured view within this angle (and ``arrival_tolerance_m``),
      tighter than ``arrival_tolerance_deg``; not held after half of ``move_timeout_s``, the frame
      then is taken as before (a warning). Unset: the platform's default (a drone 0.3; a rig's
      arrival waits for its joints to stand still).
    * ``survey_pitch_views``: a drone only: after the survey's turn in place (``explore_views``,
      pitched -10 / +5 deg), this many more captures from the start position at the ends of the
      search's pitch range (``pitch_limits_deg``), alternately the lower and the upper end, their
      yaws spread around the circle from the start's: a pitch band no capture looked at is rated
      poor by the field, and no verification goes there (dev s29_ground_drone: every good view looks
      60 deg down, no capture looked below -11 deg, the field scores the start's best view 0.16
      against truth 0.84). Unset: the platform's default (0 on both; a rig's exploration spans
      its tilt range). Measured on dev drones (docs/benchmarks.md, session 29): 6 lifted the 10
      hand-written s29 drones (0.937 -> 0.972 over base / noise / torch) but two procedural
      ones fell (tabletop:212 0.989 -> 0.826): not kept.
    * ``explore_below_covered`` / ``explore_moves``: when the search says its inputs cover less
      than this share of the space (the suggestion's ``covered_fraction``), the best predicted
      view is unverified where nothing was seen: before the loop stops on what it has (no
      candidate promises ``margin``), it spends up to ``explore_moves`` of its ``max_moves`` on
      the suggestion's exploratory candidate (``explore``: the edge of what was seen), and plans
      again with that capture in the field. 0 = never.
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
    * ``platform``: where the camera goes, a tagged mapping like a gimbal's ``device:``
      (:func:`~aes_planner.platform.parse_platform`): ``{type: rig, <the rig's kinematics and
      joint limits: PanTiltConfig keys>}`` or ``{type: drone, box: {bounds_min_m: [x, y, z],
      bounds_max_m: [x, y, z]}}``; ``{type: rig}`` / ``{type: drone}`` alone take the launch
      scene's rig / box (a drone on a rig scene: the box around the rig's base,
      :meth:`~aes_planner.platform.Platform.free_box`); none at all: the scene's platform.
      The older ``rig:`` / ``drone:`` / ``mode:`` keys are refused with how to rewrite them
      (docs/decisions.md, "One platform: mapping").
    * ``seed``: for the search's sampling.
    * ``threads``: CPU threads for the planner's torch and numba work (torch's count is
      process-wide); 0 = torch's default, all cores. 1 keeps a suggestion steady beside busy
      processes (``balanced``, 2 cores, one busy process beside: 0.86 s with 1 thread, 2.1 s with
      2; idle 0.76 s against 0.62 s; docs/benchmarks.md, "Threading layer").
    * ``adapt_threads``: with ``threads: 0``, let a :class:`~aes_planner.runtime.ThreadGovernor`
      try one thread when the suggestions do not get the cores (a busy neighbour), keep whichever
      count runs them faster, and probe all cores again now and then; diagnostics report
      ``threads``, ``cpu_efficiency`` and ``thread_changes``. Not on a simulated clock, where
      nothing may follow the load (docs/guides/clock.md).
    * ``photo_rank``: while a ``planner/request`` keeps a subject, rank the views that hold it by
      the teacher on the held frames warped into them
      (:class:`~aes_planner.search.framing.FramingConfig` ``photo_rank``, ``suggest --photo-rank``);
      about ten times the search time. Off by default.
    * ``flank_repeats``: after the flanks' pass (``flank_hills``), when the best capture came
      from it, up to this many times: one round at the coarsest polish step around the best
      capture (4 captures at most), then the flanks' pass again over that round's captures, all
      on top of ``polish_captures``. A flank climb starts a quarter of the coarsest step out, so
      no coarse round was ever taken around the top it reached, and a higher hill beyond a valley
      narrower than the coarsest step was never probed (dev photo_ring_room: the flank climb
      topped 0.762 at pan 76, the oracle 0.834 at pan 59 behind a valley at pan 67.5). Unset:
      the platform's default, 0 on both (a rig's 1 lifted that scene to 0.990 and changed no
      other dev rig's score, but failed its ship rule's spread condition: the scene's
      ``noise:1e-6`` run takes another path from the first move and stays 0.920; not measured
      on drones; docs/benchmarks.md, session 28).
    * ``shortfall_length_deg``: every hope the loop ranks by (moves, hill verifications) is
      lowered by its region's shortfall: at each move and hill verification the miss below its
      hope beyond ``SHORTFALL_SLACK`` (0.1), weighed by a Gaussian of this length (degrees) on
      the view direction (:func:`~aes_planner.node.captures.shortfall`). The field is refit on
      every capture and then predicts the captured views well while it may still over-rate the
      views around them: the hope's residual correction cannot see it (dev photo_ring_room: four
      moves into one corner, hoped 0.74-0.83, captured 0.48-0.71). 0: off. Unset: the
      platform's default, 0 on both (a rig's 30 lifted that scene to 1.000 under ``base``,
      ``noise:1e-6`` and ``torch``, but a single move's miss on a narrow peak's flank pushed
      dev tabletop:236 off its hill, 1.000 -> 0.880: its ship rule failed; docs/benchmarks.md,
      session 29). ``shortfall_gate``: the shortfall counts only where more than this many
      misses lie (Gaussian-weighted; scaled by ``clip(sum(w) - gate, 0, 1)``): 1 ignores a single
      miss, which is as often the flank of a narrow peak beside it. 0: no gate.
    * ``spare_gap``: when the loop would stop with moves left (no candidate promises ``margin``
      over the best captured view and no exploratory move is due), one more move to the
      best-ranked candidate whose hope lies within this gap (teacher units) below the best
      captured score or above it, and that no capture looks within ``spare_apart_deg`` (degrees)
      of: a prediction no capture verified is checked while the budget allows (dev tabletop:269
      stopped after two of four moves, its best remaining view promising 0.006 over the best
      capture, and settled 19 deg from the oracle). Planned again after it, so it may repeat up
      to ``max_moves``. Unset: the platform's default, a rig's 0.01 (dev tabletop:269 0.880 ->
      0.991 / 0.998 under ``base`` / ``noise:1e-6``; the other dev runs that stopped with moves
      left within 0.003), a drone's None (off, not measured; docs/benchmarks.md, session 29,
      "Moves left").
    """

    scorer: str = "field"
    preset: str = "balanced"
    teacher: str = "composition"
    active: bool = True
    explore_views: int = 6
    explore_positions: int = 4
    explore_places: int | None = None
    max_moves: int = 4
    margin: float = 0.01
    optimism: float = 1.0
    min_sigma: float = 0.02
    residual_length_deg: float = 15.0
    min_move_deg: float = 3.0
    min_move_m: float = 0.1
    polish_captures: int = 48
    polish_step_deg: float = 1.25
    polish_step_m: float = 0.0
    polish_scales: int = 4
    polish_fine_captures: int = 16
    polish_fine_gap: float = 0.01
    polish_starts: int = 3
    polish_start_gap: float = 0.1
    polish_hills: int = 5
    verify_hills: int = 2
    verify_turns: int | None = None
    spare_hills: int | None = None
    short_hills: int | None = None
    verify_apart_deg: float | None = None
    flank_hills: int | None = None
    flank_captures: int = 16
    verify_unseen: bool | None = None
    search_grid_points: int | None = None
    plan_grid_deg: float | None = None
    search_steps: int | None = None
    far_moves: int | None = None
    far_m: float = 0.3
    far_deg: float = 30.0
    plan_draws: bool | None = None
    plan_adam_eps: float | None = None
    tie_tolerance: float = 0.002
    polish_coarse_gain: float = 0.02
    hope_quantum: float = 0.005
    hope_tie_margin: float | None = None
    explore_below_covered: float = 0.9
    explore_moves: int = 1
    top_k: int = 3
    max_frames: int = 24
    arrival_tolerance_deg: float = 0.6
    arrival_tolerance_m: float = 0.05
    settle_s: float = 0.05
    move_timeout_s: float = 20.0
    max_stamp_ahead_s: float = MAX_STAMP_AHEAD_S
    fault_timeout_s: float = 10.0
    min_suggest_period_s: float = 0.5
    diagnostics_period_s: float = 1.0
    platform: dict | RigPlatformConfig | DronePlatformConfig | None = None
    seed: int = 0
    threads: int = 0
    adapt_threads: bool = True
    photo_rank: bool = False
    residual_length_m: float | None = None
    turns_one_by_one: bool | None = None
    flank_repeats: int | None = None
    verify_places: int | None = None
    settle_tolerance_deg: float | None = None
    shortfall_length_deg: float | None = None
    shortfall_gate: float = 0.0
    survey_pitch_views: int | None = None
    spare_gap: float | None = None
    spare_apart_deg: float = 10.0

    #: The keys ``platform:`` replaced, and how to rewrite each (read by :func:`~aes_planner.config.from_dict`).
    RETIRED_KEYS: ClassVar[dict[str, str]] = {
        "rig": "replaced by platform: write platform: {type: rig, <the rig's keys>} "
        "(with a YAML anchor: platform: {<<: *rig, type: rig}); docs/decisions.md",
        "drone": "replaced by platform: write platform: {type: drone, box: {bounds_min_m: [...], "
        "bounds_max_m: [...]}}; docs/decisions.md",
        "mode": "replaced by platform: write platform: {type: rig} or platform: {type: drone} "
        "(the scene's rig or box; drop the key for auto); docs/decisions.md",
    }

    def __post_init__(self):
        from aes_planner.search.scorers import SCORERS

        require(self.scorer in SCORERS, "scorer", f"must be {' or '.join(SCORERS)}, got {self.scorer!r}")
        from aes_planner.search.config import PRESETS, REMOVED_PRESETS

        require(
            self.preset not in REMOVED_PRESETS,
            "preset",
            f"{self.preset!r} was removed: {REMOVED_PRESETS.get(self.preset)}",
        )
        require(self.preset in PRESETS, "preset", f"must be {' or '.join(PRESETS)}, got {self.preset!r}")
        for name in (
            "explore_views",
            "explore_positions",
            "max_moves",
            "top_k",
            "max_frames",
            "threads",
            "polish_captures",
            "polish_fine_captures",
            "polish_scales",
            "polish_starts",
            "explore_moves",
            "polish_hills",
            "verify_hills",
            "flank_captures",
        ):
            v = getattr(self, name)
            require(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0, name, f"must be an integer >= 0, got {v!r}"
            )
        require_optional_int(self, "verify_turns", 16)
        require_optional_int(self, "verify_places", 16)
        require_optional_int(self, "survey_pitch_views", 16)
        if self.settle_tolerance_deg is not None:
            require_numbers(self, ("settle_tolerance_deg",))
            require(
                0.0 < self.settle_tolerance_deg <= 180.0,
                "settle_tolerance_deg",
                f"must be in (0, 180] degrees, or unset for the platform's default, got {self.settle_tolerance_deg}",
            )
        require_optional_int(self, "spare_hills", 16)
        require_optional_int(self, "short_hills", 16)
        require_optional_int(self, "flank_hills", 16)
        require_optional_int(self, "flank_repeats", 4)
        require(
            self.verify_apart_deg is None
            or (
                isinstance(self.verify_apart_deg, (int, float))
                and not isinstance(self.verify_apart_deg, bool)
                and math.isfinite(self.verify_apart_deg)
                and 0.0 < self.verify_apart_deg <= 90.0
            ),
            "verify_apart_deg",
            f"must be a number of degrees in (0, 90], or unset for the platform's default, got {self.verify_apart_deg!r}",
        )
        require_optional_int(self, "explore_places", 64)
        require_optional_int(self, "search_grid_points", 10_000)
        require_optional_bool(self, "verify_unseen")
        require(
            self.plan_grid_deg is None
            or (
                isinstance(self.plan_grid_deg, (int, float))
                and not isinstance(self.plan_grid_deg, bool)
                and (self.plan_grid_deg == 0 or 0.5 <= self.plan_grid_deg <= 45.0)
            ),
            "plan_grid_deg",
            f"must be 0 (the preset's random stage 1) or a spacing in [0.5, 45] degrees, or unset for the "
            f"platform's default, got {self.plan_grid_deg!r}",
        )
        require_optional_int(self, "search_steps", 10_000, "the preset's (PLANNER_PRESETS)")
        require_optional_int(self, "far_moves", 64, "the platform's default (no limit)")
        require_numbers(self, ("far_m",))
        require(self.far_m <= 10.0, "far_m", f"must be in (0, 10] metres, got {self.far_m}")
        require_numbers(self, ("far_deg",))
        require(self.far_deg <= 180.0, "far_deg", f"must be in (0, 180] degrees, got {self.far_deg}")
        require_optional_bool(self, "plan_draws")
        if self.plan_adam_eps is not None:
            require_numbers(self, ("plan_adam_eps",))
            require(self.plan_adam_eps <= 1.0, "plan_adam_eps", f"must be in (0, 1], got {self.plan_adam_eps}")
        if self.hope_tie_margin is not None:
            require_numbers(self, ("hope_tie_margin",), strict=False)
            require(
                self.hope_tie_margin <= 0.1,
                "hope_tie_margin",
                f"must be in [0, 0.1] (teacher units), got {self.hope_tie_margin}",
            )
        if self.residual_length_m is not None:
            require_numbers(self, ("residual_length_m",))
            require(
                self.residual_length_m <= 10.0,
                "residual_length_m",
                f"must be in (0, 10] metres, or unset for the platform's default, got {self.residual_length_m}",
            )
        require_optional_bool(self, "turns_one_by_one")
        require_numbers(self, ("shortfall_gate",), strict=False)
        require(self.shortfall_gate <= 10.0, "shortfall_gate", f"must be in [0, 10] misses, got {self.shortfall_gate}")
        if self.shortfall_length_deg is not None:
            require_numbers(self, ("shortfall_length_deg",), strict=False)
            require(
                self.shortfall_length_deg <= 180.0,
                "shortfall_length_deg",
                f"must be in [0, 180] degrees (0: off), or unset for the platform's default, got {self.shortfall_length_deg}",
            )
        require_numbers(self, ("spare_apart_deg",), strict=False)
        require(
            self.spare_apart_deg <= 180.0,
            "spare_apart_deg",
            f"must be in [0, 180] degrees, got {self.spare_apart_deg}",
        )
        if self.spare_gap is not None:
            require_numbers(self, ("spare_gap",), strict=False)
            require(
                self.spare_gap <= 1.0,
                "spare_gap",
                f"must be in [0, 1] teacher units, or unset for the platform's default (a rig 0.01, a drone off), got {self.spare_gap}",
            )
        require(self.top_k >= 1, "top_k", f"must be >= 1, got {self.top_k}")
        from aes_planner.messages.suggestion import MAX_CANDIDATES

        # a suggestion message holds at most MAX_CANDIDATES (more failed every publish)
        require(self.top_k <= MAX_CANDIDATES, "top_k", f"must be <= {MAX_CANDIDATES}, got {self.top_k}")
        for name, most in (
            ("explore_views", 64),
            ("explore_positions", 64),
            ("polish_captures", 64),
            ("polish_fine_captures", 64),
            ("polish_scales", 6),
            ("polish_starts", 8),
            ("explore_moves", 64),
            ("verify_hills", 16),
            ("polish_hills", 16),
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
        require_numbers(self, ("polish_step_m",), strict=False)
        require(self.polish_step_m <= 1.0, "polish_step_m", f"must be <= 1 (metres), got {self.polish_step_m}")
        require(self.polish_step_deg <= 30.0, "polish_step_deg", f"must be <= 30, got {self.polish_step_deg}")
        require(self.polish_scales >= 1, "polish_scales", f"must be >= 1, got {self.polish_scales}")
        require(self.polish_starts >= 1, "polish_starts", f"must be >= 1, got {self.polish_starts}")
        require_numbers(self, ("tie_tolerance", "hope_quantum", "polish_start_gap", "polish_coarse_gain"), strict=False)
        require_numbers(self, ("polish_fine_gap",), strict=False)
        require(
            self.polish_fine_gap <= 0.1,
            "polish_fine_gap",
            f"must be in [0, 0.1] (teacher units), got {self.polish_fine_gap}",
        )
        require(
            self.polish_coarse_gain <= 0.5,
            "polish_coarse_gain",
            f"must be in [0, 0.5] (teacher units), got {self.polish_coarse_gain}",
        )
        require_numbers(self, ("explore_below_covered",), strict=False)
        require(
            self.explore_below_covered <= 1.0,
            "explore_below_covered",
            f"must be in [0, 1] (a share of the space), got {self.explore_below_covered}",
        )
        require(
            self.tie_tolerance <= 0.1, "tie_tolerance", f"must be in [0, 0.1] (teacher units), got {self.tie_tolerance}"
        )
        require(
            self.hope_quantum <= 0.1, "hope_quantum", f"must be in [0, 0.1] (teacher units), got {self.hope_quantum}"
        )
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
        require(isinstance(self.photo_rank, bool), "photo_rank", f"must be true or false, got {self.photo_rank!r}")
        if self.platform is not None:
            self.platform = parse_platform(self.platform, "platform")

    @property
    def rig(self):
        """The rig's :class:`~aes_planner.geometry.rig.PanTiltConfig` when the platform names one, else None."""
        return self.platform.pan_tilt if isinstance(self.platform, RigPlatformConfig) else None

    @property
    def drone(self):
        """The drone's :class:`~aes_planner.platform.DroneBox` when the platform names one, else None."""
        return self.platform.box if isinstance(self.platform, DronePlatformConfig) else None
