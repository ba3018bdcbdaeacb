"""aes_planner.runtime: the thread count, torch's OpenMP spin count and glibc malloc's thresholds
(each checked in a fresh process, since all are process-wide)."""

import os
import subprocess
import sys

import pytest

from aes_planner.runtime import ThreadGovernor, available_cores, set_threads

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


def test_governor_keeps_all_threads_while_jobs_get_the_cores():
    gov = ThreadGovernor(2)
    for _ in range(50):
        assert gov.observe(0.56, 0.98) == 2  # idle: efficiency 0.88
    assert gov.changes == 0 and gov.last_efficiency == pytest.approx(0.98 / 1.12)


def test_governor_moves_to_one_thread_when_it_is_faster_and_probes_back():
    gov = ThreadGovernor(2, probe_every=4, max_probe_every=16)
    assert gov.observe(2.5, 2.5) == 2  # one core's worth on two threads (0.50), once: could be a cold start
    assert gov.observe(0.56, 0.98) == 2  # and it was
    assert [gov.observe(2.5, 2.5) for _ in range(2)] == [2, 1]  # twice in a row: a trial on one thread
    assert [gov.observe(0.8, 0.8) for _ in range(2)] == [1, 1] and not gov.trial  # it won: 0.8 s against 2.5 s
    assert [gov.observe(0.8, 0.8) for _ in range(2)] == [1, 2]  # 4 jobs since the switch: a probe on two
    assert gov.observe(2.4, 2.4) == 1 and gov.backoff == 8  # the probe lost: back, and probe later
    counts = [gov.observe(0.8, 0.8) for _ in range(8)]
    assert counts == [1] * 7 + [2]
    for _ in range(5):  # lost probes back off up to max_probe_every
        gov.observe(2.4, 2.4)
        while gov.observe(0.8, 0.8) == 1:
            pass
    assert gov.backoff == 16
    assert gov.observe(0.56, 0.98) == 2 and gov.backoff == 4  # the neighbour left: the probe won, keep two
    assert gov.observe(0.56, 0.98) == 2 and gov.changes == 4 + 2 * 5


def test_governor_keeps_all_threads_when_one_is_not_faster():
    """Low efficiency but coarse jobs: two threads still win (the closed loop's 2.6 s against 2.9 s)."""
    gov = ThreadGovernor(2, probe_every=4, max_probe_every=16)
    assert [gov.observe(2.6, 3.1) for _ in range(2)] == [2, 1]  # 0.60: a trial
    assert [gov.observe(2.9, 2.9) for _ in range(2)] == [1, 2]  # slower on one thread: back at once
    assert gov.quiet == 8 and gov.backoff == 8
    assert [gov.observe(2.6, 3.1) for _ in range(8)] == [2] * 8  # no new trial while quiet
    assert gov.observe(2.6, 3.1) == 1  # then, still slow, one more trial


def test_governor_ignores_short_and_broken_measurements():
    gov = ThreadGovernor(2)
    for wall, cpu in ((0.005, 0.0), (float("nan"), 1.0), (1.0, float("inf")), (-1.0, 0.0), (1.0, -1.0)):
        assert gov.observe(wall, cpu) == 2
    assert gov.changes == 0
    one = ThreadGovernor(1)
    assert all(one.observe(1.0, 0.1) == 1 for _ in range(100)) and one.changes == 0


@pytest.mark.parametrize("kw", [dict(max_threads=0), dict(max_threads=True), dict(low_efficiency=1.0),
                                dict(low_efficiency=0.0), dict(probe_every=0), dict(probe_every=9, max_probe_every=8), dict(patience=0)])  # fmt: skip
def test_governor_refuses_nonsense(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        ThreadGovernor(**{"max_threads": 2, **kw})


def test_available_cores_is_positive():
    assert 1 <= available_cores() <= (os.cpu_count() or 1)


def _fresh_threads(pin_first: bool) -> tuple[str, str, str]:
    code = (
        "import torch\n"
        "from aes_planner.runtime import set_threads\n"
        "from aes_planner.gaussians import numba_backend\n"
        + ("set_threads(1)\nnumba_backend.warmup()\n" if pin_first else "numba_backend.warmup()\nset_threads(1)\n")
        + "import numba\n"
        "print(torch.get_num_threads(), numba.get_num_threads(), numba.threading_layer())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    torch_threads, numba_threads, layer = out.stdout.split()
    return torch_threads, numba_threads, layer


def test_one_thread_set_before_the_kernels_load_holds_for_torch_and_numba_keeps_its_layer():
    """A count set before the rasterizer's kernels load (``suggest --threads 1``, a fresh process's
    first suggestion beside a busy one) must not start numba's pool early: that picked the ``omp``
    layer, whose start put torch back on all cores (perf-2). Fresh processes, as a user's."""
    early = _fresh_threads(pin_first=True)
    late = _fresh_threads(pin_first=False)  # the kernels loaded first: the package's own layer choice
    assert early[:2] == ("1", "1")
    assert early[2] == late[2]


_KERNEL = """
import numba, numpy as np

@numba.njit(cache=True)
def twice(x):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = 2.0 * x[i]
    return out
"""

_LOAD = """
import sys
sys.path.insert(0, {folder!r})
from numba.core import base
refreshes = []
original = base.BaseContext.refresh
base.BaseContext.refresh = lambda self: (refreshes.append(1), original(self))[1]
from aes_planner import runtime
light = runtime.light_numba_cache_loads() if {light} else False
import numpy as np, kernel_mod
y = kernel_mod.twice(np.arange(4.0))
print(light, len(refreshes), sum(kernel_mod.twice.stats.cache_hits.values()), y.tolist())
"""


def test_cached_kernels_load_without_numba_refreshing_its_registries(tmp_path):
    """A kernel numba cached on disk loads and runs with the light loads without a single refresh
    of numba's target context; numba's own load refreshes it (the ~65 ms of a cold `suggest` the
    light loads save); a compile (the first run) refreshes either way."""
    pytest.importorskip("numba")
    (tmp_path / "kernel_mod.py").write_text(_KERNEL)

    def run(light: bool) -> list[str]:
        out = subprocess.run(
            [sys.executable, "-c", _LOAD.format(folder=str(tmp_path), light=light)],
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.strip().split(" ", 3)

    first = run(True)  # compiles and writes the cache: numba's compiler refreshes its context
    assert first[0] == "True" and int(first[1]) >= 1 and first[2] == "0"
    assert run(True) == ["True", "0", "1", "[0.0, 2.0, 4.0, 6.0]"]  # from the cache, no refresh
    plain = run(False)  # numba's own load: the same kernel, after a refresh
    assert int(plain[1]) >= 1 and plain[2:] == ["1", "[0.0, 2.0, 4.0, 6.0]"]
