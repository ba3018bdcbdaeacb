"""``eval field`` writes the JSON shape the paper's experiments use, a table and plots; ``bench field`` records its keys."""

import importlib
import json

import numpy as np
import pytest

from aes_planner.eval.field import FieldEvalConfig, default_scenes, evaluate_field, write_report
from aes_planner.field import ScorerConfig
from aes_planner.field.model import FieldModel, FieldModelConfig
from aes_planner.metrics import plcc, srcc, tv_ratio
from aes_planner.sim import SimCameraConfig, SimSource
from aes_planner.teachers import get_teacher


def test_metrics_match_their_definitions():
    x = np.array([1.0, 2.0, 3.0, 5.0])
    assert plcc(x, 2 * x + 1) == pytest.approx(1.0) and plcc(x, -x) == pytest.approx(-1.0)
    assert srcc(x, x**3) == pytest.approx(1.0) and plcc(x, np.ones(4)) == 0.0
    assert tv_ratio(x, x) == pytest.approx(1.0) and tv_ratio(np.ones(4), x) == 0.0


@pytest.mark.parametrize("source", ["free", "sweep"])
def test_eval_field_json_shape_table_and_plot(tmp_path, source):
    model = FieldModel(FieldModelConfig(embed_dim=2, hidden=8, encoder_channels=4), 4, (16, 16), "composition")
    cfg = FieldEvalConfig(source=source, views=[2], targets=5, scorer=ScorerConfig(render_width_px=16))
    scenes = default_scenes(1)
    summary, raw = evaluate_field(
        scenes,
        lambda n: SimSource(n, camera=SimCameraConfig(width=32, height=24, supersample=1)),
        get_teacher(),
        {"field": model, "field_nocond": model},
        cfg,
    )
    paths = write_report(summary, raw, tmp_path, tmp_path / "out.json")
    doc = json.loads((tmp_path / "out.json").read_text())
    assert doc["source"] == source and doc["teacher"] == "composition" and doc["scenes"] == ["indoor:0"]
    for m in ("rgb", "splat", "field_nocond", "field"):
        r = doc["views"]["2"][m]
        assert {"plcc", "srcc", "tv_ratio", "coverage"} <= set(r) and -1 <= r["plcc"] <= 1
    assert all(p.exists() for p in paths) and any(p.suffix == ".png" for p in paths)


@pytest.mark.slow
def test_bench_field_records_every_key(wiring_recorder):
    importlib.import_module("aes_planner.bench.field").run(wiring_recorder, quick=True)
    keys = set(wiring_recorder.results)
    assert {"field.build_4v.ms", "field.score_b64.ms", "field.grad_b2.ms", "rgb.score_b64.ms", "rgb.grad_b2.ms"} <= keys
