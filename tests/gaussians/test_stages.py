"""Each stage of the numba backend against its plain torch twin (aes_planner.gaussians.twins):
projection and its backward, tile binning, per-tile compositing forward and backward. Every
stage gets the same inputs as its twin, so a wrong change fails the test of its own stage."""

import numpy as np
import pytest
import torch

from aes_planner.gaussians import numba_backend, random_scene, twins
from aes_planner.gaussians.numerics import TILE
from tests.helpers import assert_close

pytestmark = pytest.mark.skipif(not numba_backend.available(), reason="the numba backend is not installed")

# (rtol, atol as a fraction of the largest |value|) against the float64 twin
TOL = {torch.float64: (1e-9, 1e-10), torch.float32: (1e-3, 2e-4)}
# (name, n, width, height, cameras, channels, dtype, sigma_px_at_64, opacity): lane-major values
# (C + 4 < 8), pixel-major in the backward (C + 4 >= 8) and in the forward too (C + 4 >= 64),
# tiles cut by the border, narrow and wide row windows, and a dense opaque scene where pixels
# reach the transmittance stop.
SCENES = [
    ("lanes", 150, 40, 24, 2, 1, torch.float64, (0.5, 6.0), (0.1, 0.9)),
    ("pixels", 150, 33, 17, 3, 6, torch.float32, (0.5, 6.0), (0.1, 0.9)),
    ("wide", 100, 20, 18, 2, 61, torch.float32, (0.5, 6.0), (0.1, 0.9)),
    ("opaque", 400, 32, 32, 1, 2, torch.float32, (1.0, 8.0), (0.7, 0.99)),
    ("opaque64", 400, 20, 20, 2, 5, torch.float64, (1.0, 8.0), (0.7, 0.99)),
]


def _kernels():
    numba_backend._load()
    return numba_backend._kernels


class Stages:
    """The numba pipeline of one scene run stage by stage on numpy arrays (as numba_backend does)."""

    def __init__(self, name, n, width, height, cameras, channels, dtype, sigma_px, opacity):
        k = _kernels()
        g, world2cam, K = random_scene(
            n, channels, width, height, cameras, seed=7, dtype=dtype, sigma_px_at_64=sigma_px, opacity=opacity
        )
        self.name, self.dtype, self.width, self.height = name, dtype, width, height
        self.g = g
        self.inputs = [t.detach().numpy() for t in (g.means, g.quats, g.log_scales, g.opacities)]
        self.values = torch.cat([g.colors, g.features], 1).numpy()  # [N, Cv]
        self.channels = channels
        self.cams = k.camera_table(world2cam.numpy(), K.numpy(), width, height)  # [B, 20]
        self.tiles_x, self.tiles_y = -(-width // TILE), -(-height // TILE)
        self.n_cam = cameras
        self.cov = np.zeros((n, 6))
        self.proj = np.zeros((cameras, n, k.NPROJ), self.values.dtype)
        self.box = np.zeros((cameras, n, 4), np.int32)
        k.project_fwd(*self.inputs, self.cams, width, height, self.cov, self.proj, self.box)
        self.offsets, self.lists = self.binning(parallel=False)
        self.out = self.raster_fwd()

    def binning(self, parallel):
        k = _kernels()
        n = self.box.shape[1]
        n_tiles = self.tiles_x * self.tiles_y
        order = np.zeros((self.n_cam, n), np.int32)
        n_visible = np.zeros(self.n_cam, np.int64)
        counts = np.zeros((self.n_cam, n_tiles), np.int64)
        k.bin_cameras(self.proj, self.box, self.tiles_x, parallel, order, n_visible, counts)
        offsets = np.zeros(self.n_cam * n_tiles + 1, np.int64)
        np.cumsum(counts.reshape(-1), out=offsets[1:])
        lists = np.zeros(int(offsets[-1]), np.int32)
        k.fill_lists(self.box, self.tiles_x, parallel, order, n_visible, offsets, lists)
        return offsets, lists

    def raster_fwd(self):
        k = _kernels()
        b, h, w, c, dt = self.n_cam, self.height, self.width, self.channels, self.values.dtype
        rgb, feat = np.zeros((b, 3, h, w), dt), np.zeros((b, c, h, w), dt)
        dep, t_final, last = np.zeros((b, h, w), dt), np.zeros((b, h, w), dt), np.zeros((b, h, w), np.int32)
        k.raster_fwd(
            self.proj, self.box, self.values, self.offsets, self.lists, self.tiles_x, w, h,
            np.array(k.CONSTS, dt), k.numba.get_num_threads(), rgb, feat, dep, t_final, last,
        )  # fmt: skip
        return rgb, feat, dep, t_final, last

    def cotangents(self, seed):
        gen = torch.Generator().manual_seed(seed)
        return [torch.randn(a.shape, generator=gen, dtype=torch.float64).numpy().astype(a.dtype) for a in self.out[:4]]

    def twin_args(self):
        """The raster twin's inputs: the same arrays as the kernels got, in float64."""
        t = torch.from_numpy
        return (
            t(self.proj).double(), t(self.box), t(self.values).double(), t(self.offsets), t(self.lists),
            self.tiles_x, self.width, self.height,
        )  # fmt: skip


@pytest.fixture(scope="module", params=SCENES, ids=[s[0] for s in SCENES])
def stages(request):
    return Stages(*request.param)


def test_projection_matches_twin(stages):
    s = stages
    t = torch.from_numpy
    cov, proj, box = twins.project_fwd(*(t(a) for a in s.inputs), t(s.cams), s.width, s.height)
    visible = (s.box[..., 0] <= s.box[..., 1]).astype(bool)
    assert visible.sum() > 0.3 * visible.size, "most Gaussians should be in view"
    assert np.array_equal(box.numpy()[..., :2][~visible], np.tile([1, 0], ((~visible).sum(), 1)))
    assert np.array_equal(box.numpy()[visible], s.box[visible]), f"{s.name}: pixel boxes differ"
    assert_close(t(s.cov), cov, 1e-12, 1e-14, f"{s.name} world covariance")
    rtol = 1e-12 if s.dtype == torch.float64 else 1e-6
    assert_close(t(s.proj[visible]).double(), proj[t(visible)], rtol, rtol * 1e-2, f"{s.name} packed projection")


@pytest.mark.parametrize("need_gaussians", [True, False])
def test_projection_backward_matches_twin(stages, need_gaussians):
    s = stages
    k = _kernels()
    t = torch.from_numpy
    gen = torch.Generator().manual_seed(3)
    g2d = torch.randn(s.proj.shape, generator=gen, dtype=torch.float64)  # [B, N, 7]
    g2d[t(s.box[..., 0] > s.box[..., 1])] = 0  # the raster leaves culled Gaussians at zero
    threads = k.numba.get_num_threads()
    dt = s.values.dtype
    outs = [np.zeros_like(a) for a in s.inputs] + [np.zeros((threads, s.n_cam, k.G_CAM_STRIDE))]
    # two gradient buffers, as the raster's per-thread ones: the kernel must sum them
    g2d_buffers = np.stack([g2d.numpy(), g2d.numpy()]).astype(dt)
    k.project_bwd(*s.inputs[:3], s.cov, s.cams, s.box, g2d_buffers, *outs, need_gaussians)
    expected = twins.project_bwd(
        *(t(a) for a in s.inputs), t(s.cams), s.width, s.height, 2 * t(g2d.numpy().astype(dt)).double()
    )
    names = ("means", "quats", "log_scales", "opacities", "world2cam rows 0-2")
    assert not outs[-1][..., k.NPOSE :].any(), "project_bwd wrote into the padding of g_cam"
    outs[-1] = outs[-1][..., : k.NPOSE].sum(0)
    rtol = 1e-9 if s.dtype == torch.float64 else 1e-4
    for name, ours, ref in zip(names, outs, expected, strict=True):
        if not need_gaussians and name != names[-1]:  # pose-only: the Gaussians' buffers are not touched
            assert not ours.any(), f"{name} written although not asked for"
            continue
        assert float(ref.abs().max()) > 0, f"twin gradient of {name} is zero"
        assert_close(t(ours).double(), ref, rtol, rtol * 1e-2, f"{s.name} project_bwd d/d{name}")


@pytest.mark.parametrize("parallel", [False, True])
def test_binning_matches_twin(stages, parallel):
    s = stages
    offsets, lists = s.binning(parallel)
    ref_offsets, ref_lists = twins.bin_and_fill(torch.from_numpy(s.proj), torch.from_numpy(s.box), s.tiles_x, s.tiles_y)
    assert np.array_equal(offsets, ref_offsets.numpy()), f"{s.name}: tile counts differ"
    assert np.array_equal(lists, ref_lists.numpy()), f"{s.name}: tile lists or their depth order differ"
    assert len(lists) > s.box.shape[1], "Gaussians should span several tiles"


def test_raster_forward_matches_twin(stages):
    s = stages
    with torch.no_grad():
        ref = twins.raster_fwd(*s.twin_args())
    rtol, atol = TOL[s.dtype]
    for name, ours, expected in zip(("rgb", "features", "depth", "t_final"), s.out[:4], ref[:4], strict=True):
        assert_close(torch.from_numpy(ours), expected, rtol, atol, f"{s.name} raster_fwd {name}")
    last, ref_last = s.out[4], ref[4].numpy()
    # The last contributor depends on a threshold (T <= 1e-4); float32 rounding may move it at a few pixels.
    mismatch = float((last != ref_last).mean())
    assert mismatch <= (0 if s.dtype == torch.float64 else 0.01), (
        f"{s.name}: last contributor differs at {mismatch:.1%}"
    )
    assert (ref[3] < 1).float().mean() > 0.5, "the scene should cover most pixels"
    if s.name.startswith("opaque"):
        stopped = (ref_last > 0) & (ref_last < s.offsets[1:].max())
        assert float(ref[3].min()) < 1e-3 and stopped.any(), "some pixels should reach the transmittance stop"


@pytest.mark.parametrize("by_camera, need_values", [(False, True), (True, True), (False, False)])
def test_raster_backward_matches_twin(stages, by_camera, need_values):
    s = stages
    k = _kernels()
    v_rgb, v_feat, v_dep, v_t = s.cotangents(seed=5)
    threads = k.numba.get_num_threads()
    dt = s.values.dtype
    n = s.proj.shape[1]
    g2d = np.zeros((1 if by_camera else threads, s.n_cam, n, k.NGRAD), dt)
    gvals = np.zeros((threads, n if need_values else 0, s.values.shape[1]), dt)
    k.raster_bwd(
        s.proj, s.box, s.values, s.offsets, s.lists, s.tiles_x, s.width, s.height, np.array(k.CONSTS, dt),
        s.out[3], s.out[4], v_rgb, v_feat, v_dep, v_t, by_camera, threads, g2d, gvals, need_values,
    )  # fmt: skip
    t = torch.from_numpy
    ref_g2d, ref_gvals = twins.raster_bwd(*s.twin_args(), *(t(v).double() for v in (v_rgb, v_feat, v_dep, v_t)))
    rtol, atol = TOL[s.dtype]
    names = ("u", "v", "conic A", "conic B", "conic C", "opacity", "z")
    for i, name in enumerate(names):
        ref = ref_g2d[..., i]
        assert float(ref.abs().max()) > 0, f"twin gradient of {name} is zero"
        assert_close(t(g2d.sum(0)[..., i]), ref, 10 * rtol, 10 * atol, f"{s.name} raster_bwd d/d{name}")
    if need_values:
        assert_close(t(gvals.sum(0)), ref_gvals, 10 * rtol, 10 * atol, f"{s.name} raster_bwd d/dvalues")


def test_backward_buffers_do_not_depend_on_the_threads():
    """Each worker's gradient buffer holds the same sums, to the bit, whether one thread or two run
    the workers: a buffer per running thread made the sums' order, and the gradients' last bits,
    change from call to call (a float64 gradcheck's reentrancy check failed under load)."""
    k = _kernels()
    if k.numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs two numba threads")  # the comparison is between one thread and two
    s = Stages(*SCENES[1])  # 3 cameras: by tile, so the raster's g2d is per worker too
    v_rgb, v_feat, v_dep, v_t = s.cotangents(seed=9)
    dt, n, workers = s.values.dtype, s.proj.shape[1], 3  # more workers than threads: a thread runs several

    def backward():
        g2d = np.zeros((workers, s.n_cam, n, k.NGRAD), dt)
        gvals = np.zeros((workers, n, s.values.shape[1]), dt)
        k.raster_bwd(
            s.proj, s.box, s.values, s.offsets, s.lists, s.tiles_x, s.width, s.height, np.array(k.CONSTS, dt),
            s.out[3], s.out[4], v_rgb, v_feat, v_dep, v_t, False, workers, g2d, gvals, True,
        )  # fmt: skip
        outs = [np.zeros_like(a) for a in s.inputs] + [np.zeros((workers, s.n_cam, k.G_CAM_STRIDE))]
        k.project_bwd(*s.inputs[:3], s.cov, s.cams, s.box, g2d, *outs, True)
        return g2d, gvals, outs[-1]

    before = k.numba.get_num_threads()
    try:
        k.numba.set_num_threads(1)
        one = backward()
        k.numba.set_num_threads(2)
        two = backward()
    finally:
        k.numba.set_num_threads(before)
    for name, a, b in zip(("raster g2d", "raster value gradients", "pose gradients"), one, two, strict=True):
        assert all(a[w].any() for w in range(workers)), f"{name}: a worker's buffer is empty"
        assert np.array_equal(a, b), f"{name}: a worker's buffer differs between one thread and two"
