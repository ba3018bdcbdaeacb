"""The ``teachers`` benchmark group is registered and records its keys (composition only here:
VEN's 64-image batches take minutes, and run in `make bench`)."""

import math

import pytest

from aes_planner.bench import GROUPS, Recorder
from aes_planner.bench import teachers as bench
from aes_planner.teachers import CompositionTeacher


def test_group_is_registered():
    assert GROUPS["teachers"] == "aes_planner.bench.teachers"


def test_records_per_image_times_for_every_size_and_batch(monkeypatch):
    monkeypatch.setattr(bench, "BATCHES", (1, 4))
    rec = Recorder()
    bench.bench_teacher(rec, CompositionTeacher(), quick=True, runs=1)
    for size in bench.SIZES:
        for b in (1, 4):
            for part in ("features", "head"):
                r = rec.results[f"teachers.composition.{part}_{size}_b{b}.ms"]
                assert r["unit"] == "ms" and 0 < r["value"] < 1e4
    assert "teachers.composition.head_grad_b4.ms" in rec.results


def test_records_the_evaluator_correlation(monkeypatch):
    monkeypatch.setattr(bench, "sim_views", lambda count, seed=0: None)
    rec = Recorder()
    bench.bench_correlation(rec, quick=True)
    assert rec.results["teachers.correlation_synthetic.n"]["value"] == 60
    assert -1 <= rec.results["teachers.correlation_synthetic.plcc"]["value"] <= 1
    assert not math.isnan(rec.results["teachers.correlation_synthetic.srcc"]["value"])


def test_records_the_subject_figures_of_both_judges(monkeypatch):
    pytest.importorskip("aes_planner.sim")
    small = bench.subject_views
    monkeypatch.setattr(
        bench,
        "subject_views",
        lambda seeds, random_views: small(seeds=(0,), random_views=4, sweep=(2, 2), width=64, height=48),
    )
    rec = Recorder()
    bench.bench_subjects(rec, quick=True)
    for judge in ("composition", "evaluator"):
        for key in (
            "subject_pref_acc",
            "subject_pref_acc_texture",
            "subject_srcc",
            "sweep_argmax_subject_rate",
            "sweep_subject_share",
        ):
            assert f"teachers.{judge}.{key}" in rec.results
        assert 0 <= rec.results[f"teachers.{judge}.sweep_argmax_subject_rate"]["value"] <= 1
