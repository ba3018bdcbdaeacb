"""The ``reconstruct`` benchmark group is registered, its cases run, and it records every figure."""

import importlib

import pytest

from aes_planner.bench import GROUPS
from aes_planner.bench.reconstruct import SimSource, case, inputs_and_held_out
from aes_planner.reconstruct import ReconstructConfig


def test_group_is_registered_and_a_case_runs():
    assert GROUPS["reconstruct"] == "aes_planner.bench.reconstruct"
    ts, held = inputs_and_held_out(4)
    assert ts[0] == 0.0 and ts[-1] == 1.0 and len(held) == 3 and all(0 < t < 1 for t in held)
    src = SimSource("indoor:3", 32, 24, supersample=1)
    for mode in ("depth", "sphere"):
        psnr, coverage, count = case(src, mode, 2, ReconstructConfig())
        assert 10.0 < psnr < 60.0 and 0.5 < coverage <= 1.0 and count > 0


@pytest.mark.slow
def test_group_records_every_figure(wiring_recorder):
    rec = wiring_recorder
    importlib.import_module(GROUPS["reconstruct"]).run(rec, quick=True)
    keys = set(rec.results)
    for mode in ("depth", "stereo", "sphere", "depth_rig"):
        assert {f"reconstruct.{mode}_4v.{f}" for f in ("psnr_db", "coverage", "count")} <= keys
    for name in ("budget_default", "budget_0.1"):
        assert {
            f"reconstruct.{name}.{f}" for f in ("psnr_db", "count", "fraction", "fraction_of_raw", "psnr_loss_db")
        } <= keys
    assert {
        "reconstruct.unpruned.psnr_db",
        "reconstruct.raw.count",
        "reconstruct.stereo.abs_rel",
        "reconstruct.stereo.within_5pct",
        "reconstruct.build_4x128.ms",
        "reconstruct.stream_frame.ms",
    } <= keys
    assert rec.results["reconstruct.budget_default.fraction"]["value"] <= 0.3
