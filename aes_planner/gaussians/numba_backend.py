"""The compiled CPU backend: numba kernels of :mod:`aes_planner.gaussians._kernels` behind one
``torch.autograd.Function``. Importing this module imports numba (and loads the cached kernels
on first use); :func:`available` says whether that works without raising.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch
from torch import Tensor

log = logging.getLogger(__name__)

__all__ = ["available", "render", "warmup"]

_kernels = None
_import_error: str | None = None


def _load():
    global _kernels, _import_error
    if _kernels is None and _import_error is None:
        try:
            from aes_planner.gaussians import _kernels as k

            _kernels = k
        except ImportError as exc:  # numba missing or broken
            _import_error = f"{type(exc).__name__}: {exc}"
            log.info("numba backend unavailable: %s", _import_error)
    return _kernels


def available() -> bool:
    """True when numba imports (the kernels compile or load from cache on first call)."""
    return _load() is not None


def _np(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _forward_arrays(means, quats, log_scales, opacities, values, world2cam, K, width, height):
    """Run the forward pipeline on numpy arrays; returns (out, t_final, state for backward)."""
    k = _kernels
    dtype = means.dtype
    n_cam, n = world2cam.shape[0], means.shape[0]
    tiles_x = -(-width // k.TILE)
    tiles_y = -(-height // k.TILE)
    n_tiles = tiles_x * tiles_y
    cov = np.empty((n, 6))
    proj = np.empty((n_cam, n, k.NPROJ), dtype)
    box = np.empty((n_cam, n, 4), np.int32)
    if n:
        k.covariance_fwd(quats, log_scales, cov)
        k.project_fwd(means, cov, opacities, world2cam, K, width, height, proj, box)
    order = np.empty((n_cam, n), np.int32)
    n_visible = np.zeros(n_cam, np.int64)
    counts = np.zeros((n_cam, n_tiles), np.int64)
    if n:
        k.bin_count(proj, box, tiles_x, order, n_visible, counts)
    offsets = np.zeros(n_cam * n_tiles + 1, np.int64)
    np.cumsum(counts.reshape(-1), out=offsets[1:])
    lists = np.empty(int(offsets[-1]), np.int32)
    if n:
        k.bin_fill(box, tiles_x, order, n_visible, offsets, lists)
    out = np.empty((n_cam, values.shape[1] + 1, height, width), dtype)
    t_final = np.empty((n_cam, height, width), dtype)
    last = np.empty((n_cam, height, width), np.int32)
    k.raster_fwd(proj, box, values, offsets, lists, tiles_x, width, height, out, t_final, last)
    state = (cov, proj, box, offsets, lists, tiles_x, last)
    return out, t_final, state


class _Raster(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, log_scales, opacities, values, world2cam, K, width, height):
        arrays = [_np(t) for t in (means, quats, log_scales, opacities, values)]
        w2c = _np(world2cam.to(torch.float64))
        kk = _np(K.to(torch.float64))
        out, t_final, state = _forward_arrays(*arrays, w2c, kk, width, height)
        ctx.arrays = arrays
        ctx.camera = (w2c, kk, width, height, world2cam.dtype)
        ctx.state = state
        ctx.t_final = t_final
        return torch.from_numpy(out), torch.from_numpy(t_final)

    @staticmethod
    def backward(ctx, v_out, v_t):
        k = _kernels
        means, quats, log_scales, opacities, values = ctx.arrays
        w2c, kk, width, height, cam_dtype = ctx.camera
        cov, proj, box, offsets, lists, tiles_x, last = ctx.state
        dtype = means.dtype
        n_cam, n = w2c.shape[0], means.shape[0]
        threads = k.numba.get_num_threads()
        by_camera = n_cam >= 2 * threads
        g2d = np.zeros((1 if by_camera else threads, n_cam, n, k.NGRAD), dtype)
        gvals = np.zeros((threads, n, values.shape[1]), dtype)
        tdtype = torch.from_numpy(values[:0]).dtype
        v_out_np = _np(v_out.to(tdtype))
        v_t_np = _np(v_t.to(tdtype))
        k.raster_bwd(proj, box, values, offsets, lists, tiles_x, width, height, ctx.t_final, last,
                     v_out_np, v_t_np, by_camera, g2d, gvals)
        g_means = np.empty_like(means)
        g_quats = np.empty_like(quats)
        g_log_scales = np.empty_like(log_scales)
        g_opac = np.empty_like(opacities)
        g_cam = np.zeros((threads, n_cam, 12))
        if n:
            k.project_bwd(means, quats, log_scales, cov, w2c, kk, width, height, box, g2d,
                          g_means, g_quats, g_log_scales, g_opac, g_cam)
        g_w2c = torch.zeros(n_cam, 4, 4, dtype=torch.float64)
        g_w2c[:, :3, :] = torch.from_numpy(g_cam.sum(0).reshape(n_cam, 3, 4))
        return (
            torch.from_numpy(g_means), torch.from_numpy(g_quats), torch.from_numpy(g_log_scales),
            torch.from_numpy(g_opac), torch.from_numpy(gvals.sum(0)), g_w2c.to(cam_dtype), None, None, None,
        )


def render(means, quats, log_scales, opacities, values, world2cam, K, width, height):
    """(out [B, Cv + 1, H, W], t_final [B, H, W]) with autograd; inputs already validated."""
    if _load() is None:
        raise RuntimeError(f"numba backend unavailable: {_import_error}")
    return _Raster.apply(means, quats, log_scales, opacities, values, world2cam, K, width, height)


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
        torch.rand(n, 4, generator=g, dtype=dtype),
    ]
    for p in params:
        p.requires_grad_(True)
    w2c = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1).requires_grad_(True)
    K = torch.tensor([[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]], dtype=torch.float64).repeat(2, 1, 1)
    out, t = render(*params, w2c, K, 16, 16)
    (out.sum() + t.sum()).backward()
    return time.perf_counter() - t0
