"""One mechanism picks the thread count of every suggestion: the library's
search, ``suggest``, ``bench search`` and the planner node all run their compute inside
``aes_planner.runtime.suggestion_threads``; outside a node it starts from the cores idle now."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

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


def _fake_ticks(monkeypatch, *readings):
    """/proc/stat as ``readings`` of (idle, total) jiffies, one per read; time.sleep recorded."""
    reads = list(readings)
    slept = []
    monkeypatch.setattr(runtime, "_cpu_ticks", lambda cpus: reads.pop(0))
    monkeypatch.setattr(runtime.time, "sleep", slept.append)
    monkeypatch.setattr(runtime, "_ticks_per_s", lambda: 100.0)
    return slept


def test_a_started_window_is_read_once_without_a_wait(monkeypatch):
    """A cold `suggest` reads the load over its own start-up (started by the program) instead of
    sleeping 50 ms; its own CPU over the window counts as idle (the cores others leave it)."""
    cores = len(runtime._own_cpus())
    slept = _fake_ticks(monkeypatch, (100, 200), (150, 400), (0, 0), (10, 10))
    runtime.start_load_window()
    wall, _, ticks = runtime._load_window
    runtime._load_window = (wall - 1.0, time.process_time() - 0.5, ticks)  # 1 s ago, 0.5 s of own CPU since
    # 50 idle of 200 ticks, plus the process's own 50 (0.5 s at 100 per second): half the cores
    assert runtime.idle_cores() == pytest.approx(0.5 * cores, abs=0.02 * cores)
    assert slept == []
    assert runtime.idle_cores() == pytest.approx(cores)  # read once: the next look waits for its own window
    assert slept == [0.05]


@pytest.mark.parametrize("age_s", [0.01, runtime.LOAD_WINDOW_MAX_S + 1.0])
def test_a_window_too_short_or_too_old_is_not_read(monkeypatch, age_s):
    slept = _fake_ticks(monkeypatch, (100, 200), (0, 0), (10, 10))
    now = [1000.0]  # the window's age on a clock of the test's own: a loaded host's pause between
    monkeypatch.setattr(runtime.time, "monotonic", lambda: now[0])  # two lines made 10 ms 50 (flaky)
    runtime.start_load_window()
    now[0] += age_s
    assert runtime.idle_cores() == pytest.approx(len(runtime._own_cpus()))  # its own 50 ms look: all idle
    assert slept == [0.05] and runtime._load_window is None


@pytest.mark.parametrize("program", [True, False])
def test_the_program_starts_its_look_at_the_load_as_it_starts(tmp_path, program):
    """`aes-planner suggest` (main() without argv) starts the window at its start; main([...])
    from other code does not (its first suggestion takes its own 50 ms look). The command fails
    on a missing folder before any suggestion reads the window."""
    missing = str(tmp_path / "nowhere")
    call = "main()" if program else f"main(['suggest', {missing!r}])"
    body = (
        "import atexit, sys\nfrom aes_planner import runtime\n"
        "atexit.register(lambda: print('window', runtime._load_window is not None))\n"
        f"from aes_planner.cli import main\nsys.argv = ['aes-planner', 'suggest', {missing!r}]\nsys.exit({call})\n"
    )
    out = subprocess.run([sys.executable, "-c", body], capture_output=True, text=True, timeout=600)
    assert out.stdout.strip().splitlines()[-1] == f"window {program}", out.stderr
