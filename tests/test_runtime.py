"""aes_planner.runtime: the thread count, torch's OpenMP spin count and glibc malloc's thresholds
(each checked in a fresh process, since all are process-wide)."""

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


SPIN_SNIPPET = """
import os, sys
import aes_planner
print(os.environ.get("GOMP_SPINCOUNT", "unset"), "torch" in sys.modules)
"""
OMP_VARS = ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")


def _run(env_extra: dict, snippet: str = SNIPPET) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k not in OMP_VARS} | env_extra
    out = subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True, env=env, timeout=120)
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


def test_package_import_sets_the_spin_count_before_torch_loads():
    from aes_planner.runtime import GOMP_SPINCOUNT

    # torch not yet imported: libgomp will read the value when it loads
    assert _run({}, SPIN_SNIPPET) == [str(GOMP_SPINCOUNT), "False"]


@pytest.mark.parametrize("env", [{"GOMP_SPINCOUNT": "5"}, {"OMP_WAIT_POLICY": "passive"}])
def test_spin_count_leaves_an_explicit_choice_alone(env):
    expected = env.get("GOMP_SPINCOUNT", "unset")
    assert _run(env, SPIN_SNIPPET) == [expected, "False"]
