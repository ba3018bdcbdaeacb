"""A search suggestion says what the inputs cover and carries an exploratory candidate
(``ViewSuggestion`` schema 3), checked as the ranked candidates are before it is published."""

from __future__ import annotations

import math

import numpy as np

from aes_planner.messages import Candidate, ViewSuggestion, decode, encode
from aes_planner.node.planner import PlannerConfig, PlannerNode
from aes_planner.node.proposer import Proposal
from aes_planner.platform import RigPlatformConfig

from .nodekit import RIG, FakeTeacher, ScriptedProposer, SimRig, frame_at, passive_sim_planner


class ExploringProposer(ScriptedProposer):
    """The scripted peak, plus a coverage figure and an exploratory candidate at given joints."""

    def __init__(self, explore_joints, covered=0.4):
        super().__init__()
        self.explore_joints, self.covered = explore_joints, covered

    def propose(self, platform, captured, top_k, keep_near=None, search=None):
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
    source, node, kin = passive_sim_planner("tabletop:1")
    rig = source.scene.rig.pan_tilt
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


class SightProposer(ScriptedProposer):
    """A field that knows only what its captures saw: a view within ``seen_deg`` of a capture (in
    pan) is covered and predicted right, one within ``2 * seen_deg`` partly; the candidates are the
    covered views (1-deg grid, tilt 0), best first; the exploratory candidate the best partly
    covered view, with the share of a 1-deg grid that is covered -- what ``search_views`` says."""

    def __init__(self, peaks, seen_deg=20.0):
        super().__init__()
        self.peaks, self.seen_deg = peaks, seen_deg  # [(pan_deg, height, width_deg)]

    def value(self, pan, tilt):
        d = math.degrees(pan)
        return max(h * math.exp(-(((d - p) / w) ** 2)) for p, h, w in self.peaks) * math.exp(-(tilt**2) / 0.1)

    def propose(self, platform, captured, top_k, keep_near=None, search=None):
        seen = [math.degrees(math.atan2(c[1, 2], c[0, 2])) for c in np.asarray(captured).reshape(-1, 4, 4)]
        grid = np.arange(-90.0, 90.5, 1.0)
        near = np.array([min(abs(g - s) for s in seen) for g in grid])
        covered, partly = grid[near <= self.seen_deg], grid[(near > self.seen_deg) & (near <= 2 * self.seen_deg)]

        def cand(pan_deg):
            pan = math.radians(float(pan_deg))
            return Candidate(self.rig.forward(pan, 0.0), self.value(pan, 0.0), 1.0, pan, 0.0)

        cands = sorted((cand(g) for g in covered), key=lambda c: -c.score)[:top_k]
        explore = max((cand(g) for g in partly), key=lambda c: c.score, default=None)
        pred = np.array([self.value(math.radians(s), 0.0) for s in seen])
        return Proposal(cands, pred, self.version, len(covered) / len(grid), explore)


def _loop_on(proposer, **kw):
    from .test_planner_core import drive

    cfg = PlannerConfig(
        platform=RigPlatformConfig(RIG), settle_s=0.0, explore_views=0, polish_captures=0, max_moves=4, **kw
    )
    node = PlannerNode(cfg, proposer=proposer, teacher=FakeTeacher())
    drive(node, SimRig(proposer))
    assert node.state == "done"
    return node


def test_a_loop_goes_to_the_best_view_in_an_unseen_part_of_the_pan_range_within_4_moves():
    """The camera starts on a small hill (pan 0); the best view (pan 75 deg) lies where no capture
    looked. Nothing seen promises a gain, so the loop takes the exploratory candidate at the edge of
    what it saw, and from there climbs to the peak: within 4 moves, and settled on it."""
    prop = SightProposer([(0.0, 0.5, 10.0), (75.0, 1.0, 20.0)])
    node = _loop_on(prop)
    assert node.explored == 1 and node.moves <= 4
    moves = [c for c in node.captures if c.kind == "move"]
    assert any(abs(math.degrees(c.pan_rad) - 75.0) <= 3.0 for c in moves), [math.degrees(c.pan_rad) for c in moves]
    assert abs(math.degrees(node.captures[-1].pan_rad) - 75.0) <= 3.0, "it settles on the peak"
    assert node.captures[-1].score > 0.9


def test_without_exploring_the_loop_stops_on_the_hill_it_started_on():
    """The same scene with ``explore_below_covered: 0``: nothing seen promises a gain and the loop
    stops where it started (the behaviour the exploratory candidate fixes)."""
    prop = SightProposer([(0.0, 0.5, 10.0), (75.0, 1.0, 20.0)])
    node = _loop_on(prop, explore_below_covered=0.0)
    assert node.explored == 0
    assert node.captures[-1].score < 0.6


def test_a_covered_space_is_not_explored():
    """Every view seen (coverage above the threshold): the exploratory candidate is not taken."""
    prop = SightProposer([(0.0, 0.5, 10.0), (75.0, 1.0, 20.0)], seen_deg=200.0)
    node = _loop_on(prop)
    assert node.explored == 0
    assert abs(math.degrees(node.captures[-1].pan_rad) - 75.0) <= 3.0, "the field saw the peak and went there"
