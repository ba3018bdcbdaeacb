"""The field's unseen cells (``ScorerConfig.unseen_cells``): scored as the mean over the input
views' content at the same place in the frame, or as the decoder's own guess."""

import dataclasses

import pytest
import torch

from aes_planner.errors import AesPlannerError
from aes_planner.field import AestheticField, ScorerConfig
from aes_planner.field.model import MAX_UNSEEN_FILLS, FieldModel, FieldModelConfig, expected_terms
from aes_planner.teachers import get_teacher


@pytest.fixture(scope="module")
def teacher():
    return get_teacher("composition")


def _maps(seed: int, b: int) -> torch.Tensor:  # [b, 4, 16, 16]: teacher-map-like values
    g = torch.Generator().manual_seed(seed)
    return torch.rand(b, 4, 16, 16, generator=g) * torch.tensor([0.05, 0.02, 0.02, 0.01])[None, :, None, None]


def test_seen_cells_score_as_the_map_and_unseen_as_the_inputs(teacher):
    maps, fills = _maps(0, 3), _maps(1, 5)
    seen = expected_terms(teacher, maps, torch.ones(3, 1, 16, 16), fills)
    plain = teacher.explain_map(maps)
    assert seen.keys() == plain.keys()
    for k in plain:
        assert torch.allclose(seen[k], plain[k], atol=1e-6), k
    unseen = expected_terms(teacher, maps, torch.zeros(3, 1, 16, 16), fills)["score"]
    mean_of_inputs = teacher.head(fills).mean()
    assert torch.allclose(unseen, mean_of_inputs.expand(3), atol=1e-6)  # the maps' guess plays no part


def test_half_seen_view_is_scored_by_blends_not_by_the_mean_fill(teacher):
    maps, fills = _maps(2, 2), _maps(3, 4)
    alpha = torch.zeros(2, 1, 16, 16)
    alpha[..., :8] = 1.0  # the left half seen
    got = expected_terms(teacher, maps, alpha, fills)["score"]
    by_hand = torch.stack([teacher.head(torch.where(alpha.bool(), maps, f[None])) for f in fills]).mean(0)
    assert torch.allclose(got, by_hand, atol=1e-6)
    mean_fill = teacher.head(torch.where(alpha.bool(), maps, fills.mean(0, keepdim=True)))
    assert not torch.allclose(got, mean_fill, atol=1e-4)  # the head is not linear: the mean score differs


def test_many_inputs_fill_from_an_even_spread_of_them(teacher):
    maps, fills = _maps(4, 2), _maps(5, 3 * MAX_UNSEEN_FILLS)
    alpha = torch.full((2, 1, 16, 16), 0.4)
    got = expected_terms(teacher, maps, alpha, fills)["score"]
    picked = fills[torch.linspace(0, len(fills) - 1, MAX_UNSEEN_FILLS).round().long()]
    assert torch.allclose(got, expected_terms(teacher, maps, alpha, picked)["score"], atol=1e-7)


def test_gradient_reaches_the_maps_and_the_alpha(teacher):
    maps = _maps(6, 2).requires_grad_(True)
    alpha = torch.full((2, 1, 16, 16), 0.5, requires_grad=True)
    expected_terms(teacher, maps, alpha, _maps(7, 3))["score"].sum().backward()
    for t in (maps.grad, alpha.grad):
        assert torch.isfinite(t).all() and t.abs().sum() > 0


def test_unknown_setting_is_refused_by_name():
    with pytest.raises(AesPlannerError, match="unseen_cells"):
        ScorerConfig(unseen_cells="zeros")


@pytest.mark.slow  # builds a field: ~18 s on a loaded machine
def test_field_scores_far_views_from_its_inputs_and_near_ones_as_the_decoder(teacher, rig_frames):
    frames, poses = rig_frames
    torch.manual_seed(3)
    m = FieldModel(FieldModelConfig(embed_dim=4, hidden=8, encoder_channels=8), 4, (16, 16), "composition")
    cfg = ScorerConfig(render_width_px=32, max_gaussians=3000, unseen_cells="inputs")
    assert ScorerConfig().unseen_cells == "decoder"  # the default: the field as trained
    fld = AestheticField.build(frames, cfg, model=m, teacher=teacher)
    far = torch.as_tensor(poses[:1]).clone()
    far[0, :3, 3] += torch.tensor([1e4, -3e4, 50.0], dtype=torch.float64)  # nothing observed from there
    inputs_mode = fld.score(far)
    assert float(inputs_mode.coverage[0]) < 0.01
    assert abs(float(inputs_mode.score[0]) - float(teacher.head(fld.inputs.fmaps).mean())) < 1e-3
    near = torch.as_tensor(poses)
    fld.config = dataclasses.replace(cfg, unseen_cells="decoder")
    decoder_far, decoder_near = fld.score(far), fld.score(near)
    fld.config = cfg
    assert abs(float(decoder_far.score[0]) - float(inputs_mode.score[0])) > 1e-3  # the decoder's own guess
    near_out = fld.score(near)
    assert (near_out.coverage > 0.8).all()
    assert torch.allclose(near_out.score, decoder_near.score, atol=0.03)  # little unseen: nearly the same
