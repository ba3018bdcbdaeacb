"""float64 gradcheck of every differentiable input on tiny scenes (hand-written numba backward
and the torch path's autograd alike)."""

import pytest
import torch
from torch.autograd import gradcheck

from aes_planner.gaussians import Gaussians, random_scene, rasterize


@pytest.mark.parametrize("n_cameras", [1, 4])
def test_gradcheck_tiny_scene(fast_backend, n_cameras):
    g, world2cam, K = random_scene(
        7, 2, 12, 9, n_cameras, seed=11 + n_cameras, dtype=torch.float64, sigma_px_at_64=(2.0, 6.0), opacity=(0.2, 0.8)
    )
    bottom = world2cam[:, 3:, :]
    inputs = [
        t.detach().clone().requires_grad_()
        for t in (g.means, g.quats, g.log_scales, g.opacities, g.colors, g.features, world2cam[:, :3, :])
    ]
    background = torch.tensor([0.3, 0.1, 0.7], dtype=torch.float64)

    def fn(means, quats, log_scales, opacities, colors, features, w2c_top):
        w2c = torch.cat([w2c_top, bottom], dim=1)
        out = rasterize(
            Gaussians(means, quats, log_scales, opacities, colors, features),
            w2c,
            K,
            12,
            9,
            background=background,
            backend=fast_backend,
        )
        return out.rgb, out.features, out.depth, out.alpha

    assert rasterize(g, world2cam, K, 12, 9).alpha.max() > 0.3, "the tiny scene must be visible"
    # fast_mode checks random projections of the Jacobian (seconds instead of minutes for the
    # ~3000 outputs); the full Jacobian is checked in the slow suite.
    assert gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


@pytest.mark.slow
def test_gradcheck_full_jacobian(fast_backend):
    g, world2cam, K = random_scene(
        5, 1, 8, 6, 2, seed=4, dtype=torch.float64, sigma_px_at_64=(3.0, 6.0), opacity=(0.2, 0.8)
    )
    bottom = world2cam[:, 3:, :]
    inputs = [
        t.detach().clone().requires_grad_()
        for t in (g.means, g.quats, g.log_scales, g.opacities, g.colors, g.features, world2cam[:, :3, :])
    ]

    def fn(means, quats, log_scales, opacities, colors, features, w2c_top):
        out = rasterize(
            Gaussians(means, quats, log_scales, opacities, colors, features),
            torch.cat([w2c_top, bottom], dim=1),
            K,
            8,
            6,
            backend=fast_backend,
        )
        return out.rgb, out.features, out.depth, out.alpha

    assert gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)
