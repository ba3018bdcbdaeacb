"""The search bench's Pareto plot, and (slow) its wiring: the keys `Checked by` asks for."""

import pytest

from aes_planner.bench.search import CASES, write_pareto


def test_pareto_plot(tmp_path):
    path = write_pareto({"fast": (300.0, 0.6), "balanced": (900.0, 0.8), "rgb": (5000.0, 0.4)}, tmp_path / "p.png")
    assert path.stat().st_size > 1000


@pytest.mark.slow
def test_bench_search_keys(wiring_recorder, monkeypatch, tmp_path):
    from aes_planner.bench import search as bench_search

    monkeypatch.chdir(tmp_path)
    bench_search.run(wiring_recorder, quick=True)
    for case, _ in CASES:
        assert f"search.{case}.latency_ms" in wiring_recorder.results
        assert -1.0 <= wiring_recorder.results[f"search.{case}.normalized"]["value"] <= 1.5
        assert f"search.{case}.normalized_se" not in wiring_recorder.results  # quick: one scene, no spread
    assert (tmp_path / "bench" / "search_pareto.png").is_file()
