"""Free mode (a drone): the planner publishes targets as suggestions, a SimDrone flies them, the
frames it sends close the loop; every target stays in the flight box."""

import math

import numpy as np
import torch

from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.messages import Candidate, PosedFrame
from aes_planner.node.planner import PlannerConfig, PlannerNode
from aes_planner.node.proposer import Proposal, Proposer
from aes_planner.node.sim_drone import SimDrone, SimDroneConfig
from aes_planner.platform import DroneBox, DronePlatformConfig

from .nodekit import FakeTeacher, K

BOX = DroneBox((-1.0, -1.0, 1.0), (1.0, 1.0, 2.0))
PEAK = np.array([0.5, -0.4, 1.5, 0.7, -0.1])  # the view the scripted scorer likes best


def value(c2w):
    v = np.asarray(cam2world_to_view(c2w))
    if v[0] > 2.0:  # the scripted scorer loves views outside the box: the planner must not fly there
        inside = view_to_cam2world(torch.as_tensor(np.r_[BOX.clamp(v[:3]), v[3:]])).numpy()
        return 1.5 + 0.5 * value(inside)  # over-estimates, not a tie the loop decides by its last bits
    d = np.linalg.norm(v[:3] - PEAK[:3]) ** 2 + (math.atan2(math.sin(v[3] - PEAK[3]), math.cos(v[3] - PEAK[3]))) ** 2
    return float(math.exp(-d / 0.5))


class FreeProposer(Proposer):
    def __init__(self):
        self.version, self.frames = 0, 0

    def add_frame(self, frame, keep=False):
        self.frames += 1
        self.version += 1

    def reset(self):
        self.frames = 0

    @property
    def size(self):
        return self.frames

    def propose(self, platform, captured, top_k, keep_near=None):
        rng = np.random.default_rng(self.version)
        views = rng.uniform([-3, -3, 0, -math.pi, -0.5], [3, 3, 3, math.pi, 0.5], (64, 5))  # some outside the box
        views[0] = PEAK
        views[1] = [5.0, 0.0, 1.5, 0.7, -0.1]  # outside the box, scored higher than anything
        poses = view_to_cam2world(torch.as_tensor(views)).numpy()
        vals = np.array([value(p) for p in poses])
        order = np.argsort(-vals)[:top_k]
        return Proposal(
            [Candidate(poses[i], vals[i]) for i in order], np.array([value(c) for c in captured]), self.version
        )


def test_free_loop_flies_to_better_views_inside_the_box():
    node = PlannerNode(
        PlannerConfig(
            platform=DronePlatformConfig(BOX), explore_views=3, max_moves=3, settle_s=0.0, arrival_tolerance_deg=1.0
        ),
        proposer=FreeProposer(),
        teacher=FakeTeacher(),
    )
    drone = SimDrone(BOX, SimDroneConfig(max_speed_m_s=3.0, max_yaw_rate_deg_s=360.0), [0, 0, 1.5, 0, 0])
    now, targets, kinds = 0.0, [], {}
    for _ in range(4000):
        c2w = drone.cam2world()
        img = np.full((K.height, K.width, 3), int(255 * value(c2w)), np.uint8)
        out = node.step({"camera/frame": [PosedFrame(img, K, c2w, now)]}, now)
        for s in out["planner/suggestion"]:
            kinds.setdefault(s.kind, []).append(s)
            if s.candidates:
                targets.append(s.candidates[0].cam2world)
                drone.set_target(s.candidates[0].view)
        drone.advance(0.02)
        now += 0.02
        if node.finished:
            break
    assert node.state == "done" and node.kind == "drone"
    assert node.captures[-1].kind == "settle"
    assert max(c.score for c in node.captures) > node.captures[0].score + 0.1
    for t in targets:
        assert BOX.contains(t[:3, 3])  # suggestions the loop flies are feasible
    # a consumer tells the drone's waypoints (one pose each) from search results
    assert kinds["waypoint"] and all(len(s.candidates) == 1 for s in kinds["waypoint"])
    assert kinds["search"] and set(kinds) == {"waypoint", "search"}
