"""The raster bench group's wiring on a tiny case: the keys it records and the CPU breakdown."""

import pytest

from aes_planner.bench import Recorder
from aes_planner.bench import raster as bench_raster
from aes_planner.gaussians import numba_backend


@pytest.mark.skipif(not numba_backend.available(), reason="the breakdown is of the numba backend")
def test_case_records_timings_speedup_and_a_breakdown_that_adds_up():
    rec = Recorder()
    case = bench_raster.Case(n=300, size=16, channels=2, cameras=3, dense_cameras=1, dense_backward=False)
    bench_raster._bench_case(rec, "tiny", case, quick=True)
    r = {k: v["value"] for k, v in rec.results.items()}
    for key in ("fwd_ms", "fwdbwd_ms", "fwd_cpu_ms", "fwdbwd_cpu_ms", "dense_fwd_ms", "speedup_fwd", "pairs"):
        assert r[f"raster.tiny.{key}"] > 0, key
    for key in ("fwd_ms", "fwdbwd_ms", "fwd_cpu_ms", "fwdbwd_cpu_ms", "dense_fwd_ms", "speedup_fwd"):  # with spread
        assert r[f"raster.tiny.{key}_min"] <= r[f"raster.tiny.{key}"] <= r[f"raster.tiny.{key}_max"], key
    parts = [f"raster.tiny.cpu_{name}_ms" for name in (*bench_raster.KERNELS, "glue", "outside")]
    assert all(r[p] >= 0 for p in parts[:-2]), "kernel CPU times are non-negative"
    assert sum(r[p] for p in parts) > 0
    assert r["raster.tiny.cpu_raster_fwd_ms"] + r["raster.tiny.cpu_raster_bwd_ms"] > 0


@pytest.mark.skipif(not numba_backend.available(), reason="one numba thread is a numba backend figure")
def test_one_thread_figures_and_the_thread_count_restored():
    """A case marked ``one_thread`` is timed on one numba thread too, with its spread and the
    default threads' parallel efficiency against it; the bench's thread count is as before."""
    import numba

    before = numba.get_num_threads()
    rec = Recorder()
    case = bench_raster.Case(
        n=300, size=16, channels=2, cameras=1, dense_cameras=1, dense_backward=False, one_thread=True
    )
    bench_raster._bench_case(rec, "tiny", case, quick=True)
    r = {k: v["value"] for k, v in rec.results.items()}
    for key in ("fwd_1thread_ms", "fwdbwd_1thread_ms"):
        assert 0 < r[f"raster.tiny.{key}_min"] <= r[f"raster.tiny.{key}"] <= r[f"raster.tiny.{key}_max"], key
    for key in ("fwd_parallel_efficiency", "fwdbwd_parallel_efficiency"):
        assert r[f"raster.tiny.{key}"] > 0, key
    assert numba.get_num_threads() == before


def test_host_counters_measure_a_group():
    """The bench's per-group host figures: this process's CPU time moves forward over work, and
    the machine's stolen time, where /proc/stat has it, never goes backwards."""
    from aes_planner.bench import host_counters, host_delta

    before = host_counters()
    sum(i * i for i in range(300_000))
    delta = host_delta(before, host_counters())
    assert delta["process_user_s"] + delta["process_sys_s"] > 0
    assert delta.get("steal_s", 0.0) >= 0 and delta["process_voluntary_switches"] >= 0
