"""VEN: original architecture and checkpoint layout, exact split, clear errors for bad files.

No real weights exist here: random weights saved in the released layout stand in for them.
"""

import argparse
import logging
import math
import os
import pickle

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from aes_planner.teachers import WeightsError, get_teacher
from aes_planner.teachers.ven import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    SPLIT,
    VENTeacher,
    convert_checkpoint,
    load_ven_state_dict,
)

CONV_INDICES = (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)
POOL_INDICES = (4, 9, 16, 23, 30)
EXPECTED_KEYS = [f"features.{i}.{p}" for i in CONV_INDICES for p in ("weight", "bias")] + [
    f"classifier.{i}.{p}" for i in (0, 3, 6) for p in ("weight", "bias")
]


@pytest.fixture(scope="module")
def ven():
    return VENTeacher.random(seed=1)


@pytest.fixture(scope="module")
def x224():
    return torch.rand(2, 3, 224, 224, generator=torch.Generator().manual_seed(3))


@pytest.fixture(scope="module")
def ven_scores(ven, x224):
    with torch.no_grad():
        return ven.score(x224)


@pytest.fixture(scope="module")
def released_file(ven, tmp_path_factory):
    """Random weights in the released layout: {'state_dict': {'single_pass_net.*': ...}} plus extras."""
    path = tmp_path_factory.mktemp("ven") / "EvaluationNet.pth.tar"
    state = {f"single_pass_net.{k}": v.clone() for k, v in ven.net.state_dict().items()}
    torch.save({"state_dict": state, "epoch": 5000}, path)
    return path


def reference_ven(state, x):  # [B, 3, 224, 224] in [0, 1] -> [B]
    """The original network written out layer by layer from the checkpoint keys, independently
    of the package's modules: conv3x3 + ReLU at CONV_INDICES, 2x2 max pool at POOL_INDICES."""
    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    h = (x - mean) / std
    for i in range(31):
        if i in CONV_INDICES:
            h = F.relu(F.conv2d(h, state[f"features.{i}.weight"], state[f"features.{i}.bias"], padding=1))
        elif i in POOL_INDICES:
            h = F.max_pool2d(h, 2, 2)
    h = h.flatten(1)
    h = F.relu(F.linear(h, state["classifier.0.weight"], state["classifier.0.bias"]))
    h = F.relu(F.linear(h, state["classifier.3.weight"], state["classifier.3.bias"]))
    return F.linear(h, state["classifier.6.weight"], state["classifier.6.bias"])[:, 0]


def test_architecture_matches_torchvision_indices_and_the_release(ven):
    feats = ven.net.features
    assert len(feats) == 31
    for i, m in enumerate(feats):
        kind = type(m).__name__
        assert kind == ("Conv2d" if i in CONV_INDICES else "MaxPool2d" if i in POOL_INDICES else "ReLU"), i
    assert isinstance(feats[SPLIT - 1], torch.nn.MaxPool2d) and SPLIT == 24  # pool4 closes the trunk
    assert list(ven.net.state_dict()) == EXPECTED_KEYS
    n = sum(p.numel() for p in ven.parameters())
    assert n == 40_931_137  # 14.71 M conv + 25.69 M + 0.52 M + 513 classifier
    head = sum(p.numel() for p in ven.net.features[SPLIT:].parameters()) + sum(
        p.numel() for p in ven.net.classifier.parameters()
    )
    assert 32e6 < head < 34e6
    assert ven.feature_channels == 512 and ven.feature_size == (14, 14)


def test_released_layout_loads_and_scores_exactly_as_the_original(released_file, x224):
    teacher = get_teacher("ven", weights=released_file)
    state = load_ven_state_dict(released_file)
    x = x224
    with torch.no_grad():
        s = teacher.score(x)
        ref = reference_ven(state, x)
        full = teacher.net(teacher.preprocess(x))[:, 0]
    torch.testing.assert_close(s, ref, rtol=1e-5, atol=1e-6)  # independent layer-by-layer network
    assert torch.equal(s, full)  # the split head(features()) is bit-identical to the unsplit net
    assert s[0] != s[1]


def test_split_reproduces_the_full_network_at_any_size(ven):
    for shape in [(2, 3, 96, 128), (1, 3, 1, 1)]:  # 224x224: in the test above
        x = torch.rand(shape)
        with torch.no_grad():
            fmap = ven.features(x)
            assert fmap.shape == (shape[0], 512, 14, 14)
            assert torch.equal(ven.head(fmap), ven.net(ven.preprocess(x))[:, 0])


def test_224_input_is_not_resampled_and_others_are_bilinear(ven):
    x = torch.rand(1, 3, 224, 224)
    mean, std = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    assert torch.equal(ven.preprocess(x), (x - mean) / std)
    y = torch.rand(1, 3, 112, 448)
    resized = F.interpolate(y, size=(224, 224), mode="bilinear", align_corners=False, antialias=True)
    torch.testing.assert_close(ven.preprocess(y), (resized - mean) / std)


def test_plain_state_dicts_and_wrapped_prefixes_load(ven, tmp_path):
    plain = tmp_path / "plain.pt"
    torch.save(ven.net.state_dict(), plain)
    wrapped = {f"module.single_pass_net.{k}": v for k, v in ven.net.state_dict().items()}
    for weights in (plain, str(plain), {"state_dict": wrapped}):
        loaded = VENTeacher(weights).net.state_dict()
        assert list(loaded) == EXPECTED_KEYS
        assert all(torch.equal(loaded[k], v) for k, v in ven.net.state_dict().items())


def test_gradients_flow_through_both_halves(ven):
    x = torch.rand(1, 3, 64, 80, requires_grad=True)
    ven.score(x).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    fmap = ven.features(torch.rand(1, 3, 224, 224)).detach().requires_grad_(True)
    ven.head(fmap).sum().backward()
    assert torch.isfinite(fmap.grad).all() and fmap.grad.abs().sum() > 0
    assert not any(p.requires_grad for p in ven.parameters())


def test_gradients_finite_on_constant_images(ven):
    x = torch.tensor([0.0, 1.0, 0.5]).view(3, 1, 1, 1).expand(3, 3, 16, 16).clone().requires_grad_(True)
    ven.score(x).sum().backward()
    assert torch.isfinite(x.grad).all()


def test_dropout_stays_off(ven, x224, ven_scores):
    ven.train()
    assert not ven.training and not ven.net.classifier[2].training
    with torch.no_grad():
        assert torch.equal(ven.score(x224), ven_scores)


def test_no_weights_is_refused_with_advice():
    for make in (lambda: get_teacher("ven"), lambda: VENTeacher()):
        with pytest.raises(WeightsError) as info:
            make()
        msg = str(info.value)
        assert "--weights" in msg and "github.com/zijunwei/ViewEvaluationNet" in msg


def test_missing_file(tmp_path):
    with pytest.raises(WeightsError, match="does not exist"):
        VENTeacher(tmp_path / "nope.pth.tar")


@pytest.mark.parametrize("content", [b"", b"not a checkpoint at all" * 40, bytes(range(256)) * 10])
def test_corrupt_files_give_a_clear_error(tmp_path, content):
    path = tmp_path / "bad.pth"
    path.write_bytes(content)
    with pytest.raises(WeightsError, match="not a readable PyTorch checkpoint"):
        VENTeacher(path)


def test_truncated_file_gives_a_clear_error(released_file, tmp_path):
    path = tmp_path / "half.pth.tar"
    data = released_file.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match="truncated or corrupt"):
        VENTeacher(path)


def test_wrong_network_is_refused(ven, tmp_path):
    state = ven.net.state_dict()
    missing = {k: v for k, v in state.items() if not k.startswith("classifier.6")}
    with pytest.raises(WeightsError, match=r"missing \['classifier.6.weight'"):
        VENTeacher(missing)
    extra = {**state, "fc.weight": torch.zeros(2)}
    with pytest.raises(WeightsError, match="unexpected"):
        VENTeacher(extra)
    torchvision_vgg = {**state, "classifier.0.weight": torch.zeros(4096, 25088)}
    with pytest.raises(WeightsError, match=r"classifier.0.weight has shape \(4096, 25088\)"):
        VENTeacher(torchvision_vgg)
    with pytest.raises(WeightsError, match="not finite"):
        VENTeacher({**state, "classifier.6.bias": torch.tensor([math.nan])})
    with pytest.raises(WeightsError, match="not a tensor"):
        VENTeacher({**state, "classifier.6.bias": [0.0]})
    with pytest.raises(WeightsError, match="expected a state dict"):
        VENTeacher([1, 2])


class _Training:  # an object a training script might have pickled next to the weights
    def __init__(self):
        self.lr = 0.01


@pytest.mark.parametrize("zip_format", [True, False], ids=["zip", "legacy"])
def test_pickled_extras_load_as_inert_placeholders(ven, tmp_path, x224, ven_scores, zip_format, caplog):
    """A checkpoint with training extras (numpy scalars and arrays, a Namespace, a class of the
    training script) in the 2018 legacy format or the zip format loads weights-only, the extras
    as placeholders; it scores exactly like its weights, and converts to bare tensors."""
    released = tmp_path / "EvaluationNet.pth.tar"
    state = {f"single_pass_net.{k}": v for k, v in ven.net.state_dict().items()}
    extras = {
        "best_prec": np.float64(0.77),
        "hist": np.zeros(3),
        "args": argparse.Namespace(lr=0.1),
        "cfg": _Training(),
    }
    torch.save({"state_dict": state, **extras}, released, _use_new_zipfile_serialization=zip_format)
    with pytest.raises(pickle.UnpicklingError):
        torch.load(released, weights_only=True)  # what a plain weights-only load says
    with caplog.at_level(logging.INFO, logger="aes_planner.teachers.ven"):
        with torch.no_grad():
            assert torch.equal(VENTeacher(released).score(x224), ven_scores)
    assert "argparse.Namespace" in caplog.text and "_Training" in caplog.text
    out = convert_checkpoint(released, tmp_path / "ven_weights.pt")
    assert set(torch.load(out, weights_only=True)) == set(ven.net.state_dict())
    with torch.no_grad():
        assert torch.equal(VENTeacher(out).score(x224), ven_scores)


class _Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("zip_format", [True, False], ids=["zip", "legacy"])
def test_a_file_that_would_run_code_is_refused_and_runs_nothing(ven, tmp_path, zip_format):
    marker = tmp_path / "ran"
    path = tmp_path / "EvaluationNet.pth.tar"
    state = {f"single_pass_net.{k}": v for k, v in ven.net.state_dict().items()}
    torch.save({"state_dict": state, "x": _Payload(marker)}, path, _use_new_zipfile_serialization=zip_format)
    for read in (VENTeacher, lambda p: convert_checkpoint(p, tmp_path / "out.pt")):
        with pytest.raises(WeightsError, match=r"references .*system.*never needs"):
            read(path)
    assert not marker.exists() and not (tmp_path / "out.pt").exists()


def test_a_tensor_entry_that_is_a_placeholder_is_refused(tmp_path):
    path = tmp_path / "odd.pt"
    torch.save({"state_dict": {"features.0.weight": np.zeros(3)}}, path)
    with pytest.raises(WeightsError, match="features.0.weight.*not a tensor"):
        VENTeacher(path)


def test_conversion_refuses_what_is_not_ven(tmp_path):
    src = tmp_path / "other.pt"
    torch.save({"state_dict": {"fc.weight": torch.zeros(1)}, "note": np.float64(1)}, src)
    with pytest.raises(WeightsError, match="not VEN's"):
        convert_checkpoint(src, tmp_path / "out.pt")
    assert not (tmp_path / "out.pt").exists()
    with pytest.raises(WeightsError, match="does not exist"):
        convert_checkpoint(tmp_path / "missing.pt", tmp_path / "out.pt")
