"""A search suggestion says what the inputs cover and carries an exploratory candidate
(``ViewSuggestion`` schema 3), checked as the ranked candidates are before it is published."""

from __future__ import annotations

import math

import numpy as np

from aes_planner.messages import Candidate, ViewSuggestion, decode, encode
from aes_planner.node.planner import PlannerConfig, PlannerNode
from aes_planner.node.proposer import FieldProposer, Proposal
from aes_planner.platform import RigPlatformConfig
from aes_planner.sim import SimSource
from aes_planner.sim.camera import SimCameraConfig

from .nodekit import RIG, FakeTeacher, ScriptedProposer, frame_at


class ExploringProposer(ScriptedProposer):
    """The scripted peak, plus a coverage figure and an exploratory candidate at given joints."""

    def __init__(self, explore_joints, covered=0.4):
        super().__init__()
        self.explore_joints, self.covered = explore_joints, covered

    def propose(self, platform, captured, top_k, keep_near=None):
        p = super().propose(platform, captured, top_k, keep_near)
        pan, tilt = self.explore_joints
        explore = Candidate(self.rig.forward(pan, tilt), 0.2, 0.1, pan, tilt)
        return Proposal(p.candidates, p.captured_pred, p.field_version, self.covered, explore)


def _passive(proposer):
    cfg = PlannerConfig(platform=RigPlatformConfig(RIG), settle_s=0.0, active=False, min_suggest_period_s=0.01)
    return PlannerNode(cfg, proposer=proposer, teacher=FakeTeacher())


def test_a_suggestion_carries_the_coverage_and_the_exploratory_candidate(rig):
    node = _passive(ExploringProposer((-1.2, 0.3), covered=0.4))
    out = node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 1.0)]}, 1.0)
    (msg,) = out["planner/suggestion"]
    assert msg.covered_fraction == 0.4
    assert msg.explore is not None and math.isclose(msg.explore.pan_rad, -1.2)
    back = decode(encode(msg))  # on the wire as well
    assert back.covered_fraction == 0.4 and np.array_equal(back.explore.cam2world, msg.explore.cam2world)


def test_an_exploratory_candidate_beyond_the_joint_limits_is_refused_not_sent(rig):
    node = _passive(ExploringProposer((math.radians(120.0), 0.0)))  # the rig pans to +-90 deg
    out = node.step({"camera/frame": [frame_at(rig, 0.0, 0.0, 1.0)]}, 1.0)
    (msg,) = out["planner/suggestion"]
    assert msg.explore is None and msg.candidates, "the ranked candidates still go"
    assert node.counters["commands_refused"] >= 1


def test_a_field_search_measures_what_its_inputs_cover():
    """A real search (RGB scorer, fast preset) on four frames of one side of a sim scene: the
    share covered is measured, below 1 on a rig that can turn away from them, and the exploratory
    candidate (offered since part of the range is uncovered) lies inside the joint limits."""
    source = SimSource("tabletop:1", supersample=1, camera=SimCameraConfig(width=64, height=48, supersample=1))
    rig = source.scene.rig.pan_tilt
    node = PlannerNode(
        PlannerConfig(platform=RigPlatformConfig(rig), active=False, min_suggest_period_s=0.01),
        proposer=FieldProposer("rgb", "fast"),
        teacher=FakeTeacher(),
    )
    from aes_planner.geometry.pantilt import PanTilt

    kin = PanTilt(rig)
    lo, hi = (math.radians(v) for v in rig.pan_limits_deg)
    pans = np.linspace(lo, lo + 0.2 * (hi - lo), 4)  # one fifth of the pan range seen
    out = {}
    for i, pan in enumerate(pans):
        out = node.step({"camera/frame": [source.capture(kin.forward(pan, 0.0), stamp_s=1.0 + i)]}, 1.0 + i)
    msg: ViewSuggestion = out["planner/suggestion"][-1]
    assert msg.covered_fraction is not None and 0.0 <= msg.covered_fraction < 1.0
    assert msg.explore is not None, "part of the range is not covered: an exploratory candidate is offered"
    assert lo - 1e-9 <= msg.explore.pan_rad <= hi + 1e-9
    assert np.isfinite(msg.explore.cam2world).all()
