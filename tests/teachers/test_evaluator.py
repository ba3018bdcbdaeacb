"""Independent evaluator: sane judgements, correct correlation statistics, a positive but partial
agreement with the composition teacher."""

import numpy as np
import pytest
import torch

from aes_planner.metrics import MetricsError, plcc, srcc
from aes_planner.teachers import CompositionTeacher, TeacherError
from aes_planner.teachers.evaluator import CompositionEvaluator, correlation
from aes_planner.teachers.synthetic import add_clutter, canvas, draw_disc, draw_horizon, random_composition

H, W = 96, 128
RED = (0.85, 0.2, 0.15)


@pytest.fixture(scope="module")
def evaluator():
    return CompositionEvaluator()


def test_judgements_move_the_right_way(evaluator):
    blank = canvas(H, W)
    thirds = draw_disc(canvas(H, W), 1 / 3, 1 / 3, 0.12, RED)
    cut = draw_disc(canvas(H, W), 0.02, 0.5, 0.2, RED)
    level = draw_disc(draw_horizon(canvas(H, W), 2 / 3), 1 / 3, 0.45, 0.1, RED)
    tilted = draw_disc(draw_horizon(canvas(H, W), 2 / 3, 4.0), 1 / 3, 0.45, 0.1, RED)
    busy = add_clutter(thirds.clone(), 80, np.random.default_rng(0))
    e = evaluator.explain(torch.stack([blank, thirds, cut, level, tilted, busy]))
    assert e["score"][0] < 0.05 < e["score"][1]
    assert e["pattern_thirds"][1] > 0.9 and e["not_cut"][1] == 1.0
    assert e["not_cut"][2] < 1.0 and e["score"][2] < e["score"][1]
    assert e["pattern_horizontal"][3] > 0.9 and e["level"][3] == 1.0
    assert e["level"][4] < 0.8 and e["score"][4] < e["score"][3]
    assert e["score"][5] < e["score"][1]
    assert ((e["score"] >= 0) & (e["score"] <= 1)).all()


def test_accepts_numpy_uint8_and_float(evaluator):
    img = draw_disc(canvas(H, W), 1 / 3, 1 / 3, 0.12, RED)
    as_u8 = (img.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    a = evaluator.evaluate([img])[0]
    b = evaluator.evaluate([as_u8])[0]
    c = evaluator.evaluate([as_u8.astype(np.float32) / 255])[0]
    assert a == pytest.approx(b, abs=1e-6) and b == pytest.approx(c, abs=1e-6)
    with pytest.raises(TeacherError, match="RGB"):
        evaluator.evaluate([np.zeros((8, 8))])
    with pytest.raises(TeacherError, match="no images"):
        evaluator.evaluate([])


def test_plcc_and_srcc_known_values():
    x = np.arange(10.0)
    assert plcc(x, 2 * x + 1) == pytest.approx(1.0)
    assert plcc(x, -x) == pytest.approx(-1.0)
    assert srcc(x, np.exp(x)) == pytest.approx(1.0)  # monotone but not linear
    assert plcc(x, np.exp(x)) < 0.9
    # ties share the average rank: ranks of [1, 2, 2, 3] are [1, 2.5, 2.5, 4]
    assert srcc([1, 2, 2, 3], [1, 2.5, 2.5, 4]) == pytest.approx(1.0)
    assert srcc([1, 2, 3, 4, 5], [5, 6, 7, 8, 7]) == pytest.approx(0.8207826816681233)  # scipy.stats.spearmanr
    assert plcc([1, 1, 1], [1, 2, 3]) == 0.0 and srcc([2, 2, 2], [3, 1, 2]) == 0.0  # constant: no agreement
    with pytest.raises(MetricsError):
        plcc([1.0], [2.0])


def test_correlation_with_the_composition_teacher_is_positive_and_partial(evaluator):
    rng = np.random.default_rng(7)
    images = [random_composition(rng) for _ in range(80)]
    r = correlation(CompositionTeacher(), images, evaluator)
    assert r["n"] == 80
    assert 0.2 < r["plcc"] < 0.95
    assert 0.2 < r["srcc"] < 0.95


def test_correlation_accepts_mixed_sizes(evaluator):
    images = [
        canvas(40, 60),
        draw_disc(canvas(50, 50), 0.3, 0.3, 0.1, RED),
        draw_horizon(canvas(40, 60), 0.6),
        torch.rand(3, 33, 20),
    ]
    r = correlation(CompositionTeacher(), images, evaluator, batch_size=2)
    assert r["n"] == 4 and -1 <= r["plcc"] <= 1
    with pytest.raises(TeacherError, match="at least 3"):
        correlation(CompositionTeacher(), images[:2], evaluator)
