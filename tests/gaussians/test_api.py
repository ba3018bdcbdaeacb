"""rasterize(): input checks with useful errors, backend selection, output layout."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from aes_planner.gaussians import BACKEND_ENV, GaussianError, numba_backend, random_scene, rasterize, resolve_backend
from aes_planner.geometry.poses import quat_to_matrix
from tests.helpers import FAST_BACKENDS


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
        (lambda w, K: (_rotation_times(w, torch.zeros(3, 3)), K), "not orthonormal"),
        (lambda w, K: (_rotation_times(w, torch.ones(3, 3) / 3), K), "not orthonormal"),  # rank 1
        (lambda w, K: (_rotation_times(w, 1.01 * torch.eye(3)), K), "not orthonormal"),  # scaled
        (lambda w, K: (_rotation_times(w, torch.diag(torch.tensor([-1.0, 1, 1]))), K), "reflection"),  # mirrored
        (lambda w, K: (_rotation_times(w, torch.tensor([[1.0, 0.01, 0], [0, 1, 0], [0, 0, 1]])), K), "orthonormal"),
        (lambda w, K: (w[:0], K[:0]), "0 cameras"),
        (lambda w, K: (w[:0], K[0]), "0 cameras"),
    ],
)
def test_bad_cameras_raise_helpful_errors(scene, change, message, fast_backend):
    g, world2cam, K = scene
    w, k = change(world2cam, K)
    with pytest.raises(GaussianError, match=message) as info:
        rasterize(g, w, k, 20, 12, backend=fast_backend)
    assert isinstance(info.value, AesPlannerError)


def _rotation_times(world2cam, m):
    """world2cam with its rotation block multiplied by m on the left (the last camera only)."""
    out = world2cam.clone()
    out[-1, :3, :3] = m.to(out.dtype) @ out[-1, :3, :3]
    return out


@settings(max_examples=40, deadline=None)
@given(
    quat=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: sum(v * v for v in q) > 1e-2),
    scale=st.floats(0.5, 2.0),
    float32=st.booleans(),
)
def test_rigid_check_accepts_rotations_and_refuses_scaled_ones(quat, scale, float32):
    g, world2cam, K = random_scene(20, 0, 8, 8, 1, seed=3)
    rot = quat_to_matrix(torch.tensor(quat, dtype=torch.float64))
    w = _rotation_times(world2cam, rot)
    if float32:
        w = w.float()  # rounding of a float32 pose must pass
    assert rasterize(g, w, K, 8, 8, backend="torch").rgb.isfinite().all()
    scaled = _rotation_times(w, scale * torch.eye(3))
    if abs(scale - 1) > 1e-3:
        with pytest.raises(GaussianError, match="rigid"):
            rasterize(g, scaled, K, 8, 8, backend="torch")


def test_non_finite_background_and_huge_batches_are_refused(scene, fast_backend):
    g, world2cam, K = scene
    for bad in ([float("nan"), 0.0, 0.0], [0.0, float("inf"), 0.0]):
        with pytest.raises(GaussianError, match="background has NaN or Inf"):
            rasterize(g, world2cam, K, 20, 12, background=bad, backend=fast_backend)
    with pytest.raises(GaussianError, match="pixels in one call"):
        rasterize(g, world2cam, K, 100_000, 100_000, backend=fast_backend)


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
