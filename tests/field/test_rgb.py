"""RGB scoring: finite, differentiable scores and a coverage that knows what was observed."""

import numpy as np
import pytest
import torch

from aes_planner.field import RGBScorer, ScorerError, build_scorer


@pytest.fixture(scope="module")
def scorer(rig_frames):
    frames, _ = rig_frames
    return build_scorer("rgb", frames, render_width_px=32)


def test_scores_observed_views_with_the_teacher_and_full_coverage(scorer, rig_frames):
    _, poses = rig_frames
    out = scorer.score(torch.from_numpy(poses))
    assert out.score.shape == out.coverage.shape == (3,)
    assert torch.isfinite(out.score).all() and (out.coverage > 0.9).all()
    assert set(out.terms) >= {"score", "thirds", "content"}
    # the score is the teacher's score of the rendered image
    rgb, _ = scorer.render(torch.from_numpy(poses))
    assert torch.allclose(out.score, scorer.teacher.score(rgb), atol=1e-6)


def test_looking_away_has_low_coverage_and_finite_gradients(scorer, rig_frames):
    _, poses = rig_frames
    back = poses[1].copy()
    back[:3, :3] = back[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # turned 180 degrees about the camera's y
    p = torch.from_numpy(np.stack([poses[1], back])).requires_grad_(True)
    out = scorer.score(p)
    out.score.sum().backward()
    assert out.coverage[1] < 0.05 < out.coverage[0]
    assert torch.isfinite(p.grad).all() and p.grad[0].abs().sum() > 0


def test_world_frame_precision_far_from_the_origin(rig_frames):
    # the same scene shifted 1e6 m away scores the same (local frame + float64 at the boundary)
    frames, poses = rig_frames
    from dataclasses import replace

    shift = np.eye(4)
    shift[:3, 3] = [1e6, -2e6, 30.0]
    far = [replace(f, cam2world=shift @ f.cam2world) for f in frames]
    a = build_scorer("rgb", frames, render_width_px=32).score(torch.from_numpy(poses)).score
    b = build_scorer("rgb", far, render_width_px=32).score(torch.from_numpy(shift @ poses)).score
    assert torch.allclose(a, b, atol=1e-4)


def test_bad_input_is_refused_with_a_clear_error(scorer):
    with pytest.raises(ScorerError, match="4, 4"):
        scorer.score(torch.eye(4, dtype=torch.float64))
    with pytest.raises(ScorerError, match="kind"):
        build_scorer("nope", [])
    with pytest.raises(ScorerError, match="unknown knobs"):
        build_scorer("rgb", [], widht=3)
    with pytest.raises(ScorerError, match="no frames"):
        RGBScorer.build([])
