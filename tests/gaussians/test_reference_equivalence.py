"""Fast backends against the dense reference: values and gradients on random scenes."""

import pytest
import torch

from aes_planner.gaussians import random_scene, rasterize
from aes_planner.gaussians.reference import rasterize_dense
from aes_planner.geometry import rigid_inverse, view_to_cam2world
from tests.helpers import GRAD_FIELDS, OUTPUTS, assert_close, outputs_and_grads

# (rtol, atol as a fraction of the largest |value|): float64 is exact up to summation order;
# float32 pixel maths against the float64 reference.
TOL = {torch.float64: (1e-9, 1e-10), torch.float32: (1e-3, 2e-4)}


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize(
    "n, width, height, n_cameras, channels",
    [
        (300, 40, 24, 1, 2),  # tiles cut by the image border; backward parallel over tiles
        (200, 16, 16, 5, 0),  # no features; backward parallel over cameras
        (400, 33, 17, 2, 5),
    ],
)
def test_values_and_gradients_match_reference(fast_backend, dtype, n, width, height, n_cameras, channels):
    g, world2cam, K = random_scene(n, channels, width, height, n_cameras, seed=n + width, dtype=dtype)
    background = torch.tensor([0.2, 0.5, 0.9], dtype=dtype)
    args = (g, world2cam, K, width, height, background)
    out, grads = outputs_and_grads(fast_backend, *args)
    ref_out, ref_grads = outputs_and_grads("dense", *args)
    rtol, atol = TOL[dtype]
    for k in OUTPUTS:
        assert_close(out[k], ref_out[k], rtol, atol, f"{fast_backend} {k}")
    assert float(ref_out["alpha"].max()) > 0.5, "the scene should cover the image"
    for k in (*GRAD_FIELDS, "world2cam", "background"):
        assert_close(grads[k], ref_grads[k], 10 * rtol, 10 * atol, f"{fast_backend} d/d{k}")
        if k != "features" or channels:
            assert float(ref_grads[k].abs().max()) > 0, f"reference gradient of {k} is zero"


def test_gradients_reach_the_5dof_view(fast_backend):
    g, _, K = random_scene(150, 1, 24, 20, 1, seed=5, dtype=torch.float64)

    def grad_of_view(backend):
        view = torch.tensor([[0.05, -0.02, 1.52, 0.03, -0.02]], dtype=torch.float64, requires_grad=True)
        world2cam = rigid_inverse(view_to_cam2world(view))
        if backend == "dense":
            out = rasterize_dense(g, world2cam, K, 24, 20)
            rgb, depth = out["rgb"], out["depth"]
        else:
            out = rasterize(g, world2cam, K, 24, 20, backend=backend)
            rgb, depth = out.rgb, out.depth
        (rgb.square().sum() + 0.1 * depth.sum()).backward()
        return view.grad

    ours, ref = grad_of_view(fast_backend), grad_of_view("dense")
    assert ref.abs().min() > 0, "every view parameter should move the image"
    assert_close(ours, ref, 1e-8, 1e-9, "d/d(x, y, z, yaw, pitch)")


def test_batch_equals_cameras_one_by_one(fast_backend):
    g, world2cam, K = random_scene(250, 3, 32, 24, 6, seed=9)
    batch = rasterize(g, world2cam, K, 32, 24, backend=fast_backend)
    for b in range(6):
        one = rasterize(g, world2cam[b], K[b], 32, 24, backend=fast_backend)
        for k in OUTPUTS:
            assert torch.allclose(getattr(batch, k)[b], getattr(one, k)[0], atol=1e-6), (b, k)


def test_depth_is_alpha_normalised_z():
    # One opaque, large Gaussian straight ahead at z = 3: depth 3 where drawn, 0 elsewhere.
    g, _, _ = random_scene(1, 0, 16, 16, dtype=torch.float64)
    g.means[:] = torch.tensor([[3.0, 0.0, 1.5]], dtype=torch.float64)  # camera at (0, 0, 1.5) looks along +x
    g.log_scales[:] = -1.0
    g.opacities[:] = 0.6
    _, world2cam, K = random_scene(1, 0, 16, 16, dtype=torch.float64)
    out = rasterize(g, world2cam, K, 16, 16)
    drawn = out.alpha > 0
    assert drawn.any() and (~drawn).any()
    assert torch.allclose(out.depth[drawn], torch.full_like(out.depth[drawn], 3.0), atol=1e-9)
    assert (out.depth[~drawn] == 0).all()


def test_gaussians_outside_the_frustum_match_reference(fast_backend):
    # Centres beyond 1.3 half fields of view (the projection Jacobian's x/z and y/z are clamped
    # there) with footprints large enough to reach into the image.
    g, world2cam, K = random_scene(40, 1, 24, 16, 2, seed=21, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    depth = 1.0 + 2.0 * torch.rand(40, generator=gen, dtype=torch.float64)
    side = torch.where(torch.rand(40, generator=gen) < 0.5, -1.0, 1.0).to(torch.float64)
    lateral = side * depth * (0.8 + 0.6 * torch.rand(40, generator=gen, dtype=torch.float64))  # |x/z| in [0.8, 1.4]
    vertical = 0.3 * depth * torch.randn(40, generator=gen, dtype=torch.float64)
    # camera 0 at (0, 0, 1.5) looks along +x; world +y is image left, +z image up
    g.means[:] = torch.stack([depth, lateral, 1.5 + vertical], -1)
    g.log_scales[:] = torch.log(0.3 * depth)[:, None] + torch.tensor([0.0, -0.7, 0.5], dtype=torch.float64)
    out, grads = outputs_and_grads(fast_backend, g, world2cam, K, 24, 16)
    ref_out, ref_grads = outputs_and_grads("dense", g, world2cam, K, 24, 16)
    assert float(ref_out["alpha"].max()) > 0.2
    for k in OUTPUTS:
        assert_close(out[k], ref_out[k], 1e-9, 1e-10, f"{fast_backend} {k}")
    for k in (*GRAD_FIELDS, "world2cam"):
        assert_close(grads[k], ref_grads[k], 1e-8, 1e-9, f"{fast_backend} d/d{k}")


def test_transmittance_stop_leaves_out_the_last_gaussian(fast_backend):
    # Four small Gaussians stacked on the centre pixel, alpha 0.95 there: T goes 1, 0.05,
    # 2.5e-3, 1.25e-4, then 6.25e-6 <= 1e-4, so the fourth is not composited and the pixel ends
    # with alpha = 1 - 1.25e-4 and the first three colours only.
    g, world2cam, K = random_scene(4, 0, 9, 9, dtype=torch.float64)
    depth = torch.tensor([2.0, 2.5, 3.0, 3.5], dtype=torch.float64)
    g.means[:] = torch.stack(
        [depth, torch.zeros(4, dtype=torch.float64), torch.full((4,), 1.5, dtype=torch.float64)], -1
    )
    g.quats[:] = torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)
    g.log_scales[:] = torch.log(0.02 * depth)[:, None]
    g.opacities[:] = 0.95
    g.colors[:] = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    out, grads = outputs_and_grads(fast_backend, g, world2cam, K, 9, 9)
    ref_out, ref_grads = outputs_and_grads("dense", g, world2cam, K, 9, 9)
    centre = (0, slice(None), 4, 4)
    a = 0.95
    expected = torch.tensor([a, (1 - a) * a, (1 - a) ** 2 * a], dtype=torch.float64)
    assert torch.allclose(ref_out["rgb"][centre], expected, atol=1e-12)
    assert torch.allclose(out["rgb"][centre], expected, atol=1e-12)
    assert abs(float(out["alpha"][0, 4, 4]) - (1 - (1 - a) ** 3)) < 1e-12
    for k in OUTPUTS:
        assert_close(out[k], ref_out[k], 1e-10, 1e-12, f"{fast_backend} {k}")
    for k in (*GRAD_FIELDS, "world2cam"):
        assert_close(grads[k], ref_grads[k], 1e-8, 1e-10, f"{fast_backend} d/d{k}")


def test_pose_only_gradients_equal_the_full_backward(fast_backend):
    """The search differentiates the poses only; the numba backend then skips the Gaussians'
    gradients, which must not change the poses' (bit-identical on the numba backend)."""
    g, world2cam, K = random_scene(300, 5, 40, 24, 3, seed=9, opacity=(0.3, 0.99))
    grads = []
    for gaussians_too in (True, False):
        gg = g.clone().requires_grad_() if gaussians_too else g.clone()
        w = world2cam.clone().requires_grad_()
        out = rasterize(gg, w, K, 40, 24, background=[0.1, 0.2, 0.3], backend=fast_backend)
        (out.rgb.square().sum() + out.features.sum() + out.depth.sum() + out.alpha.sum()).backward()
        grads.append(w.grad)
        assert (gg.means.grad is not None) == gaussians_too
    assert float(grads[0].abs().max()) > 0
    assert torch.equal(grads[0], grads[1])
