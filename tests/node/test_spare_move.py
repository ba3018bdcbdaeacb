"""A stop with moves left (``spare_gap``; a rig's default 0.01, a drone's off): before the loop stops on a prediction no capture
verified, one more move to the best-ranked candidate within the gap of the best capture that no
capture looks within ``spare_apart_deg`` of; nothing when the option is off or the moves are spent."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from aes_planner.config import ConfigError
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.messages import Candidate
from aes_planner.node.active_loop import ActiveLoop
from aes_planner.node.captures import Capture
from aes_planner.node.motion import DroneMotion, RigMotion
from aes_planner.node.planner import PlannerConfig


def pose(yaw_deg, pitch_deg=0.0):  # -> [4, 4], a rig's views share one place
    return view_to_cam2world(
        torch.tensor([0.0, 0.0, 1.4, math.radians(yaw_deg), math.radians(pitch_deg)], dtype=torch.float64)
    ).numpy()


def cand(yaw_deg, pitch_deg, score):
    return Candidate(pose(yaw_deg, pitch_deg), score, pan_rad=math.radians(yaw_deg), tilt_rad=math.radians(pitch_deg))


def loop(moves, setting=None, default=None):
    """The mixin's spare-move choice alone, with dev tabletop:269's captures after its two moves."""

    class Loop(ActiveLoop):
        config = PlannerConfig(spare_gap=setting)
        motion = SimpleNamespace(spare_gap=default, hope_tie_margin=0.0)
        node_id = "planner"

    out = Loop()
    out.moves = moves
    out.captures = [
        Capture("initial", pose(0.0), 0.665, 0.0),
        Capture("move", pose(33.3, 6.9), 0.771, 0.0, predicted=0.780),
        Capture("move", pose(52.5, 1.2), 0.584, 0.0),
    ]
    return out


# tabletop:269 after two moves: the best candidate 2.8 deg from move 1, the next 0.006 above the best
# capture (under margin 0.01) and far from every capture, then views hoping less than the gap allows
CANDS = [cand(30.5, 6.8, 0.736), cand(-3.1, -36.8, 0.721), cand(32.8, -9.9, 0.702), cand(-40.0, -10.0, 0.70)]
HOPE = np.array([0.783, 0.777, 0.753, 0.760])  # [C]
ORDER = [0, 1, 3, 2]


def test_a_stop_with_moves_left_spends_one_on_the_unverified_view_within_the_gap():
    target = loop(2, setting=0.01)._spare_target(CANDS, HOPE, ORDER, 0.771)
    assert target is not None and target.kind == "move"
    assert np.array_equal(target.cam2world, CANDS[1].cam2world)  # not CANDS[0]: 2.8 deg from move 1
    assert target.predicted == pytest.approx(0.777)
    # the platform's default reaches it when the config leaves it unset
    assert loop(2, default=0.01)._spare_target(CANDS, HOPE, ORDER, 0.771) is not None


def test_nothing_when_off_or_the_moves_are_spent_or_nothing_is_within_the_gap():
    assert loop(2)._spare_target(CANDS, HOPE, ORDER, 0.771) is None  # off (both unset)
    assert loop(2, setting=0.01, default=None)._spare_target(CANDS, HOPE, ORDER, 0.771) is not None
    assert loop(4, setting=0.01)._spare_target(CANDS, HOPE, ORDER, 0.771) is None  # max_moves 4 spent
    assert loop(2, setting=0.01)._spare_target(CANDS, HOPE, ORDER, 0.80) is None  # all below 0.80 - 0.01
    assert loop(2, setting=0.0)._spare_target(CANDS, HOPE, ORDER, 0.780) is None  # 0.777 < 0.780
    nan = np.array([0.783, math.nan, 0.753, 0.760])
    assert loop(2, setting=0.01)._spare_target(CANDS, nan, ORDER, 0.771) is None  # NaN never qualifies


def test_a_full_budget_never_reaches_the_spare_choice():
    """``_plan`` returns before searching once ``max_moves`` are spent, so a run that used all its
    moves takes main's path whatever ``spare_gap`` is."""
    node = loop(4, setting=0.01)
    node.config.max_moves = 4
    assert node._plan(0.0, {}) is None  # no search, no suggestion: it would fail on this bare loop


def test_on_for_a_rig_off_for_a_drone_by_default_and_bad_values_are_refused_by_name():
    assert RigMotion.spare_gap == 0.01 and DroneMotion.spare_gap is None  # a drone: main's path
    assert PlannerConfig().spare_gap is None and PlannerConfig().spare_apart_deg == 10.0
    for bad in (-0.01, math.nan, math.inf, 1.5, "0.01", True):
        with pytest.raises(ConfigError, match="spare_gap"):
            PlannerConfig(spare_gap=bad)
    for bad in (-1.0, 181.0, math.nan):
        with pytest.raises(ConfigError, match="spare_apart_deg"):
            PlannerConfig(spare_apart_deg=bad)
