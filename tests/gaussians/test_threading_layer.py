"""numba's threading layer: TBB when oneTBB is installed (the rasterizer loads its library, which
pip puts off the loader's path), numba's workqueue otherwise, and an explicit
NUMBA_THREADING_LAYER always wins. Each case renders in a fresh process, since the layer is
fixed when numba first starts its threads."""

import importlib.metadata
import os
import platform
import subprocess
import sys

import pytest

from aes_planner.gaussians import numba_backend

SNIPPET = """
import numba
from aes_planner.gaussians import random_scene, rasterize
g, world2cam, K = random_scene(200, 3, 32, 32, 2, seed=0)
rasterize(g, world2cam, K, 32, 32)
print(numba.threading_layer())
"""


def _tbb_installed() -> bool:
    try:
        importlib.metadata.distribution("tbb")
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def _layer(env_layer: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    if env_layer is not None:
        env["NUMBA_THREADING_LAYER"] = env_layer
    out = subprocess.run([sys.executable, "-c", SNIPPET], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


pytestmark = pytest.mark.skipif(not numba_backend.available(), reason="numba is not installed")


def test_default_layer_is_tbb_when_installed_else_workqueue():
    # the package's requirements install tbb on x86-64 Linux, so there a missing TBB layer is a bug
    on_tbb_platform = sys.platform == "linux" and platform.machine() == "x86_64"
    expected = "tbb" if _tbb_installed() or on_tbb_platform else "workqueue"
    assert _layer(None) == expected


def test_explicit_layer_wins():
    assert _layer("workqueue") == "workqueue"


THREADS_SNIPPET = """
import threading
import numba
import torch
from aes_planner.gaussians import random_scene, rasterize
scenes = [random_scene(2000, 3, 32, 32, 4, seed=s) for s in range(2)]
for g, *_ in scenes:
    g.means.requires_grad_(True)
want = [rasterize(g, w, K, 32, 32).rgb.detach().clone() for g, w, K in scenes]
errors = []
def run(i):
    g, w, K = scenes[i]
    try:
        for _ in range(30):
            out = rasterize(g, w, K, 32, 32)
            out.rgb.sum().backward()
            assert torch.equal(out.rgb.detach(), want[i])
    except BaseException as exc:
        errors.append(repr(exc))
threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
[t.start() for t in threads]
[t.join() for t in threads]
print(numba.threading_layer(), errors)
"""


@pytest.mark.parametrize("layer", ["workqueue", None])
def test_two_threads_render_at_once_on_any_layer(layer):
    """numba's workqueue layer (where oneTBB is missing) aborted the process when two threads
    rendered at once ("Concurrent access has been detected"); renders take turns there."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    if layer is not None:
        env["NUMBA_THREADING_LAYER"] = layer
    out = subprocess.run([sys.executable, "-c", THREADS_SNIPPET], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1].endswith("[]"), out.stdout
