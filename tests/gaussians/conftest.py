"""Helpers shared by the rasterizer tests: render with any backend and collect every gradient."""

from __future__ import annotations

import pytest
import torch

from aes_planner.gaussians import Gaussians, rasterize
from aes_planner.gaussians.numba_backend import available as numba_available
from aes_planner.gaussians.reference import rasterize_dense

FAST_BACKENDS = ["numba", "torch"] if numba_available() else ["torch"]
GRAD_FIELDS = ("means", "quats", "log_scales", "opacities", "colors", "features")
OUTPUTS = ("rgb", "features", "depth", "alpha")


def render(backend: str, g: Gaussians, world2cam, K, width, height, background=None):
    """Outputs as a dict; backend 'dense' is the reference."""
    if backend == "dense":
        return rasterize_dense(g, world2cam, K, width, height, background=background)
    out = rasterize(g, world2cam, K, width, height, background=background, backend=backend)
    return {k: getattr(out, k) for k in OUTPUTS}


def outputs_and_grads(backend, g, world2cam, K, width, height, background=None, seed=1):
    """Render, take a fixed random linear functional of every output, and return
    (outputs, gradients) for the Gaussian fields, world2cam and background."""
    g = g.detach().clone().requires_grad_()
    world2cam = world2cam.detach().clone().requires_grad_()
    if background is not None:
        background = background.detach().clone().requires_grad_()
    out = render(backend, g, world2cam, K, width, height, background)
    gen = torch.Generator().manual_seed(seed)
    loss = sum((out[k] * torch.randn(out[k].shape, generator=gen, dtype=out[k].dtype)).sum() for k in OUTPUTS)
    loss.backward()
    grads = {f: getattr(g, f).grad for f in GRAD_FIELDS}
    grads["world2cam"] = world2cam.grad
    if background is not None:
        grads["background"] = background.grad
    return {k: v.detach() for k, v in out.items()}, grads


def assert_close(actual, expected, rtol, atol_frac, what):
    """|a - e| <= max(atol_frac * max|e|, 1e-12) + rtol * |e| elementwise, with a readable failure."""
    assert actual.shape == expected.shape, f"{what}: shape {tuple(actual.shape)} != {tuple(expected.shape)}"
    if expected.numel() == 0:
        return
    scale = float(expected.abs().max())
    err = (actual.double() - expected.double()).abs()
    bound = max(atol_frac * scale, 1e-12) + rtol * expected.double().abs()
    worst = float((err - bound).max())
    assert worst <= 0, f"{what}: max error {float(err.max()):.3e} exceeds tolerance (scale {scale:.3e})"


@pytest.fixture(params=FAST_BACKENDS)
def fast_backend(request):
    return request.param
