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
