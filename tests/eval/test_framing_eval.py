"""``eval framing``: the true subject, its pick, the constrained oracle and one searched case."""

from __future__ import annotations

import numpy as np
import pytest

from aes_planner.eval.framing import FramingEvalConfig, object_points, run_framing_eval, true_holds
from aes_planner.geometry import Intrinsics
from aes_planner.geometry.poses import look_at
from aes_planner.sim.spec import BoxSpec, SphereSpec


def test_true_points_bound_the_object_and_holds_checks_every_one():
    box = object_points(BoxSpec(centre_m=(4.0, 0.0, 1.0), size_m=(0.4, 0.6, 2.0), yaw_deg=30.0))
    assert box.shape == (8, 3) and np.allclose(box.mean(0), (4.0, 0.0, 1.0))
    ball = object_points(SphereSpec(centre_m=(0.0, 0.0, 0.0), radius_m=0.5))
    assert np.all(np.linalg.norm(ball, axis=1) >= 0.5)  # the lattice encloses the sphere
    k = Intrinsics.from_fov(64, 48, 60.0)
    at = np.asarray(look_at(np.array([0.0, 0.0, 1.0]), np.array([4.0, 0.0, 1.0])))
    away = np.asarray(look_at(np.array([0.0, 0.0, 1.0]), np.array([4.0, 3.0, 1.0])))  # half of it out
    close = np.asarray(look_at(np.array([3.5, 0.0, 1.0]), np.array([4.0, 0.0, 1.0])))  # too close to fit
    assert true_holds(box, np.stack([at, away, close]), k).tolist() == [True, False, False]


def test_cfg_is_checked():
    with pytest.raises(Exception, match="keep_margin"):
        FramingEvalConfig(keep_margin=0.9)
    with pytest.raises(Exception, match="min_frac"):
        FramingEvalConfig(min_frac=0.5, max_frac=0.2)


def test_one_case_holds_its_subject_and_is_measured_against_the_constrained_oracle():
    cfg = FramingEvalConfig(
        scenes=["tabletop:102"], seeds=[1], preset="fast", oracle_step_deg=15.0, oracle_min_step_deg=8.0
    )
    doc = run_framing_eval(cfg)
    (row,) = doc["rows"]
    assert row["subject"] == "candle" and row["holds"] is True
    assert 0 < row["holding_views"] < row["grid_views"]
    assert row["best_teacher"] >= row["mean_teacher"] and np.isfinite(row["teacher"])
    s = doc["summary"]
    assert s["hold_rate"] == 1.0 and np.isfinite(s["normalized_teacher_median"])
    # the loss breakdown: the field's best stage-1 candidates that hold the subject, on ground truth
    assert 2 <= row["pool_n"] <= 16
    assert row["pool_best"] >= row["pool_pick"] and -1.0 <= row["pool_rank_corr"] <= 1.0
    assert s["pool_best_median"] == row["pool_best"]
