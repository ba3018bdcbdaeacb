"""The Gaussians container: validation, concatenation, indexing, dtype moves, files."""

import numpy as np
import pytest
import torch

from aes_planner import tensorfile
from aes_planner.errors import AesPlannerError
from aes_planner.gaussians import GaussianError, Gaussians, random_scene

_FIELDS = ("means", "quats", "log_scales", "opacities", "colors", "features", "source_frame", "source_pixel")


def make(n=5, c=2, dtype=torch.float32):
    g, _, _ = random_scene(n, channels=c, dtype=dtype, seed=3)
    return g


def test_defaults_fill_features_and_provenance():
    g = make()
    bare = Gaussians(g.means, g.quats, g.log_scales, g.opacities, g.colors)
    assert bare.num_channels == 0 and bare.features.shape == (5, 0)
    assert bare.source_frame.tolist() == [-1] * 5
    assert bare.source_pixel.shape == (5, 2) and bare.source_pixel.dtype == torch.int32


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("means", torch.zeros(5, 2), "means"),
        ("quats", torch.zeros(4, 4), "quats"),
        ("opacities", torch.zeros(5, 1), "opacities"),
        ("features", torch.zeros(5, 2, 1), "features"),
        ("colors", torch.zeros(5, 3, dtype=torch.float64), "dtype"),
        ("source_frame", torch.zeros(5, dtype=torch.int64), "int32"),
    ],
)
def test_bad_fields_are_named(field, value, message):
    g = make()
    kwargs = {f: getattr(g, f) for f in ("means", "quats", "log_scales", "opacities", "colors", "features")}
    kwargs[field] = value
    with pytest.raises(GaussianError, match=message) as info:
        Gaussians(**kwargs)
    assert field in str(info.value) or message in str(info.value)
    assert isinstance(info.value, AesPlannerError)


def test_validate_catches_nan_and_opacity_range():
    g = make()
    g.validate()
    bad = g.clone()
    bad.log_scales[2, 1] = float("nan")
    with pytest.raises(GaussianError, match="log_scales"):
        bad.validate()
    bad = g.clone()
    bad.opacities[0] = 1.5
    with pytest.raises(GaussianError, match=r"\[0, 1\]"):
        bad.validate()


def test_cat_index_and_mask_keep_every_field():
    a, b = make(4), make(3)
    a.source_frame[:] = 0
    b.source_frame[:] = 1
    b.source_pixel[:] = torch.tensor([7, 9], dtype=torch.int32)
    both = Gaussians.cat([a, b])
    assert len(both) == 7 and both.num_channels == 2
    assert both.source_frame.tolist() == [0] * 4 + [1] * 3
    assert torch.equal(both[4:].means, b.means)
    assert torch.equal(both[-1].source_pixel, b.source_pixel[-1:])
    mask = both.source_frame == 1
    assert torch.equal(both[mask].features, b.features)
    picked = both[[6, 0]]
    assert torch.equal(picked.colors, torch.stack([b.colors[2], a.colors[0]]))
    with pytest.raises(GaussianError, match="channels"):
        Gaussians.cat([make(2, c=1), make(2, c=2)])
    with pytest.raises(GaussianError, match="mask"):
        both[torch.ones(3, dtype=torch.bool)]


def test_indexing_is_differentiable():
    g = make().requires_grad_()
    g[1:3].means.sum().backward()
    assert g.means.grad[1:3].eq(1).all() and g.means.grad[0].eq(0).all()


def test_to_changes_float_fields_only():
    g = make().to(dtype=torch.float64)
    assert g.means.dtype == torch.float64 and g.features.dtype == torch.float64
    assert g.source_frame.dtype == torch.int32


def test_save_load_round_trip(tmp_path):
    g = make(6, c=3)
    g.source_frame[:] = torch.arange(6, dtype=torch.int32)
    path = g.save(tmp_path / "scene.npz")
    back = Gaussians.load(path)
    for f in ("means", "quats", "log_scales", "opacities", "colors", "features", "source_frame", "source_pixel"):
        assert torch.equal(getattr(back, f), getattr(g, f)), f


def test_load_rejects_other_files(tmp_path):
    with pytest.raises(GaussianError, match="no such"):
        Gaussians.load(tmp_path / "missing.npz")
    tensorfile.save(tmp_path / "other.npz", {"weights": torch.zeros(3)})
    with pytest.raises(GaussianError, match="not a Gaussians file"):
        Gaussians.load(tmp_path / "other.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a pickle")
    with pytest.raises(GaussianError, match="not a Gaussians file"):
        Gaussians.load(tmp_path / "junk.npz")
    g = make(4)
    tensorfile.save(tmp_path / "v1.npz", {**{f: getattr(g, f) for f in _FIELDS}, "format_version": 1})
    with pytest.raises(GaussianError, match="version 1"):
        Gaussians.load(tmp_path / "v1.npz")
    tensorfile.save(
        tmp_path / "arr.npz", {**{f: getattr(g, f) for f in _FIELDS}, "means": np.zeros((4, 3)), "format_version": 2}
    )
    with pytest.raises(GaussianError, match="not tensors"):
        Gaussians.load(tmp_path / "arr.npz")


@pytest.mark.parametrize("zip_format", [True, False])
def test_load_refuses_old_torch_files_without_unpickling(tmp_path, request, zip_format):
    g = make(3)
    old = tmp_path / "scene.pt"
    data = {**{f: getattr(g, f) for f in _FIELDS}, "format_version": torch.tensor(1)}
    torch.save(data, old, _use_new_zipfile_serialization=zip_format)
    request.getfixturevalue("no_unpickling")
    with pytest.raises(GaussianError, match="older aes-planner in torch's pickle-based format.*Gaussians.save"):
        Gaussians.load(old)


def test_from_logits_and_empty():
    g = make()
    logits = torch.zeros(5, requires_grad=True)
    h = Gaussians.from_logits(g.means, g.quats, g.log_scales, logits, g.colors)
    assert torch.allclose(h.opacities, torch.full((5,), 0.5))
    h.opacities.sum().backward()
    assert torch.allclose(logits.grad, torch.full((5,), 0.25))
    e = Gaussians.empty(channels=4, dtype=torch.float64)
    assert len(e) == 0 and e.num_channels == 4 and e.dtype == torch.float64
