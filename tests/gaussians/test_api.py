"""rasterize(): input checks with useful errors, backend selection, output layout."""

import pytest
import torch

from aes_planner.errors import AesPlannerError
from aes_planner.gaussians import BACKEND_ENV, GaussianError, numba_backend, random_scene, rasterize, resolve_backend

from .conftest import FAST_BACKENDS


@pytest.fixture
def scene():
    return random_scene(50, 4, 20, 12, 2, seed=2)


def test_output_layout_is_batch_and_channel_first(scene, fast_backend):
    g, world2cam, K = scene
    out = rasterize(g, world2cam, K, 20, 12, backend=fast_backend)
    assert out.backend == fast_backend
    assert out.rgb.shape == (2, 3, 12, 20) and out.features.shape == (2, 4, 12, 20)
    assert out.depth.shape == (2, 12, 20) and out.alpha.shape == (2, 12, 20)
    assert out.rgb.dtype == torch.float32


def test_single_camera_and_shared_intrinsics(scene):
    g, world2cam, K = scene
    one = rasterize(g, world2cam[0], K[0], 20, 12)
    assert one.rgb.shape == (1, 3, 12, 20)
    shared = rasterize(g, world2cam, K[0], 20, 12)
    assert torch.allclose(shared.rgb, rasterize(g, world2cam, K, 20, 12).rgb)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda w, K: (w[:, :3], K), "world2cam must have shape"),
        (lambda w, K: (w.clone().index_fill_(2, torch.tensor([3]), float("nan")), K), "NaN"),
        (lambda w, K: (w, K[:1].repeat(3, 1, 1)), "3 cameras"),
        (lambda w, K: (w, K * torch.tensor([[-1.0, 1, 1], [1, 1, 1], [1, 1, 1]], dtype=K.dtype)), "positive"),
        (lambda w, K: (w, K + torch.tensor([[0, 0.5, 0], [0, 0, 0], [0, 0, 0]], dtype=K.dtype)), "skew"),
        (lambda w, K: (w.clone().index_fill_(1, torch.tensor([3]), 0.5), K), "bottom row"),
        (lambda w, K: (w.long(), K), "floating point"),
    ],
)
def test_bad_cameras_raise_helpful_errors(scene, change, message):
    g, world2cam, K = scene
    w, k = change(world2cam, K)
    with pytest.raises(GaussianError, match=message) as info:
        rasterize(g, w, k, 20, 12)
    assert isinstance(info.value, AesPlannerError)


def test_bad_sizes_background_and_gaussians(scene):
    g, world2cam, K = scene
    for width in (0, 2.5, True):
        with pytest.raises(GaussianError, match="width"):
            rasterize(g, world2cam, K, width, 12)
    with pytest.raises(GaussianError, match="background"):
        rasterize(g, world2cam, K, 20, 12, background=[0.0, 1.0])
    bad = g.clone()
    bad.means[3, 0] = float("inf")
    with pytest.raises(GaussianError, match="means"):
        rasterize(bad, world2cam, K, 20, 12)
    with pytest.raises(GaussianError, match="Gaussians"):
        rasterize({"means": g.means}, world2cam, K, 20, 12)


def test_backend_argument_and_environment(monkeypatch):
    monkeypatch.delenv(BACKEND_ENV, raising=False)
    assert resolve_backend("torch") == "torch"
    assert resolve_backend("auto") == FAST_BACKENDS[0]
    monkeypatch.setenv(BACKEND_ENV, "torch")
    assert resolve_backend("auto") == "torch"
    if numba_backend.available():
        assert resolve_backend("numba") == "numba"  # an explicit argument wins over the variable
    monkeypatch.setenv(BACKEND_ENV, "cuda")
    with pytest.raises(GaussianError, match=BACKEND_ENV):
        resolve_backend("auto")
    with pytest.raises(GaussianError, match="one of"):
        resolve_backend("fast")


def test_without_numba_auto_falls_back_and_numba_explains(monkeypatch):
    monkeypatch.delenv(BACKEND_ENV, raising=False)
    monkeypatch.setattr(numba_backend, "available", lambda: False)
    assert resolve_backend("auto") == "torch"
    with pytest.raises(GaussianError, match=r"pip install 'aes-planner\[fast\]'"):
        resolve_backend("numba")


def test_numba_needs_cpu_tensors():
    with pytest.raises(GaussianError, match="CPU"):
        resolve_backend("numba", device="meta")
    assert resolve_backend("auto", device="meta") == "torch"
