"""The bench recorder: every timed figure carries its spread (issue 38 item 2)."""

import pytest

from aes_planner.bench import Recorder


def test_time_records_the_median_with_its_spread():
    rec = Recorder()
    calls = []
    median = rec.time("g.case.ms", lambda: calls.append(1), runs=5, warmup=2)
    assert len(calls) == 7  # the warm-up calls are not in the figures
    r = rec.results
    assert r["g.case.ms"]["value"] == median and r["g.case.ms"]["runs"] == 5
    assert r["g.case.ms_min"]["value"] <= median <= r["g.case.ms_max"]["value"]
    assert r["g.case.ms_min"]["runs"] == r["g.case.ms_max"]["runs"] == 5


def test_record_spread_keeps_the_extremes_and_refuses_no_samples():
    rec = Recorder()
    assert rec.record_spread("g.case.cpu_ms", [3.0, 1.0, 10.0], "ms") == 3.0
    assert (rec.results["g.case.cpu_ms_min"]["value"], rec.results["g.case.cpu_ms_max"]["value"]) == (1.0, 10.0)
    with pytest.raises(ValueError, match="no samples"):
        rec.record_spread("g.case.x", [], "ms")


def test_time_with_cpu_records_both_clocks_with_their_spread():
    rec = Recorder()
    rec.time("g.case.ms", lambda: sum(range(20000)), runs=3, warmup=0, cpu=True)
    for key in ("g.case.ms", "g.case.cpu_ms"):
        r = rec.results
        assert r[f"{key}_min"]["value"] <= r[key]["value"] <= r[f"{key}_max"]["value"], key
        assert r[key]["runs"] == 3
    assert rec.results["g.case.cpu_ms_max"]["value"] > 0  # the loop used the CPU it was timed on


@pytest.mark.parametrize("writes", [True, False])
def test_machine_info_says_whether_python_writes_bytecode(monkeypatch, writes):
    """The cold-process figures depend on it (PYTHONDONTWRITEBYTECODE makes every process
    compile the package from source), so the JSON's machine block must say which it was."""
    import sys

    from aes_planner.bench import machine_info

    monkeypatch.setattr(sys, "dont_write_bytecode", not writes)
    assert machine_info()["python_writes_bytecode"] is writes
