"""The package's own gradients (the reconstruction's blending weights, the search's pose refinement)
work when a caller wraps it in ``torch.no_grad()`` or ``torch.inference_mode()``, with the same
results as without. Before, the reconstruction failed there and stage 2 silently took no steps."""

import numpy as np
import pytest
import torch

from aes_planner.field import AestheticField, ScorerConfig, build_scorer
from aes_planner.gaussians import autograd_on, numba_backend
from aes_planner.reconstruct import ReconstructConfig, reconstruct
from aes_planner.search import SearchConfig, search_views

MODES = {"no_grad": torch.no_grad, "inference_mode": torch.inference_mode}
CFG = SearchConfig.preset("fast", render_width_px=32, max_gaussians=3000, steps=6, lr=0.05)


def _suggest(kind, frames, poses, platform):
    scorer = build_scorer(kind, frames, render_width_px=CFG.render_width_px, max_gaussians=CFG.max_gaussians)
    return scorer, search_views(scorer, poses, platform, CFG)


@pytest.fixture(scope="module")
def plain(rig_source, rig_frames):
    """(scorer, result) of each kind, built and searched with autograd as torch starts."""
    frames, poses = rig_frames
    return {kind: _suggest(kind, frames, poses, rig_source.platform) for kind in ("field", "rgb")}


def _same(result, ref):
    assert result.best.score > result.best.stage1_score  # stage 2 stepped (under no_grad it took none)
    # equal up to the parallel backward's summation order (~1e-7 after the steps)
    np.testing.assert_allclose(result.best.cam2world, ref.best.cam2world, atol=1e-4)
    assert result.best.score == pytest.approx(ref.best.score, abs=1e-4)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("kind", ["field", "rgb"])
def test_build_and_search_under_a_callers_grad_mode(mode, kind, rig_source, rig_frames, plain):
    frames, poses = rig_frames
    ref_scorer, ref = plain[kind]
    with MODES[mode]():
        _same(search_views(ref_scorer, poses, rig_source.platform, CFG), ref)  # a scorer built outside
        scorer, result = _suggest(kind, frames, poses, rig_source.platform)
    _same(result, ref)
    # the scorer built under the mode differentiates outside it too
    p = torch.as_tensor(ref.best.cam2world[None]).clone().requires_grad_(True)
    scorer.score(p).score.sum().backward()
    assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0


@pytest.mark.parametrize("mode", MODES)
def test_reconstruct_under_a_callers_grad_mode(mode, rig_frames):
    frames, _ = rig_frames
    cfg = ReconstructConfig()
    ref = reconstruct(frames, cfg)
    with MODES[mode]():
        rec = reconstruct(frames, cfg)
    assert len(rec.gaussians) == len(ref.gaussians) > 0
    assert torch.equal(rec.gaussians.means, ref.gaussians.means)
    assert torch.equal(rec.gaussians.colors, ref.gaussians.colors)


def test_autograd_on_restores_the_callers_mode():
    x = torch.ones(3, requires_grad=True)
    with torch.inference_mode():
        with autograd_on():
            y = (x * 2).sum()
            assert y.requires_grad and not torch.is_inference_mode_enabled()
        assert torch.is_inference_mode_enabled()
    with torch.no_grad():
        with autograd_on():
            assert torch.is_grad_enabled()
        assert not torch.is_grad_enabled()
    (g,) = torch.autograd.grad(y, x)
    assert torch.equal(g, torch.full((3,), 2.0))


def test_warmup_under_no_grad():
    with torch.no_grad():
        assert numba_backend.warmup(torch.float32) >= 0.0


def test_field_grown_under_inference_mode_differentiates(rig_frames):
    frames, poses = rig_frames
    with torch.inference_mode():
        fld = AestheticField.load_default(config=ScorerConfig(render_width_px=32, max_gaussians=3000))
        for frame in frames:
            fld.add_frame(frame)
    p = torch.as_tensor(poses[:1]).clone().requires_grad_(True)
    fld.score(p).score.sum().backward()
    assert torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0
