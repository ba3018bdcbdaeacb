"""Blending weights for hidden-splat pruning: the batched render (a probe channel per view, views
grouped by image size) against one render per view, the definition it replaces."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aes_planner.gaussians import autograd_on, rasterize
from aes_planner.geometry.camera import Intrinsics
from aes_planner.reconstruct.merge import contributions
from aes_planner.reconstruct.splats import SplatSet


def _splats(m: int, seed: int) -> SplatSet:
    rng = np.random.default_rng(seed)
    base = SplatSet.empty()
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    quats = rng.normal(size=(m, 4))
    fields = dict(base.__dict__)
    fields.update(
        means=f32(rng.uniform([-4.0, -0.8, 2.0], [4.0, 0.8, 4.0], size=(m, 3))),
        quats=f32(quats / np.linalg.norm(quats, axis=1, keepdims=True)),
        log_scales=f32(rng.uniform(-3.5, -2.0, size=(m, 3))),
        opacities=f32(rng.uniform(0.2, 0.95, size=m)),
        colors=f32(rng.uniform(size=(m, 3))),
    )
    for name in ("normals", "footprint_m", "score", "samples", "edge_px", "border_px"):
        fields[name] = np.zeros((m, *getattr(base, name).shape[1:]), np.float32)
    for name in ("source_frame", "source_pixel", "level", "block", "stride"):
        fields[name] = np.zeros((m, *getattr(base, name).shape[1:]), getattr(base, name).dtype)
    return SplatSet(**fields)


def _view(yaw_deg: float, width: int, height: int) -> tuple[np.ndarray, Intrinsics]:
    a = np.radians(yaw_deg)
    cam2world = np.eye(4)
    cam2world[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    return cam2world, Intrinsics(0.9 * width, 0.9 * width, width / 2, height / 2, width, height)


def _one_view_at_a_time(sp: SplatSet, views) -> tuple[np.ndarray, np.ndarray]:
    best, seen = np.zeros(len(sp)), np.zeros(len(sp), bool)
    with autograd_on():
        g = sp.to_gaussians()
        colors = g.colors.clone().requires_grad_(True)
        g.colors = colors
        for cam2world, k in views:
            w2c = torch.from_numpy(np.linalg.inv(cam2world))
            out = rasterize(g, w2c, torch.from_numpy(k.K), k.width, k.height, validate=False)
            (grad,) = torch.autograd.grad(out.rgb[:, 0].sum(), colors)
            wgt = grad[:, 0].double().numpy()
            best, seen = np.maximum(best, wgt), seen | (wgt > 0)
    return best, seen


@pytest.mark.parametrize(
    "sizes",
    [
        [(32, 24)],  # one view: the colours' first channel only
        [(32, 24)] * 3,  # the colours carry all views
        [(32, 24)] * 5 + [(40, 30)] * 2,  # the features carry views 3-4; a second image size, its own call
    ],
)
def test_batched_weights_match_one_render_per_view(sizes):
    sp = _splats(400, seed=len(sizes))
    views = [_view(-20.0 + 8.0 * i, w, h) for i, (w, h) in enumerate(sizes)]
    best, seen = contributions(sp, views)
    ref_best, ref_seen = _one_view_at_a_time(sp, views)
    assert seen.any() and not seen.all()  # some splats fall outside every view
    np.testing.assert_array_equal(seen, ref_seen)
    np.testing.assert_allclose(best, ref_best, rtol=1e-5, atol=1e-6)
    # the weight of a splat is at most its pixels of coverage and at least 0
    assert (best >= 0).all() and (best <= max(w * h for w, h in sizes)).all()


def test_weights_do_not_import_torch_symbolic_shapes():
    """autograd's check of explicit grad_outputs imports torch's symbolic shapes and sympy
    (~0.5 s of CPU in a cold `suggest`); the weights must come without it."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from tests.reconstruct.test_contributions import _splats, _view\n"
        "from aes_planner.reconstruct.merge import contributions\n"
        "best, seen = contributions(_splats(200, 0), [_view(a, 32, 24) for a in (-10.0, 0.0, 10.0, 20.0)])\n"
        "assert seen.any()\n"
        "print('sympy' in sys.modules, 'torch.fx.experimental.symbolic_shapes' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    assert out.stdout.split()[-2:] == ["False", "False"], out.stdout + out.stderr
