"""One mechanism picks the thread count of every suggestion: the library's
search, ``suggest``, ``bench search`` and the planner node all run their compute inside
``aes_planner.runtime.suggestion_threads``; outside a node it starts from the cores idle now."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
import torch

from aes_planner import runtime
from aes_planner.runtime import (
    ThreadGovernor,
    available_cores,
    reset_suggestion_governor,
    suggestion_threads,
    threads_for_load,
)
from tests.helpers import wait_for


@pytest.fixture
def two_threads(monkeypatch):
    """torch on 2 threads, a fresh process governor and no count pinned in this thread (an earlier
    test's set_threads, e.g. a CLI run in-process, pins one); all put back afterwards."""
    monkeypatch.setattr(runtime, "_local", threading.local())
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    reset_suggestion_governor()
    yield
    reset_suggestion_governor()
    torch.set_num_threads(before)


@pytest.mark.parametrize(("idle", "expected"), [(2.0, 2), (1.7, 2), (1.0, 1), (1.6, 1), (0.0, 1), (None, 2)])
def test_threads_for_load_counts_the_idle_cores(monkeypatch, idle, expected):
    monkeypatch.setattr(runtime, "idle_cores", lambda window_s=0.05: idle)
    assert threads_for_load(2) == expected


def test_idle_cores_sees_busy_processes():
    """With a spinning process on every core, at most a fraction of one core is idle."""
    if runtime.idle_cores() is None:
        pytest.skip("/proc/stat is not readable here (not Linux)")
    busy = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
        for _ in range(available_cores())
    ]
    try:
        assert wait_for(lambda: threads_for_load() == 1, timeout_s=20.0)
        assert 0.0 <= runtime.idle_cores() <= available_cores()
    finally:
        for p in busy:
            p.kill()
            p.wait()


def test_a_busy_machine_gets_one_thread_and_the_count_is_put_back(monkeypatch, two_threads):
    monkeypatch.setattr(runtime, "threads_for_load", lambda most=None, window_s=0.05: 1)
    with suggestion_threads() as job:
        assert torch.get_num_threads() == 1 and job.threads == 1
        with suggestion_threads() as inner:  # the library's search inside `suggest`'s job
            assert inner.threads is None and torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2  # the caller's count afterwards
    assert job.wall_s >= 0 and job.cpu_s >= 0
    reset_suggestion_governor()
    monkeypatch.setattr(runtime, "threads_for_load", lambda most=None, window_s=0.05: 2)
    with suggestion_threads() as job:
        assert torch.get_num_threads() == 2 and job.threads == 2


def test_an_explicit_count_or_adapt_off_is_kept(monkeypatch, two_threads):
    monkeypatch.setattr(runtime, "threads_for_load", lambda most=None, window_s=0.05: 1)
    with suggestion_threads(adapt=False) as job:
        assert torch.get_num_threads() == 2 and job.threads is None
    seen = []

    def pinned():  # set_threads pins the count of the calling thread (suggest --threads, a node's threads: N)
        runtime.set_threads(2)
        with suggestion_threads() as job:
            seen.append((torch.get_num_threads(), job.threads))

    t = threading.Thread(target=pinned)
    t.start()
    t.join()
    assert seen == [(2, 2)]


def test_a_nodes_governor_is_used_and_learns(two_threads):
    gov = ThreadGovernor(2, patience=1)
    clock = iter([0.0, 0.001])  # 1 ms of CPU in a job of >= 10 ms wall: efficiency far below 0.65
    with suggestion_threads(gov, cpu_clock=lambda: next(clock)) as job:
        assert job.threads == 2
        threading.Event().wait(0.02)
    assert gov.trial and gov.threads == 1 and torch.get_num_threads() == 1  # its next job's count, set


def test_the_library_search_runs_on_the_picked_count(monkeypatch, two_threads):
    from aes_planner.search import SearchConfig, search_views
    from tests.search.test_search import AimScorer, rig_inputs, rig_platform

    class Watching(AimScorer):
        def score(self, cam2world):
            counts.add(torch.get_num_threads())
            return super().score(cam2world)

    counts: set[int] = set()
    monkeypatch.setattr(runtime, "threads_for_load", lambda most=None, window_s=0.05: 1)
    platform = rig_platform()
    search_views(Watching([1.0, 0.0, 0.0]), rig_inputs(platform), platform, SearchConfig.preset("fast"))
    assert counts == {1} and torch.get_num_threads() == 2
