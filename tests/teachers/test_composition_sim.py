"""The composition teacher on the simulator's own views: what a search maximising it would find."""

import numpy as np
import pytest
import torch

from aes_planner.bench.teachers import subject_metrics, subject_views
from aes_planner.teachers import CompositionTeacher

sim = pytest.importorskip("aes_planner.sim")


def rig_sweep(spec, n_pan=8, n_tilt=4):  # -> [N, 3, 72, 96]
    scene = sim.load_scene(spec)
    camera = sim.SimCamera(scene, sim.SimCameraConfig(width=96, height=72))
    views = [camera.capture_joints(float(p), float(t)).image for p, t in camera.kinematics.joint_grid(n_pan, n_tilt)]
    return torch.from_numpy(np.stack(views)).permute(0, 3, 1, 2).float() / 255


@pytest.mark.parametrize("spec", ["indoor:0", "outdoor:1", "tabletop:2", "gallery:3"])
def test_the_best_view_of_a_sweep_frames_something(spec):
    views = rig_sweep(spec)
    with torch.no_grad():
        e = CompositionTeacher().explain(views)
    best = int(e["score"].argmax())
    assert e["content"][best] > 0.9  # not a blank wall, floor or sky
    assert e["subject_presence"][best] > 0.8  # there is a subject (a small painting will do)
    empty = e["content"] < 0.3
    if empty.any():  # featureless views sit at the bottom of the ranking
        assert e["score"][empty].max() < e["score"].median()


def test_views_of_subjects_beat_views_of_bare_structure_and_texture():
    # 136 random rig views of 8 scenes (seeds that neither the bench nor the tuning used), at
    # 80x60. On them the teacher before subject presence, colour distinctiveness and isolation
    # preferred the subject view in 60 % of the 253 same-scene pairs and in 37 % of the 126
    # against checker/stripe views; now in 91 % and 87 % (the bench's 1619 pairs of seeds 0-4:
    # 88 % and 81 %; 960 views of unseen seeds 200-204: 92 % and 86 %). The thresholds sit
    # several points under all of these and far above the old teacher.
    views = subject_views(seeds=(10, 11), random_views=16, sweep=None, width=80, height=60)
    with torch.no_grad():
        scores = CompositionTeacher().score(torch.stack(views.images)).numpy()
    m = subject_metrics(scores, views)
    assert m["subject_pairs"] > 200 and m["subject_pairs_texture"] > 100
    assert m["subject_pref_acc"] > 0.8
    assert m["subject_pref_acc_texture"] > 0.7
