"""The compiled kernels are cached on disk, so a second process loads instead of compiling
(checked through numba's cache statistics, not through timing)."""

import json
import subprocess
import sys

import pytest
import torch

from aes_planner.gaussians import numba_backend, warmup

SNIPPET = """
import json, torch
from aes_planner.gaussians import numba_backend
numba_backend.warmup(torch.float32)
k = numba_backend._kernels
names = ["camera_table", "project_fwd", "bin_and_fill", "raster_fwd", "raster_bwd", "project_bwd"]
print(json.dumps({n: [getattr(k, n).stats.cache_hits.total(), getattr(k, n).stats.cache_misses.total()] for n in names}))
"""


@pytest.mark.skipif(not numba_backend.available(), reason="numba is not installed")
def test_second_process_loads_every_kernel_from_cache():
    numba_backend.warmup(torch.float32)  # this process compiles (or loads) and writes the cache
    out = subprocess.run([sys.executable, "-c", SNIPPET], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    stats = json.loads(out.stdout.strip().splitlines()[-1])
    for name, (hits, misses) in stats.items():
        assert hits >= 1 and misses == 0, f"{name}: {hits} cache hits, {misses} misses (not cacheable?)"


@pytest.mark.skipif(not numba_backend.available(), reason="numba is not installed")
def test_warmup_command_readies_the_kernels(capsys, monkeypatch):
    from aes_planner.cli import main

    monkeypatch.delenv("AES_PLANNER_RASTER_BACKEND", raising=False)
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "rasterizer kernels ready" in out and "composition head ready" in out
    assert warmup.warm_kernels() < warmup.COMPILED_AFTER_S  # in this process: loaded already


def test_warmup_has_nothing_to_do_on_the_torch_backend(capsys, monkeypatch):
    from aes_planner.cli import main

    monkeypatch.setenv("AES_PLANNER_RASTER_BACKEND", "torch")
    assert warmup.warm_kernels() is None
    assert main(["warmup"]) == 0
    assert "nothing to compile" in capsys.readouterr().out
