"""The compiled CPU backend: numba kernels of :mod:`aes_planner.gaussians.kernels` behind one
``torch.autograd.Function``. numba is imported on first use (and the cached kernels loaded);
:func:`available` says whether that works, without raising.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import defaultdict

import numpy as np
import torch
from torch import Tensor

from aes_planner.gaussians.grad_mode import autograd_on
from aes_planner.gaussians.numerics import DEPTH_ALPHA_MIN, TILE

log = logging.getLogger(__name__)

__all__ = ["available", "profile_stages", "render", "warmup"]

_kernels = None
_import_error: str | None = None
_profile: dict[str, list[float]] | None = None  # stage -> [process CPU s, wall s, calls] while profiling


@contextlib.contextmanager
def profile_stages():
    """Collect process CPU and wall seconds per stage of every render in the block: the kernels
    (``project``, ``bin``, ``raster_fwd``, ``raster_bwd``, ``project_bwd``) and the bodies of the
    autograd Function (``fwd_body``, ``bwd_body``: kernels plus the numpy glue around them).
    Yields the dict ``{stage: [cpu_s, wall_s, calls]}``; not thread-safe (a measuring aid)."""
    global _profile
    _profile = defaultdict(lambda: [0.0, 0.0, 0])
    try:
        yield _profile
    finally:
        _profile = None


@contextlib.contextmanager
def _stage(name: str):
    if _profile is None:
        yield
        return
    c0, w0 = time.process_time(), time.perf_counter()
    try:
        yield
    finally:
        entry = _profile[name]
        entry[0] += time.process_time() - c0
        entry[1] += time.perf_counter() - w0
        entry[2] += 1


_serial_lock = threading.Lock()


def _serialised():
    """numba's ``workqueue`` layer (where oneTBB is missing: off x86-64 Linux) aborts the process
    when two threads run parallel kernels at once; there, and until the first parallel call says
    which layer runs, renders take turns. TBB and OpenMP run them side by side."""
    try:
        layer = _kernels.numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet
        layer = None
    return _serial_lock if layer in (None, "workqueue") else contextlib.nullcontext()


def _load():
    global _kernels, _import_error
    if _kernels is None and _import_error is None:
        try:
            from aes_planner.gaussians import kernels as k
            from aes_planner.runtime import apply_pending_numba_threads, tune_malloc

            tune_malloc()  # before the first kernel's buffers (aes_planner.runtime says why)
            _kernels = k
            apply_pending_numba_threads()  # a count set before the kernels chose their threading layer
        except ImportError as exc:  # numba missing or broken
            _import_error = f"{type(exc).__name__}: {exc}"
            log.info("numba backend unavailable: %s", _import_error)
    return _kernels


def available() -> bool:
    """True when numba imports (the kernels compile or load from cache on first call)."""
    return _load() is not None


def _np(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _forward_arrays(means, quats, log_scales, opacities, values, channels, world2cam, K, width, height):
    """Run the forward pipeline on numpy arrays: (rgb, features, depth_sum, t_final, state)."""
    k = _kernels
    dtype = means.dtype
    n_cam, n = world2cam.shape[0], means.shape[0]
    tiles_x = -(-width // TILE)
    tiles_y = -(-height // TILE)
    n_tiles = tiles_x * tiles_y
    cov = np.empty((n, 6))
    proj = np.empty((n_cam, n, k.NPROJ), dtype)
    box = np.empty((n_cam, n, 4), np.int32)
    threads = k.numba.get_num_threads()
    cams = k.camera_table(world2cam, K, width, height)  # [B, NCAM], the backward's too
    with _stage("project"):
        if n:
            k.project_fwd(means, quats, log_scales, opacities, cams, width, height, cov, proj, box)
    with _stage("bin"):
        if n:  # cameras over threads; one camera: its sort beside its count
            offsets, lists = k.bin_and_fill(proj, box, tiles_x, n_tiles, threads > 1)
        else:
            offsets, lists = np.zeros(n_cam * n_tiles + 1, np.int64), np.empty(0, np.int32)
    rgb = np.empty((n_cam, 3, height, width), dtype)
    feat = np.empty((n_cam, channels, height, width), dtype)
    depth_sum = np.empty((n_cam, height, width), dtype)
    t_final = np.empty((n_cam, height, width), dtype)
    last = np.empty((n_cam, height, width), np.int32)
    consts = np.array(k.CONSTS, dtype)
    # the leading arguments that raster_fwd and raster_bwd share, in their order
    tiles = (proj, box, values, offsets, lists, tiles_x, width, height, consts)
    with _stage("raster_fwd"):
        k.raster_fwd(*tiles, threads, rgb, feat, depth_sum, t_final, last)
    state = (cov, box, tiles, last, cams)
    return rgb, feat, depth_sum, t_final, state


def _contiguous(t: Tensor, dtype) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy(), dtype=dtype)


class _Raster(torch.autograd.Function):
    """Everything between the tensors and the kernels is numpy: torch ops above its parallel
    grain size wake torch's OpenMP pool, whose spinning threads then compete with numba's for
    the cores (figures: docs/benchmarks.md, "Figures behind code comments")."""

    @staticmethod
    def forward(ctx, *args):
        with _stage("fwd_body"), _serialised():
            return _Raster._forward(ctx, *args)

    @staticmethod
    def backward(ctx, *grads):
        with _stage("bwd_body"), _serialised():
            return _Raster._backward(ctx, *grads)

    @staticmethod
    def _forward(ctx, means, quats, log_scales, opacities, colors, features, background, world2cam, K, width, height):
        arrays = [_np(t) for t in (means, quats, log_scales, opacities)]
        dtype = arrays[0].dtype
        values = np.concatenate([_np(colors), _np(features)], axis=1)  # [N, 3 + C]
        w2c = _np(world2cam.to(torch.float64))
        kk = _np(K.to(torch.float64))
        channels = features.shape[1]
        rgb, feat, depth_sum, t_final, state = _forward_arrays(*arrays, values, channels, w2c, kk, width, height)
        alpha = 1 - t_final
        depth = depth_sum / np.maximum(alpha, DEPTH_ALPHA_MIN)
        bg = None if background is None else _np(background).astype(dtype, copy=False)  # [1 or B, 3]
        if bg is not None:
            rgb += bg[:, :, None, None] * t_final[:, None]
        ctx.arrays, ctx.values, ctx.bg = arrays, values, bg
        ctx.camera = (w2c, world2cam.dtype)
        ctx.state = state
        ctx.maps = (t_final, alpha, depth_sum)
        return torch.from_numpy(rgb), torch.from_numpy(feat), torch.from_numpy(depth), torch.from_numpy(alpha)

    @staticmethod
    def _backward(ctx, v_rgb, v_feat, v_depth, v_alpha):
        k = _kernels
        means, quats, log_scales, opacities = ctx.arrays
        values, bg = ctx.values, ctx.bg
        w2c, cam_dtype = ctx.camera
        cov, box, tiles, last, cams = ctx.state
        t_final, alpha, depth_sum = ctx.maps
        dtype = means.dtype
        v_rgb, v_feat, v_depth, v_alpha = (_contiguous(v, dtype) for v in (v_rgb, v_feat, v_depth, v_alpha))
        # depth = depth_sum / max(alpha, eps); alpha = 1 - T; rgb = rgb_sum + bg T
        inv = 1 / np.maximum(alpha, DEPTH_ALPHA_MIN)
        v_depth_sum = v_depth * inv
        v_alpha = v_alpha - np.where(alpha > DEPTH_ALPHA_MIN, v_depth * depth_sum * inv * inv, 0)
        v_t = -v_alpha
        g_bg = None
        if bg is not None:
            v_t += np.einsum("bchw,bc->bhw", v_rgb, np.broadcast_to(bg, (v_rgb.shape[0], 3)))
            g_bg = np.einsum("bchw,bhw->bc", v_rgb, t_final)
            if bg.shape[0] == 1:
                g_bg = g_bg.sum(0, keepdims=True)
        n_cam, n = w2c.shape[0], means.shape[0]
        threads = k.numba.get_num_threads()
        by_camera = n_cam >= 2 * threads
        # Gradients the caller does not need are not computed (the search differentiates the poses only).
        need_gaussians = any(ctx.needs_input_grad[:4])  # means, quats, log_scales, opacities
        need_values = any(ctx.needs_input_grad[4:6])  # colors, features
        g2d = np.zeros((1 if by_camera else threads, n_cam, n, k.NGRAD), dtype)
        gvals = np.zeros((threads, n if need_values else 0, values.shape[1]), dtype)
        with _stage("raster_bwd"):
            k.raster_bwd(
                *tiles, t_final, last, v_rgb, v_feat, v_depth_sum, v_t, by_camera, threads, g2d, gvals, need_values
            )
        g_means = np.empty_like(means)
        g_quats = np.empty_like(quats)
        g_log_scales = np.empty_like(log_scales)
        g_opac = np.empty_like(opacities)
        g_cam = np.zeros((threads, n_cam, k.G_CAM_STRIDE))
        need_pose = ctx.needs_input_grad[7]  # world2cam
        with _stage("project_bwd"):
            if n and (need_gaussians or need_pose):  # e.g. not for a reconstruction's blending weights
                k.project_bwd(
                    means,
                    quats,
                    log_scales,
                    cov,
                    cams,
                    box,
                    g2d,
                    g_means,
                    g_quats,
                    g_log_scales,
                    g_opac,
                    g_cam,
                    need_gaussians,
                )
        g_w2c = np.zeros((n_cam, 4, 4))
        g_w2c[:, :3, :] = g_cam[..., : k.NPOSE].sum(0).reshape(n_cam, 3, 4)
        g_values = gvals.sum(0) if threads > 1 else gvals[0]
        g_gauss = [
            torch.from_numpy(a) if need_gaussians and n else None for a in (g_means, g_quats, g_log_scales, g_opac)
        ]
        if need_gaussians and not n:
            g_gauss = [torch.from_numpy(np.zeros_like(a)) for a in (means, quats, log_scales, opacities)]
        return (
            *g_gauss,
            torch.from_numpy(np.ascontiguousarray(g_values[:, :3])) if need_values else None,
            torch.from_numpy(np.ascontiguousarray(g_values[:, 3:])) if need_values else None,
            None if g_bg is None else torch.from_numpy(g_bg.astype(dtype, copy=False)),
            torch.from_numpy(g_w2c.astype(w2c.dtype)).to(cam_dtype) if need_pose else None,
            None,
            None,
            None,
        )


def render(means, quats, log_scales, opacities, colors, features, background, world2cam, K, width, height):
    """(rgb [B,3,H,W], features [B,C,H,W], depth [B,H,W], alpha [B,H,W]) with autograd; inputs
    already validated; ``background`` is None or [1 or B, 3] in the Gaussians' dtype."""
    if _load() is None:
        raise RuntimeError(f"numba backend unavailable: {_import_error}")
    return _Raster.apply(means, quats, log_scales, opacities, colors, features, background, world2cam, K, width, height)


def warmup(dtype: torch.dtype = torch.float32) -> float:
    """Compile (or load from numba's cache) every kernel for ``dtype``; returns seconds taken."""
    t0 = time.perf_counter()
    g = torch.Generator().manual_seed(0)
    n = 8
    params = [
        torch.randn(n, 3, generator=g, dtype=dtype) * 0.2 + torch.tensor([0.0, 0.0, 3.0], dtype=dtype),
        torch.randn(n, 4, generator=g, dtype=dtype),
        torch.full((n, 3), -2.0, dtype=dtype),
        torch.full((n,), 0.5, dtype=dtype),
        torch.rand(n, 3, generator=g, dtype=dtype),
        torch.rand(n, 1, generator=g, dtype=dtype),
        torch.rand(1, 3, generator=g, dtype=dtype),
    ]
    for p in params:
        p.requires_grad_(True)
    w2c = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1).requires_grad_(True)
    K = torch.tensor([[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]], dtype=torch.float64).repeat(2, 1, 1)
    with autograd_on():  # the backward kernels compile too, also under a caller's no_grad
        outputs = render(*params, w2c, K, 16, 16)
        sum(o.sum() for o in outputs).backward()
    return time.perf_counter() - t0
