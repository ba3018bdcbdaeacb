"""Peak memory of the fast path must not grow with N x H x W (growth, not time).

Measured as the process's peak resident set during one forward+backward, after resetting the
kernel's high-water mark (``/proc/self/clear_refs``): this sees torch, numpy and numba's own
allocations alike (tracemalloc sees only numpy's). It runs in a subprocess with a fixed glibc
mmap threshold, so every large buffer is a fresh mapping instead of reused heap.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from aes_planner.gaussians import random_scene, rasterize
from aes_planner.gaussians.numba_backend import available

STATUS = Path("/proc/self/status")
CLEAR_REFS = Path("/proc/self/clear_refs")


def _kib(field: str) -> int:
    for line in STATUS.read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    raise RuntimeError(field)


def _can_measure() -> bool:
    try:
        CLEAR_REFS.write_text("5")
        return _kib("VmHWM") > 0
    except OSError:
        return False


def peak_mib(n: int, size: int, backend: str = "numba") -> float:
    """Extra peak resident memory (MiB) of one forward+backward."""
    g, world2cam, K = random_scene(n, 3, size, size, seed=1)
    g = g.requires_grad_()
    out = rasterize(g, world2cam, K, size, size, backend=backend)  # warm-up (kernels loaded)
    (out.rgb.sum() + out.depth.sum()).backward()
    del out
    before = _kib("VmRSS")
    CLEAR_REFS.write_text("5")  # reset VmHWM to the current RSS
    out = rasterize(g, world2cam, K, size, size, backend=backend)
    (out.rgb.sum() + out.features.sum() + out.depth.sum()).backward()
    return (_kib("VmHWM") - before) / 1024


@pytest.mark.skipif(not available() or not _can_measure(), reason="needs numba and /proc/self/clear_refs")
def test_peak_memory_is_additive_in_gaussians_and_pixels():
    # memory ~ a N + b HW + c N HW. With c = 0 the step from 32x32 to 128x128 pixels costs the
    # same for 1k and 16k Gaussians; a dense [N, H*W] float32 buffer would add
    # 15000 * 15360 * 4 B = 880 MiB to the second step.
    code = (
        f"import json, sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from test_memory import peak_mib\n"
        "print(json.dumps([peak_mib(n, s) for n, s in [(1000, 32), (1000, 128), (16000, 32), (16000, 128)]]))"
    )
    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="65536")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    values = json.loads(res.stdout.strip().splitlines()[-1])
    peak = dict(zip([(1000, 32), (1000, 128), (16000, 32), (16000, 128)], values))
    small_n = peak[1000, 128] - peak[1000, 32]
    large_n = peak[16000, 128] - peak[16000, 32]
    assert large_n < small_n + 16, peak  # MiB; allocator noise, never a dense term
    assert peak[16000, 128] < 200, peak
