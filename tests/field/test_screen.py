"""The field's stage-1 screen (``score_screened``): the splatted teacher map ranks, the decoder
scores only the ``keep`` best, and what it scores equals ``score_batched``."""

import contextlib

import numpy as np
import pytest
import torch

from aes_planner.field import AestheticField, ScorerConfig, ScorerError
from aes_planner.field.model import FieldModel, FieldModelConfig
from aes_planner.field.scorer import ScoreOutput, Scorer
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.teachers import get_teacher

CFG = ScorerConfig(render_width_px=32, max_gaussians=3000)


@pytest.fixture(scope="module")
def field(rig_frames):
    torch.manual_seed(2)
    m = FieldModel(FieldModelConfig(embed_dim=4, hidden=8, encoder_channels=8), 4, (16, 16), "composition")
    with torch.no_grad():  # a trained-looking correction: screen and decoder disagree
        m.out.weight.normal_(0, 0.3)
        m.out.bias.normal_(0, 0.1)
    return AestheticField.build(rig_frames[0], CFG, model=m, teacher=get_teacher("composition"))


@pytest.fixture(scope="module")
def poses(rig_source):
    pt = PanTilt(rig_source.platform.rig)
    pan, tilt = np.meshgrid(np.radians(np.linspace(-40, 40, 6)), np.radians(np.linspace(-30, 10, 3)))
    return torch.as_tensor(np.stack([pt.forward(p, t) for p, t in zip(pan.ravel(), tilt.ravel())]))  # [18, 4, 4]


@contextlib.contextmanager
def _counting_decoder(field):
    """Yields a list that gets the batch size of every decoder call in the block."""
    decoded = []
    decode = field.model.decode_pooled

    def counting(x):
        decoded.append(len(x))
        return decode(x)

    field.model.decode_pooled = counting
    try:
        yield decoded
    finally:
        del field.model.decode_pooled


def _rank(out):
    return out.score - 2.0 * (0.7 - out.coverage.to(out.score.dtype)).clamp_min(0.0)


def test_the_kept_are_the_screens_best_and_scored_as_score_batched(field, poses):
    full = field.score_batched(poses, 64)
    with _counting_decoder(field) as decoded:
        out, exact = field.score_screened(poses, 4, 5, _rank)  # batches of 4: the kept set carried across
    assert sum(decoded) == 5 and int(exact.sum()) == 5  # the decoder saw the 5 kept poses, no more
    assert torch.allclose(out.score[exact], full.score[exact], atol=1e-5)
    assert torch.equal(out.coverage, full.coverage)
    for k in full.terms:
        assert torch.allclose(out.terms[k][exact], full.terms[k][exact], atol=1e-5)
    # the kept are the 5 best by the screen: the splatted map alone (the decoder's correction off)
    screen = _rank(out)  # the screen's own scores where not exact; recompute them where exact
    out_w, out_b = field.model.out.weight.clone(), field.model.out.bias.clone()
    with torch.no_grad():
        field.model.out.weight.zero_()
        field.model.out.bias.zero_()
        splat = _rank(field.score_batched(poses, 64))
        field.model.out.weight.copy_(out_w)
        field.model.out.bias.copy_(out_b)
    assert torch.allclose(screen[~exact], splat[~exact], atol=1e-5)
    assert set(torch.argsort(splat, descending=True)[:5].tolist()) == set(torch.nonzero(exact).flatten().tolist())
    assert not torch.allclose(full.score, splat.to(full.score.dtype), atol=1e-3)  # the screen is not the field


def test_eligible_poses_are_kept_first(field, poses):
    eligible = torch.zeros(len(poses), dtype=torch.bool)
    eligible[[1, 7, 16]] = True
    _, exact = field.score_screened(poses, 64, 5, _rank, eligible)
    assert exact[[1, 7, 16]].all() and int(exact.sum()) == 5
    with pytest.raises(ScorerError, match="eligible"):
        field.score_screened(poses, 64, 5, _rank, eligible[:3])


def test_keep_beyond_the_batch_scores_everything_exactly(field, poses):
    out, exact = field.score_screened(poses, 64, len(poses), _rank)
    assert exact.all()
    assert torch.allclose(out.score, field.score_batched(poses, 64).score, atol=1e-6)
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ScorerError, match="keep"):
            field.score_screened(poses, 64, bad, _rank)


class _Height(Scorer):
    """A scorer without a screen: the camera's height."""

    def score(self, cam2world):
        return ScoreOutput(cam2world[:, 2, 3].float(), torch.ones(len(cam2world)), {})


def test_a_scorer_without_a_screen_scores_every_pose(poses):
    scorer = _Height()
    out, exact = scorer.score_screened(poses, 4, 3, _rank)
    assert exact.all() and torch.equal(out.score, scorer.score_batched(poses, 4).score)


def test_score_where_decodes_only_the_picked_poses(field, poses):
    """The explore pass's score_where: every pose's coverage, the decoder on the picked ones only,
    and their scores those of score_batched."""
    full = field.score_batched(poses, 64)

    def middle(coverage):  # a pick that depends on the coverage, as the explore pass's does
        return (coverage > 0.2) & (coverage < 0.9)

    with _counting_decoder(field) as decoded:
        out, exact = field.score_where(poses, 5, middle)  # batches of 5: 18 poses in 4 batches
    want = middle(full.coverage)
    assert 0 < int(want.sum()) < len(poses)  # the case picks some, not all
    assert torch.equal(exact, want) and sum(decoded) == int(want.sum())
    assert torch.equal(out.coverage, full.coverage)
    assert torch.allclose(out.score[exact], full.score[exact], atol=1e-5)
    for k in full.terms:
        assert torch.allclose(out.terms[k][exact], full.terms[k][exact], atol=1e-5)
    with pytest.raises(ScorerError, match="which"):
        field.score_where(poses, 5, lambda c: torch.ones(2, dtype=torch.bool))


def test_a_scorer_without_a_screen_scores_every_pose_where_asked(poses):
    scorer = _Height()
    out, exact = scorer.score_where(poses, 4, lambda c: torch.zeros(len(c), dtype=torch.bool))
    assert exact.all() and torch.equal(out.score, scorer.score_batched(poses, 4).score)


def test_cached_rays_first_made_under_inference_mode_still_differentiate(field, poses):
    """The unit rays are computed once per camera and cached: made first inside a caller's
    inference_mode, they are still normal tensors that the pose gradient can save."""
    from aes_planner.field.model import _unit_rays

    _unit_rays.cache_clear()
    with torch.inference_mode():
        field.score(poses[:2])
    p = poses[:2].clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(field.score(p).score.sum(), p)
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0
