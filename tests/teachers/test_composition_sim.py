"""The composition teacher on the simulator's own views: what a search maximising it would find."""

import numpy as np
import pytest
import torch

from aes_planner.teachers import CompositionTeacher

sim = pytest.importorskip("aes_planner.sim")


def rig_sweep(spec, n_pan=8, n_tilt=4):  # -> [N, 3, 96, 128]
    scene = sim.load_scene(spec)
    camera = sim.SimCamera(scene, sim.SimCameraConfig(width=128, height=96))
    views = [camera.capture_joints(float(p), float(t)).image for p, t in camera.kinematics.joint_grid(n_pan, n_tilt)]
    return torch.from_numpy(np.stack(views)).permute(0, 3, 1, 2).float() / 255


@pytest.mark.parametrize("spec", ["indoor:0", "outdoor:1", "tabletop:2", "gallery:3"])
def test_the_best_view_of_a_sweep_frames_something(spec):
    views = rig_sweep(spec)
    with torch.no_grad():
        e = CompositionTeacher().explain(views)
    best = int(e["score"].argmax())
    assert e["content"][best] > 0.9  # not a blank wall, floor or sky
    assert e["subject_size"][best] > 0.2  # there is a subject
    empty = e["content"] < 0.3
    if empty.any():  # featureless views sit at the bottom of the ranking
        assert e["score"][empty].max() < e["score"].median()
