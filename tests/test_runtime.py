"""aes_planner.runtime: the thread count and glibc malloc's thresholds (each checked in a fresh
process, since both are process-wide)."""

import os
import subprocess
import sys

import pytest

from aes_planner.runtime import set_threads

SNIPPET = """
import ctypes
from aes_planner.runtime import tune_malloc
first = tune_malloc()
print(first, tune_malloc() == first)
"""


def _run(env_extra: dict) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")} | env_extra
    out = subprocess.run([sys.executable, "-c", SNIPPET], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_tune_malloc_fixes_the_thresholds_once():
    assert _run({}) == ["True", "True"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_tune_malloc_leaves_an_explicit_choice_alone():
    assert _run({"MALLOC_MMAP_THRESHOLD_": "131072"}) == ["False", "True"]


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_set_threads_refuses_nonsense(bad):
    with pytest.raises(ValueError, match="threads"):
        set_threads(bad)
