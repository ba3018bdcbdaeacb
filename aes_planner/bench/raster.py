"""Benchmark group ``raster``: the Gaussian rasterizer against the dense reference.

Keys per case (``raster.<case>.<figure>``), all per view:

* ``fwd_ms``, ``fwdbwd_ms``: the fast backend (numba when available), wall-clock medians.
* ``fwd_cpu_ms``, ``fwdbwd_cpu_ms``: process CPU time (all threads) in the same runs, medians:
  on a shared machine, where wall-clock depends on what else runs, this is the work done.
  Each of these four carries its spread over the runs beside it (``_min``, ``_max``).
* ``dense_fwd_ms``: the dense reference in float32 (a plain dense rasterizer) in the same run;
  ``speedup_fwd`` = dense / fast, its spread the slowest dense call over the fastest fast one
  and the other way round (``_min``, ``_max``, as ``dense_fwd_ms``'s). ``dense_fwdbwd_ms`` where
  the dense graph fits in memory.
* ``pairs``: Gaussian-pixel pairs with ``alpha >= 1/255`` in the view (the work a rasterizer
  cannot avoid, up to early termination); ``pairs_per_s_fwd``, ``pairs_per_s_fwdbwd``.
* ``cpu_<stage>_ms`` (numba backend): where the process CPU time of one forward+backward goes,
  from :func:`aes_planner.gaussians.numba_backend.profile_stages` in separate runs: the kernels
  ``project``, ``bin``, ``raster_fwd``, ``raster_bwd``, ``project_bwd``; ``glue`` = the numpy
  code around them inside the autograd Function; ``outside`` = everything else of the call
  (input checks, torch autograd, the loss and its ``backward()`` call).
* ``fwd_1thread_ms``, ``fwdbwd_1thread_ms`` (numba backend, the 10k 64x64 case): the same on one
  numba thread, i.e. the work; ``fwd_parallel_efficiency``, ``fwdbwd_parallel_efficiency``: that over
  the default threads' wall time times their count (a slow run with the work unchanged and the
  efficiency down lost its time to the threads' hand-offs, not to the kernels).
* ``dense_extrapolated``: 1 when the dense time was measured on a subset and scaled up: some
  cameras of a batch (with ``--quick`` one camera), and with ``--quick`` the top 1/32 of the rows
  when the image holds more than ``QUICK_DENSE_WHOLE_ENTRIES`` Gaussian-pixel entries (the 50k
  case; scaling the crop scales the call's fixed costs too, so its dense time is overstated).
  The dense reference runs in pixel chunks of ``DENSE_CHUNK_BYTES`` temporaries, the fastest
  chunking measured: it is timed at its best.

And ``raster.jit.compile_s`` (numba compile in an empty cache dir, full run only),
``raster.jit.cached_load_s`` (a new process: load the cached kernels and render once).
Scenes come from :func:`aes_planner.gaussians.random_scene` (Gaussians spread 2-6 m in front
of the cameras, 0.4-2.5 px standard deviation at 64 px, opacity 0.1-0.9).
"""

from __future__ import annotations

import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

import torch

from aes_planner.bench import Recorder, time_ms, time_wall_cpu_ms

log = logging.getLogger(__name__)

__all__ = ["CASES", "run"]


@dataclass(frozen=True)
class Case:
    n: int
    size: int  # width, px
    channels: int
    cameras: int
    dense_cameras: int  # cameras the dense reference renders (time scaled to per view)
    dense_backward: bool  # whether the dense autograd graph is affordable
    height: int | None = None  # px; None = square
    pose_grad_only: bool = False  # backward w.r.t. world2cam only (the search's refinement)
    opacity: tuple[float, float] = (0.1, 0.9)
    sigma_px: tuple[float, float] = (0.4, 2.5)  # random_scene's sigma_px_at_64
    # the Gaussians' O(N) checks in every call; the field checks its Gaussians once when it is
    # built and then renders with validate=False, so the search's cases leave them out as it does
    validate: bool = True
    # also time it on one thread (numba backend): the kernels' work without the second thread's
    # wake-ups and waits, so a slow run says whether the work or the threads' hand-offs were slow
    one_thread: bool = False


# The search's workload (a field search): a 4-view field of ~8k Gaussians (a 4-frame
# reconstruction of `indoor:3` gave 8321 under the default budget), D = 32 embedding channels
# (the paper's f_aes), 48x36 renders (render_width_px of `balanced`, 4:3 frames), mostly opaque
# Gaussians (the reconstruction's median opacity is 0.95); stage 1 scores batches of 64 poses
# (forward only), stage 2 refines the top 2 with gradients w.r.t. the poses only.
SEARCH_FIELD = dict(n=8_000, size=48, channels=32, height=36, opacity=(0.3, 0.99), dense_backward=False, validate=False)
# The shipped field's calls in a balanced suggestion (measured on held-out indoor:100 in round 4):
# 1611 Gaussians, 48x36, opacity 0.95, stage 1 in batches of 64 poses, stage 2 25 steps of 2 poses;
# 6k-28k pairs per view (median 15k), which Gaussians of 0.2-0.8 px (at 64 px width) give in the
# random scene. Values: C = 8 features (the teacher's map and D) plus the 3 colours, which carry
# the direction to each Gaussian's source camera (round 6; it was 11 features beside 3 unused
# colours before).
SEARCH_REAL = dict(
    n=1611,
    size=48,
    channels=8,
    height=36,
    opacity=(0.9, 0.99),
    sigma_px=(0.2, 0.8),
    dense_backward=False,
    validate=False,
)

DENSE_CHUNK_BYTES = 4 << 20  # one float32 [pixels, N] temporary of the dense reference, at most
QUICK_DENSE_WHOLE_ENTRIES = 48_000_000  # --quick renders the whole image up to this N x pixels (0.1-0.6 s a call)

CASES = {
    "10k_64x64_c3": Case(10_000, 64, 3, 1, 1, False, one_thread=True),
    "10k_32x32_c32": Case(10_000, 32, 32, 1, 1, True),
    "50k_128x128_c3": Case(50_000, 128, 3, 1, 1, False),
    "b64_10k_32x32_c32": Case(10_000, 32, 32, 64, 2, False),
    "search_s1_b64_8k_48x36_c32": Case(cameras=64, dense_cameras=2, pose_grad_only=True, **SEARCH_FIELD),
    "search_s2_b2_8k_48x36_c32": Case(cameras=2, dense_cameras=1, pose_grad_only=True, **SEARCH_FIELD),
    "search_s1_b64_1611_48x36_c8": Case(cameras=64, dense_cameras=2, pose_grad_only=True, **SEARCH_REAL),
    "search_s2_b2_1611_48x36_c8": Case(cameras=2, dense_cameras=1, pose_grad_only=True, **SEARCH_REAL),
}

_LOAD_SNIPPET = (
    "import time; t0 = time.perf_counter()\n"
    "import torch\n"
    "from aes_planner.gaussians import numba_backend\n"
    "t1 = time.perf_counter()\n"
    "numba_backend.warmup(torch.float32)\n"
    "print(time.perf_counter() - t1, t1 - t0)\n"
)


def _count_pairs(g, world2cam, K, width, height, rows: int) -> int:
    """Pairs with alpha >= 1/255 in the first ``rows`` rows of camera 0 (chunked, no grad)."""
    from aes_planner.gaussians.numerics import ALPHA_MIN, SIGMA_CLAMP
    from aes_planner.gaussians.projection import project

    with torch.no_grad():
        p = project(g.means, g.quats, g.log_scales, g.opacities, world2cam[:1], K[:1], width, height)
        keep = p.visible[0]
        uv, conic, o = p.means2d[0, keep].float(), p.conics[0, keep].float(), g.opacities[keep].float()
        total = 0
        ys = torch.arange(rows, dtype=torch.float32) + 0.5
        xs = torch.arange(width, dtype=torch.float32) + 0.5
        for y in ys.split(max(1, 2048 // width)):
            pix = torch.stack(torch.meshgrid(y, xs, indexing="ij"), -1).reshape(-1, 2)[:, [1, 0]]
            d = pix[:, None, :] - uv[None]
            sigma = (
                0.5 * (conic[:, 0] * d[..., 0] ** 2 + conic[:, 2] * d[..., 1] ** 2)
                + conic[:, 1] * d[..., 0] * d[..., 1]
            )
            alpha = (o * torch.exp(-sigma.clamp(0, SIGMA_CLAMP))).clamp(max=0.99)
            total += int(((alpha >= ALPHA_MIN) & (sigma >= 0)).sum())
    return total


def _bench_case(rec: Recorder, name: str, case: Case, quick: bool) -> None:
    from aes_planner.gaussians import random_scene, rasterize, resolve_backend
    from aes_planner.gaussians.reference import rasterize_dense

    size, height, views = case.size, case.height or case.size, case.cameras
    g, world2cam, K = random_scene(
        case.n, case.channels, size, height, views, seed=0, opacity=case.opacity, sigma_px_at_64=case.sigma_px
    )
    runs = 9 if quick else 15  # medians: --quick too takes enough runs that one slow call cannot move them
    prefix = f"raster.{name}"

    def fwd():
        with torch.no_grad():
            rasterize(g, world2cam, K, size, height, validate=case.validate)

    gg = g.clone() if case.pose_grad_only else g.clone().requires_grad_()
    w2c = world2cam.clone().requires_grad_()

    def fwdbwd():
        # gradients set to None first, as optimizer.zero_grad() does: accumulating into the previous
        # call's .grad would time torch's in-place adds (which wake its thread pool), not the rasterizer
        for t in (gg.means, gg.quats, gg.log_scales, gg.opacities, gg.colors, gg.features, w2c):
            t.grad = None
        out = rasterize(gg, w2c, K, size, height, validate=case.validate)
        (out.rgb.sum() + out.features.sum() + out.depth.sum() + out.alpha.sum()).backward()

    samples = {}  # per view, with their spread: the machine is shared and a median alone hides it
    samples["fwd_ms"], samples["fwd_cpu_ms"] = time_wall_cpu_ms(fwd, runs)
    samples["fwdbwd_ms"], samples["fwdbwd_cpu_ms"] = time_wall_cpu_ms(fwdbwd, runs)
    fast_fwd, cpu_fwd, fast_fb, cpu_fb = (
        rec.record_spread(f"{prefix}.{figure}", [v / views for v in samples[figure]], "ms")
        for figure in ("fwd_ms", "fwd_cpu_ms", "fwdbwd_ms", "fwdbwd_cpu_ms")
    )

    if resolve_backend("auto") == "numba":
        _breakdown(rec, prefix, fwdbwd, runs, views)
        if case.one_thread:
            _one_thread(rec, prefix, fwd, fwdbwd, runs, views, fast_fwd, fast_fb)

    # Dense reference (float32 per-pixel maths) on the same scene, in the same run. A crop to the
    # top rows is the same camera with a smaller height (pixel centres do not depend on it).
    whole = not quick or case.n * size * height <= QUICK_DENSE_WHOLE_ENTRIES
    rows = height if whole else height // 32
    dense_views = case.dense_cameras if not quick else 1
    extrapolated = rows < height or dense_views < views
    scale = height / rows  # a crop's time scaled by the pixel count (its fixed costs too: an overestimate)

    # The reference timed at its best: pixel chunks of 4 MiB [pixels, N] temporaries were the
    # fastest of 2-64 MiB in three cases. Temporaries over glibc's mmap threshold (32 MiB, fixed by
    # aes_planner.runtime.tune_malloc) are mapped and faulted in afresh on every call: its default
    # chunk of 4096 px made the same call up to 2.8x slower (docs/journal/rasterizer.md, "Why 10k
    # 32x32 C=32 stays under 100x").
    chunk = max(64, DENSE_CHUNK_BYTES // (4 * max(case.n, 1)))

    def dense():
        with torch.no_grad():
            rasterize_dense(
                g, world2cam[:dense_views], K[:dense_views], size, rows, pixel_chunk=chunk, compute_dtype=torch.float32
            )

    # --quick's dense calls (whole images up to 48M entries, else a crop) are cheap enough for a
    # warm-up call and a median of 3 (one cold call moved 20-30 % between runs); the full 50k image
    # takes ~11 s a call, so it is timed once
    dense_runs = 3 if (quick or case.n < 50_000) else 1
    dense_warmup = 1 if quick else 0
    dense_ms = [t / dense_views * scale for t in time_ms(dense, runs=dense_runs, warmup=dense_warmup)]
    dense_fwd = rec.record_spread(f"{prefix}.dense_fwd_ms", dense_ms, "ms")
    rec.record(f"{prefix}.speedup_fwd", dense_fwd / fast_fwd, "x", dense_runs)
    # its spread: the slowest dense call over the fastest kernel call, and the other way round
    fwd_min, fwd_max = (rec.results[f"{prefix}.fwd_ms{e}"]["value"] for e in ("_min", "_max"))
    rec.record(f"{prefix}.speedup_fwd_min", min(dense_ms) / fwd_max, "x", dense_runs)
    rec.record(f"{prefix}.speedup_fwd_max", max(dense_ms) / fwd_min, "x", dense_runs)
    rec.record(f"{prefix}.dense_extrapolated", float(extrapolated), "bool")
    if case.dense_backward and not quick:

        def dense_fb():
            h = g.clone().requires_grad_()
            w = world2cam[:1].clone().requires_grad_()
            out = rasterize_dense(h, w, K[:1], size, height, compute_dtype=torch.float32, pixel_chunk=256)
            (out["rgb"].sum() + out["features"].sum() + out["depth"].sum() + out["alpha"].sum()).backward()

        dense_fb_ms = statistics.median(time_ms(dense_fb, runs=1, warmup=0))
        rec.record(f"{prefix}.dense_fwdbwd_ms", dense_fb_ms, "ms", 1)
        rec.record(f"{prefix}.speedup_fwdbwd", dense_fb_ms / fast_fb, "x", 1)

    pairs = _count_pairs(g, world2cam, K, size, height, rows) * scale
    rec.record(f"{prefix}.pairs", pairs, "pairs")
    rec.record(f"{prefix}.pairs_per_s_fwd", pairs / (fast_fwd / 1e3), "1/s")
    rec.record(f"{prefix}.pairs_per_s_fwdbwd", pairs / (fast_fb / 1e3), "1/s")
    log.info(
        "%s: fwd %.2f ms, fwd+bwd %.2f ms per view, dense %.0f ms (%.0fx)",
        name,
        fast_fwd,
        fast_fb,
        dense_fwd,
        dense_fwd / fast_fwd,
    )


KERNELS = ("project", "bin", "raster_fwd", "raster_bwd", "project_bwd")


def _breakdown(rec: Recorder, prefix: str, fwdbwd, runs: int, views: int) -> None:
    """Per-view process CPU ms of one forward+backward by stage (kernels, glue, outside)."""
    from aes_planner.gaussians import numba_backend

    total = 0.0
    with numba_backend.profile_stages() as prof:
        for _ in range(runs):
            c0 = time.process_time()
            fwdbwd()
            total += time.process_time() - c0
    per = {name: prof[name][0] / runs / views * 1e3 for name in (*KERNELS, "fwd_body", "bwd_body")}
    for name in KERNELS:
        rec.record(f"{prefix}.cpu_{name}_ms", per[name], "ms", runs)
    glue = per["fwd_body"] + per["bwd_body"] - sum(per[name] for name in KERNELS)
    rec.record(f"{prefix}.cpu_glue_ms", glue, "ms", runs)
    rec.record(f"{prefix}.cpu_outside_ms", total / runs / views * 1e3 - per["fwd_body"] - per["bwd_body"], "ms", runs)


def _one_thread(
    rec: Recorder, prefix: str, fwd, fwdbwd, runs: int, views: int, fast_fwd: float, fast_fb: float
) -> None:
    """The case on one numba thread (``fwd_1thread_ms``, ``fwdbwd_1thread_ms``: wall, which on one
    thread is its CPU, the work), and the default threads' parallel efficiency against it
    (``fwd_parallel_efficiency`` = one-thread time / (threads x wall time on them); 1 = the threads
    split the work with nothing lost). Two runs of the same code a day apart gave this case's
    forward 1.35 and 1.96 ms on 2 threads (docs/benchmarks.md, "perf-2, session 28"): this says
    whether the work or the threads' hand-offs were slower."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one_fwd, _ = time_wall_cpu_ms(fwd, runs)
        one_fb, _ = time_wall_cpu_ms(fwdbwd, runs)
    finally:
        numba.set_num_threads(threads)
    one_fwd_ms = rec.record_spread(f"{prefix}.fwd_1thread_ms", [v / views for v in one_fwd], "ms")
    one_fb_ms = rec.record_spread(f"{prefix}.fwdbwd_1thread_ms", [v / views for v in one_fb], "ms")
    rec.record(f"{prefix}.fwd_parallel_efficiency", one_fwd_ms / (threads * fast_fwd), "ratio", runs)
    rec.record(f"{prefix}.fwdbwd_parallel_efficiency", one_fb_ms / (threads * fast_fb), "ratio", runs)


def _subprocess_seconds(env: dict) -> tuple[float, float]:
    out = subprocess.run(
        [sys.executable, "-c", _LOAD_SNIPPET], capture_output=True, text=True, env=env, timeout=900, check=True
    )
    kernel_s, import_s = (float(v) for v in out.stdout.split()[-2:])
    return kernel_s, import_s


def _bench_jit(rec: Recorder, quick: bool) -> None:
    env = dict(os.environ)
    if not quick:
        with tempfile.TemporaryDirectory() as cache:
            cold = dict(env, NUMBA_CACHE_DIR=cache)
            compile_s, _ = _subprocess_seconds(cold)
            rec.record("raster.jit.compile_s", compile_s, "s")
            load_s, import_s = _subprocess_seconds(cold)
    else:
        _subprocess_seconds(env)  # make sure the default cache is populated
        load_s, import_s = _subprocess_seconds(env)
    rec.record("raster.jit.cached_load_s", load_s, "s")
    rec.record("raster.jit.import_s", import_s, "s")


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.gaussians import numba_backend, resolve_backend

    backend = resolve_backend("auto")
    info = {"backend": backend, "torch_threads": torch.get_num_threads()}
    if backend == "numba":
        import numba

        numba_backend.warmup(torch.float32)
        info.update(
            numba=numba.__version__, threading_layer=numba.threading_layer(), numba_threads=numba.get_num_threads()
        )
    rec.meta["backends"]["raster"] = info
    rec.meta.setdefault("load_average", {})["raster_start"] = os.getloadavg()
    t0 = time.perf_counter()
    for name, case in CASES.items():
        _bench_case(rec, name, case, quick)
    if backend == "numba":
        _bench_jit(rec, quick)
    rec.meta["load_average"]["raster_end"] = os.getloadavg()
    log.info("raster group took %.1f s", time.perf_counter() - t0)
