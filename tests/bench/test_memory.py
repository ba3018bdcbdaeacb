"""Memory of a suggestion and of a planner node against the documented ceilings
(aes_planner.bench.memory, docs/benchmarks.md "Memory"). Bounds and growth, not speed; each
measurement runs in a fresh process, so what other tests allocated does not count."""

import pytest

from aes_planner.bench import memory


def test_rss_reads_this_process_and_its_peak_is_not_below_it():
    now, peak = memory.rss_mb(), memory.rss_mb("VmHWM")
    assert 10.0 < now <= peak
    with pytest.raises(RuntimeError, match="NoSuchField"):
        memory.rss_mb("NoSuchField")


@pytest.mark.slow
def test_a_balanced_suggestion_from_4_views_stays_under_its_ceiling():
    m = memory.suggest_memory("balanced")
    assert m["imports_rss_mb"] < m["peak_rss_mb"]  # the suggestion itself was measured
    assert m["peak_rss_mb"] < memory.SUGGEST_PEAK_CEILING_MB


@pytest.mark.slow
def test_a_planner_node_stays_flat_over_100_frames():
    m = memory.planner_memory(100)
    assert m["suggestions"] >= 90  # it planned after (nearly) every frame: the field was exercised
    assert m["rss_mb"] < memory.PLANNER_CEILING_MB
    assert m["rss_mb"] - m["mid_rss_mb"] < memory.PLANNER_GROWTH_CEILING_MB
