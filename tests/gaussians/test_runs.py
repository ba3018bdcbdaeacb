"""The tile kernels walk each Gaussian's box rows in a tile as one run of pixels and write (and,
backward, read) a tile's maps at flat indices. Hypothesis over images that cut tiles anywhere,
footprints from a fraction of a pixel to wider than a tile, and every channel layout: few and
many channels in the backward (from 8 values), pixel-major forward (from 64 values)."""

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.gaussians import random_scene, rasterize
from tests.helpers import FAST_BACKENDS, GRAD_FIELDS, OUTPUTS, assert_close, outputs_and_grads

pytestmark = pytest.mark.skipif("numba" not in FAST_BACKENDS, reason="the compiled kernels need numba")

# value channels + depth: 3 + C + 1 = 4 (few), 13 (many in the backward), 65 (pixel-major forward)
CHANNELS = [0, 9, 61]


@st.composite
def tile_scenes(draw, dtype, max_cameras=2):
    width, height = draw(st.integers(1, 40)), draw(st.integers(1, 40))
    n = draw(st.integers(0, 30))
    sigma = 10 ** draw(st.floats(-1.5, 1.4))  # 0.03 to 25 px at 64 px width
    g, world2cam, K = random_scene(
        n,
        draw(st.sampled_from(CHANNELS)),
        width,
        height,
        draw(st.integers(1, max_cameras)),
        seed=draw(st.integers(0, 2**31 - 1)),
        dtype=dtype,
        sigma_px_at_64=(sigma, 3 * sigma),
        opacity=(0.02, 0.99),
    )
    return g, world2cam, K, width, height


@given(scene=tile_scenes(torch.float64))
def test_runs_match_the_dense_reference(scene):
    """Values and every gradient against the dense reference in float64 (no tiles, no boxes)."""
    g, world2cam, K, width, height = scene
    background = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    out, grads = outputs_and_grads("numba", g, world2cam, K, width, height, background)
    ref_out, ref_grads = outputs_and_grads("dense", g, world2cam, K, width, height, background)
    for k in OUTPUTS:
        assert_close(out[k], ref_out[k], 1e-9, 1e-10, k)
    for k in (*GRAD_FIELDS, "world2cam", "background"):
        assert_close(grads[k], ref_grads[k], 1e-8, 1e-9, f"d/d{k}")


@given(scene=tile_scenes(torch.float32, max_cameras=1), grow=st.tuples(st.integers(0, 20), st.integers(0, 20)))
def test_a_smaller_image_is_the_crop_of_a_larger_one(scene, grow):
    """Pixel centres do not depend on the image size, so the maps of a W x H render are, bit for
    bit, the top-left W x H of a larger render with the same intrinsics: the border's partial
    tiles and the boxes it clips change nothing inside. (One camera: random_scene keeps the
    centres within 10 % of its border, inside the Jacobian's clamp limits of both sizes, which
    depend on the image size; a jittered second camera sees centres beyond them.)"""
    g, world2cam, K, width, height = scene
    with torch.no_grad():
        small = rasterize(g, world2cam, K, width, height, backend="numba")
        large = rasterize(g, world2cam, K, width + grow[0], height + grow[1], backend="numba")
    for k in OUTPUTS:
        crop = getattr(large, k)[..., :height, :width]
        assert torch.equal(getattr(small, k), crop), k
