"""Helpers for node tests: a scripted proposer, frames, gimbal states."""

import math

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.pantilt import PanTilt, PanTiltConfig
from aes_planner.messages import Candidate, GimbalState, PosedFrame
from aes_planner.node.proposer import Proposal, Proposer

RIG = PanTiltConfig(base_xyz_m=(0.0, 0.0, 1.0), pan_limits_deg=(-90.0, 90.0), tilt_limits_deg=(-30.0, 30.0))
K = Intrinsics.from_fov(32, 24, 60.0)


class ScriptedProposer(Proposer):
    """Scores a view by a known function of its joints: a peak at (pan0, tilt0). For testing the
    planner's state machine, not a scorer anyone ships."""

    def __init__(self, rig=RIG, peak=(0.6, 0.2), candidates=None):
        self.rig = PanTilt(rig)
        self.peak = peak
        self.frames = []
        self.version = 0
        self.fixed = candidates
        self.calls = 0
        self.searches = []  # the search settings each call asked for

    def value(self, pan, tilt):
        return float(math.exp(-((pan - self.peak[0]) ** 2 + (tilt - self.peak[1]) ** 2) / 0.1))

    def add_frame(self, frame, keep=False):
        self.frames.append(frame)
        del self.frames[:-8]
        self.version += 1

    def reset(self):
        self.frames.clear()
        self.version += 1

    @property
    def size(self):
        return len(self.frames)

    def propose(self, platform, captured, top_k, keep_near=None, search=None):
        self.calls += 1
        self.searches.append(search)
        captured = np.asarray(captured).reshape(-1, 4, 4)
        pred = []
        for c2w in captured:
            d = c2w[:3, 2]
            pan, tilt = math.atan2(d[1], d[0]), math.asin(max(-1.0, min(1.0, d[2])))
            pred.append(self.value(pan, tilt))
        if self.fixed is not None:
            cands = self.fixed()
        else:
            g = self.rig.joint_grid(13, 7, margin=0.0)
            vals = [self.value(p, t) for p, t in g]
            order = np.argsort(vals)[::-1][:top_k]
            cands = [Candidate(self.rig.forward(*g[i]), vals[i], 1.0, float(g[i][0]), float(g[i][1])) for i in order]
        return Proposal(cands, np.asarray(pred), self.version)


class FakeTeacher:
    """Mean brightness as the score (captures are synthetic images)."""

    def score(self, images):
        return images.mean(dim=(1, 2, 3))


def frame_at(rig: PanTilt, pan, tilt, stamp, value=0.5, seq=0):
    img = np.full((K.height, K.width, 3), int(255 * value), np.uint8)
    return PosedFrame(img, K, rig.forward(pan, tilt), stamp, None, f"f{seq}", sequence=seq, pan_rad=pan, tilt_rad=tilt)


def state(pan, tilt, goal=None, moving=False, stamp=0.0, faults=(), status="ok"):
    gp, gt = goal if goal is not None else (pan, tilt)
    return GimbalState(pan, tilt, gp, gt, moving, (30.0, 30.0), tuple(faults), stamp, 0, status)


class SimRig:
    """A perfect gimbal + camera for stepping the planner core by hand: commands arrive instantly."""

    def __init__(self, proposer, rig=RIG):
        self.kin = PanTilt(rig)
        self.pan, self.tilt = 0.0, 0.0
        self.proposer = proposer
        self.commands = []
        self.seq = 0
        self.faults = ()

    def inputs(self, now):
        self.seq += 1
        v = self.proposer.value(self.pan, self.tilt)
        return {
            "gimbal/state": [
                state(self.pan, self.tilt, stamp=now, faults=self.faults, status="fault" if self.faults else "ok")
            ],
            "camera/frame": [frame_at(self.kin, self.pan, self.tilt, now, v, self.seq)],
        }

    def apply(self, out):
        for cmd in out.get("gimbal/command", []):
            self.commands.append(cmd)
            if not self.faults:
                self.pan, self.tilt = cmd.pan_rad, cmd.tilt_rad


def passive_sim_planner(scene: str = "tabletop:1"):
    """A passive planner on a sim scene's rig with a real search (RGB scoring, ``fast``), frames
    64 x 48: ``(source, node, kinematics)``."""
    from aes_planner.node.planner import PlannerConfig, PlannerNode
    from aes_planner.node.proposer import FieldProposer
    from aes_planner.platform import RigPlatformConfig
    from aes_planner.sim import SimSource
    from aes_planner.sim.camera import SimCameraConfig

    source = SimSource(scene, supersample=1, camera=SimCameraConfig(width=64, height=48, supersample=1))
    rig = source.scene.rig.pan_tilt
    node = PlannerNode(
        PlannerConfig(platform=RigPlatformConfig(rig), active=False, min_suggest_period_s=0.01),
        proposer=FieldProposer("rgb", "fast"),
        teacher=FakeTeacher(),
    )
    return source, node, PanTilt(rig)
