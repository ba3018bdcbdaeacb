"""The cameras the package lets in, and only those: Intrinsics refuse what no camera has (a focal
length of 1e30 px, where the compiled and the torch rasterizer part ways in float32), and across
the whole allowed range (fields of view 0.01-179.5 deg over the longer side, principal points within ten image sizes) the compiled
and the torch rasterizer agree."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.gaussians import Gaussians
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError
from aes_planner.geometry.plausible import CAMERA_FOV_RANGE_DEG, MAX_PRINCIPAL_OFFSET
from tests.helpers import FAST_BACKENDS, OUTPUTS, assert_close, render


@pytest.mark.parametrize(
    "args",
    [
        (1e30, 1e30, 16.0, 12.0, 32, 24),
        (1e30, 30.0, 16.0, 12.0, 32, 24),
        (1e-30, 1e-30, 16.0, 12.0, 32, 24),
        (30.0, 30.0, 1e9, 12.0, 32, 24),
        (30.0, 30.0, 16.0, -1e9, 32, 24),
        (1e6, 1e6, 16.0, 12.0, 32, 24),  # 0.002 deg: a telescope pointed at nothing
    ],
)
def test_a_camera_no_camera_is_refused_where_it_enters(args):
    with pytest.raises(IntrinsicsError, match="intrinsics"):
        Intrinsics(*args)


@st.composite
def cameras(draw):
    width, height = draw(st.sampled_from([(1, 1), (7, 5), (32, 24), (64, 8)]))
    lo, hi = CAMERA_FOV_RANGE_DEG
    hfov = math.exp(draw(st.floats(math.log(lo), math.log(hi))))
    fx = max(width, height) / (2 * math.tan(math.radians(hfov) / 2))
    fy = fx * draw(st.floats(0.5, 2.0))
    cx = draw(st.floats(-MAX_PRINCIPAL_OFFSET, 1 + MAX_PRINCIPAL_OFFSET)) * width
    cy = draw(st.floats(-MAX_PRINCIPAL_OFFSET, 1 + MAX_PRINCIPAL_OFFSET)) * height
    try:
        k = Intrinsics(fx, fy, cx, cy, width, height)
    except IntrinsicsError:  # fy took the vertical field of view past the bounds: refused, as it must be
        return None
    return k, draw(st.integers(0, 2**31 - 1)), draw(st.sampled_from([torch.float32, torch.float64]))


@pytest.mark.skipif(len(FAST_BACKENDS) < 2, reason="the compiled backend (numba) is not available")
@settings(max_examples=25, deadline=None)
@given(camera=cameras())
def test_compiled_and_torch_rasterizers_agree_across_the_allowed_cameras(camera):
    if camera is None:
        return
    k, seed, dtype = camera
    rng = np.random.default_rng(seed)
    n = 12
    # Gaussians in the camera's view at 1-20 m, a few pixels to a whole image across
    z = rng.uniform(1.0, 20.0, n)
    u = rng.uniform(0.0, k.width, n)
    v = rng.uniform(0.0, k.height, n)
    means = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=1)
    pixel_m = z / k.fx  # one pixel's size at that depth
    log_scales = np.log(pixel_m[:, None] * rng.uniform(0.3, max(k.width, k.height), (n, 3)))
    t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    g = Gaussians(
        t(means),
        t(rng.normal(size=(n, 4))),
        t(log_scales),
        t(rng.uniform(0.05, 1.0, n)),
        t(rng.random((n, 3))),
        t(rng.normal(size=(n, 2))),
    )
    world2cam = torch.eye(4, dtype=torch.float64)[None]
    K = torch.tensor(k.K, dtype=torch.float64)[None]
    outs = {b: render(b, g, world2cam, K, k.width, k.height) for b in FAST_BACKENDS}
    tol = (1e-6, 1e-8) if dtype == torch.float64 else (2e-3, 2e-4)
    for name in OUTPUTS:
        a, b = outs["numba"][name], outs["torch"][name]
        assert torch.isfinite(a).all() and torch.isfinite(b).all()
        assert_close(a, b, *tol, f"numba vs torch {name} at fx {k.fx:.4g} px ({math.degrees(k.hfov_rad):.3g} deg)")
