"""The aesthetic field: finite, differentiable scores in every corner case, incremental updates,
checkpoints that load without pickle."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from aes_planner.field import AestheticField, ScorerConfig, ScorerError
from aes_planner.field.model import (
    FieldModel,
    FieldModelConfig,
    ModelError,
    load_model,
    read_checkpoint,
    write_checkpoint,
)
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.sim import SimCameraConfig, SimSource
from aes_planner.teachers import get_teacher

CFG = ScorerConfig(render_width_px=32, max_gaussians=3000)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(1)
    m = FieldModel(FieldModelConfig(embed_dim=4, hidden=8, encoder_channels=8), 4, (16, 16), "composition")
    with torch.no_grad():  # a trained-looking correction (the shipped init is zero)
        m.out.weight.normal_(0, 0.05)
    return m


@pytest.fixture(scope="module")
def teacher():
    return get_teacher("composition")


def _check(fld, poses):
    p = torch.as_tensor(poses, dtype=torch.float64).clone().requires_grad_(True)
    out = fld.score(p)
    out.score.sum().backward()
    assert torch.isfinite(out.score).all() and torch.isfinite(p.grad).all()
    assert ((out.coverage >= 0) & (out.coverage <= 1)).all()
    return out, p.grad


def test_scores_are_finite_everywhere(model, teacher, rig_frames):
    frames, poses = rig_frames
    fld = AestheticField.build(frames, CFG, model=model, teacher=teacher)
    centre = poses[1][:3, 3]
    views = np.array(
        [
            [*centre, 0.3, np.pi / 2],  # pole: straight up
            [*centre, -0.3, -np.pi / 2],  # pole: straight down
            [*(centre + [1e4, -3e4, 50.0]), 1.0, 0.0],  # far outside the observed region
            [*(centre + [0.0, 0.0, -1.15]), 0.0, -0.2],  # at the floor, inside geometry
        ]
    )
    out, _ = _check(fld, view_to_cam2world(views))
    assert out.coverage[2] < 0.05  # nothing observed from 30 km away
    out, grad = _check(fld, poses)
    assert (out.coverage > 0.8).all() and grad.abs().sum() > 0


def test_single_identical_and_no_views(model, teacher, rig_frames):
    frames, poses = rig_frames
    for fs in ([frames[0]], [frames[0], frames[0]]):
        out, _ = _check(AestheticField.build(fs, CFG, model=model, teacher=teacher), poses)
        assert out.coverage[0] > 0.8
    empty = AestheticField.build([], CFG, model=model, teacher=teacher)
    out, _ = _check(empty, poses)
    assert len(empty) == 0 and (out.coverage == 0).all()


def test_score_batched_equals_score_and_refuses_bad_batches(model, teacher, rig_frames):
    frames, poses = rig_frames
    fld = AestheticField.build(frames, CFG, model=model, teacher=teacher)
    p = torch.as_tensor(poses)
    whole, chunked = fld.score(p), fld.score_batched(p, batch_size=2)
    assert torch.allclose(whole.score, chunked.score, atol=1e-6)
    assert torch.allclose(whole.coverage, chunked.coverage, atol=1e-6)
    assert whole.terms.keys() == chunked.terms.keys()
    for bad in (0, -3, 1.5, True):
        with pytest.raises(ScorerError, match="batch_size"):
            fld.score_batched(p, batch_size=bad)
    with pytest.raises(ScorerError, match="empty batch"):
        fld.score_batched(p[:0])
    with pytest.raises(ScorerError, match="torch.Tensor"):
        fld.score_batched(poses)


def test_frames_of_another_size_are_refused_and_the_field_kept(model, teacher, rig_frames):
    frames, poses = rig_frames
    small = SimSource("tabletop:5", camera=SimCameraConfig(width=32, height=24, supersample=1)).capture(poses[1])
    with pytest.raises(ScorerError, match=r"frames\[1\] is 32x24 px but frames\[0\] is 64x48"):
        AestheticField.build([frames[0], small], CFG, model=model, teacher=teacher)
    fld = AestheticField.build(frames, CFG, model=model, teacher=teacher)
    before, version = fld.score(torch.as_tensor(poses)).score, fld.version
    with pytest.raises(ScorerError, match="one size"):
        fld.add_frame(small)
    assert fld.version == version and len(fld._frames) == len(frames)
    assert torch.equal(fld.score(torch.as_tensor(poses)).score, before)


def test_gradient_matches_finite_differences(model, teacher, depth_frames):
    frames, poses = depth_frames
    fld = AestheticField.build(frames, CFG, model=model, teacher=teacher)
    p0 = torch.from_numpy(poses[:1])
    _, grad = _check(fld, p0)
    direction = torch.zeros(1, 4, 4, dtype=torch.float64)
    direction[0, :3, 3] = torch.tensor([0.3, -0.4, 0.2])  # a translation
    eps = 5e-3
    with torch.no_grad():
        fd = (fld.score(p0 + eps * direction).score - fld.score(p0 - eps * direction).score) / (2 * eps)
    analytic = float((grad * direction).sum())
    assert abs(analytic - float(fd)) <= 0.15 * abs(float(fd)) + 2e-3


def test_add_frame_bumps_version_and_keeps_memory_bounded(model, teacher, rig_source):
    from aes_planner.geometry.pantilt import PanTilt

    cfg = ScorerConfig(render_width_px=32, max_gaussians=800)
    fld = AestheticField.build([], cfg, model=model, teacher=teacher)
    pt = PanTilt(rig_source.platform.rig)
    versions, sizes = [fld.version], []
    for pan in np.radians([-30, -10, 10, 30, 50, 10, -10]):
        fld.add_frame(rig_source.capture(pt.forward(pan, 0.0), depth=False))
        versions.append(fld.version)
        sizes.append(len(fld))
    assert all(b > a for a, b in zip(versions, versions[1:]))
    assert max(sizes) <= 800 and len(fld._frames) <= 7
    with pytest.raises(ScorerError, match="PosedFrame"):
        fld.add_frame("not a frame")


def test_checkpoint_round_trip_without_pickle(model, tmp_path):
    path = write_checkpoint(tmp_path / "m.npz", model.checkpoint({"note": "test"}))
    loaded = load_model(path)
    for (k, a), b in zip(model.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a, b) and a.dtype == b.dtype, k
    assert read_checkpoint(path)["note"] == "test"
    write_checkpoint(tmp_path / "bad.npz", {"format": 99})
    with pytest.raises(ModelError, match="format"):
        load_model(tmp_path / "bad.npz")
    with pytest.raises(ModelError, match="does not exist"):
        load_model(tmp_path / "missing.npz")


@pytest.mark.parametrize("zip_format", [True, False])
def test_old_torch_checkpoint_is_refused_unread(model, tmp_path, request, zip_format):
    old = tmp_path / "model.pt"
    torch.save(model.checkpoint(), old, _use_new_zipfile_serialization=zip_format)
    request.getfixturevalue("no_unpickling")
    with pytest.raises(ModelError, match=r"older aes-planner in torch's pickle-based format.*aes-planner train"):
        load_model(old)


def test_packaged_checkpoints_load():
    from aes_planner.field.model import DEFAULT_CHECKPOINT, NOCOND_CHECKPOINT

    assert DEFAULT_CHECKPOINT.endswith(".npz") and NOCOND_CHECKPOINT.endswith(".npz")
    on, off = load_model(), load_model(NOCOND_CHECKPOINT)
    assert on.config.condition and not off.config.condition


def test_teacher_mismatch_is_refused(model):
    other = FieldModel(FieldModelConfig(embed_dim=4), 4, (16, 16), "someone-else")
    with pytest.raises(ModelError, match="teacher"):
        AestheticField(other, get_teacher("composition"), None, CFG)


def test_pointwise_matches_the_convolutions_in_values_and_gradients(model):
    from aes_planner.field.model import pointwise

    x = torch.randn(3, model.pixel[0].in_channels, 6, 5, dtype=torch.float64, requires_grad=True)
    layers = model.pixel.double()
    try:
        fast, plain = pointwise(layers, x), layers(x)
        torch.testing.assert_close(fast, plain)
        g_fast, g_plain = (torch.autograd.grad((y * y).sum(), x)[0] for y in (fast, plain))
        torch.testing.assert_close(g_fast, g_plain)
    finally:
        layers.float()


def _plain_decode(m, rendered, alpha, cond):  # the decoder written with the modules as declared: its reference
    fh, fw = m.feature_size
    x = F.adaptive_avg_pool2d(torch.cat([rendered, alpha[:, None], cond], 1), (2 * fh, 2 * fw))
    base = F.avg_pool2d(x[:, : m.feature_channels], 2)
    x = F.avg_pool2d(m.pixel(x), 2)
    x = F.relu(m.cell(torch.cat([x, base], 1))) + x
    tokens = x.flatten(2).transpose(1, 2)
    att = torch.softmax(m.query(tokens) @ m.key(tokens).transpose(1, 2) / math.sqrt(m.query.out_features), -1)
    ctx = (att @ m.value(tokens)).transpose(1, 2).reshape_as(x)
    return (base + m.out(torch.cat([x, ctx], 1))) * m.map_scale[None, :, None, None]


def test_decode_matches_its_plain_reference_in_values_and_gradients(model):
    gen = torch.Generator().manual_seed(3)
    c, d = model.feature_channels, model.config.embed_dim
    m = model.double()
    try:
        inputs = [
            torch.rand(3, c + d, 36, 48, dtype=torch.float64, generator=gen).requires_grad_(True),
            torch.rand(3, 36, 48, dtype=torch.float64, generator=gen).requires_grad_(True),
            torch.rand(3, 2, 36, 48, dtype=torch.float64, generator=gen).requires_grad_(True),
        ]
        fast, plain = m.decode(*inputs), _plain_decode(m, *inputs)
        torch.testing.assert_close(fast, plain)
        g_fast, g_plain = (torch.autograd.grad((y * y).sum(), inputs) for y in (fast, plain))
        for a, b in zip(g_fast, g_plain):
            torch.testing.assert_close(a, b)
        assert float(g_fast[0].abs().sum()) > 0
    finally:
        model.float()


def test_decode_without_autograd_attends_in_chunks_to_the_same_values(model, monkeypatch):
    """Stage 1's path (no autograd: the attention a few poses at a time, scaled in place) gives
    what the differentiable path gives, over a batch that ends in a partial chunk."""
    from aes_planner.field import model as field_model

    gen = torch.Generator().manual_seed(5)
    c, d = model.feature_channels, model.config.embed_dim
    inputs = [torch.rand(7, c + d, 36, 48, generator=gen), torch.rand(7, 36, 48, generator=gen)]
    inputs.append(torch.rand(7, 2, 36, 48, generator=gen))
    n = model.feature_size[0] * model.feature_size[1]
    monkeypatch.setattr(field_model, "_ATTENTION_CHUNK_BYTES", 3 * 4 * n * n)  # chunks of 3, 3, 1 poses
    calls = []
    bmm = torch.bmm
    monkeypatch.setattr(torch, "bmm", lambda *a, **k: calls.append(a[0].shape[0]) or bmm(*a, **k))
    with torch.no_grad():
        chunked = model.decode(*inputs)
    assert calls == [3, 3, 3, 3, 1, 1]  # scores and context per chunk
    whole = model.decode(*inputs).detach()  # autograd on: the whole batch at once
    torch.testing.assert_close(chunked, whole, rtol=1e-6, atol=1e-7)
    assert float(whole.abs().sum()) > 0


def test_gaussians_carry_the_source_direction_in_the_colour_slot(model, teacher, rig_frames):
    """Layout the renderer relies on: features = [teacher map (C), embedding (D)], colours = the
    unit direction from each Gaussian to the camera that observed it (local frame)."""
    frames, _ = rig_frames
    fld = AestheticField.build(frames, CFG, model=model, teacher=teacher)
    g, inputs = fld.gaussians, fld._inputs
    assert g.features.shape[1] == model.feature_channels + model.config.embed_dim
    direction = g.colors.detach().double()
    assert torch.allclose(direction.norm(dim=1), torch.ones(len(g), dtype=torch.float64), atol=1e-5)
    centre = torch.from_numpy(inputs.cam2world_local[inputs.splats.source_frame, :3, 3])  # [N, 3]
    to_camera = centre - torch.from_numpy(inputs.splats.means.astype(np.float64))
    cosine = (direction * to_camera).sum(1) / to_camera.norm(dim=1)
    assert float(cosine.min()) > 0.999
