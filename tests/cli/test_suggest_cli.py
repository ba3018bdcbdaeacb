"""``aes-planner suggest`` on a tiny ``sim render`` folder: table, JSON shape, report, clear errors."""

import json
import math

import numpy as np
import pytest
import torch
import yaml

from aes_planner.cli import main
from aes_planner.dataset import load_dataset, save_dataset
from aes_planner.geometry import PanTilt
from aes_planner.platform import platform_from_meta
from aes_planner.search import SearchConfig
from aes_planner.sim import load_scene


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("suggest") / "tabletop0"
    args = ["sim", "render", "--scene", "tabletop:0", "--views", "3", "--out", str(out)]
    assert main([*args, "--supersample", "1", "--width", "32", "--height", "24"]) == 0
    return out


def test_sim_render_writes_the_rig(folder):
    ds = load_dataset(folder)
    platform = platform_from_meta(ds.meta, ds.frames[0].intrinsics)
    assert platform.kind == "rig" and platform.rig == load_scene("tabletop:0").rig.pan_tilt


def test_suggest_rig_json_and_report(folder, tmp_path, capsys):
    out_json, out_dir = tmp_path / "s.json", tmp_path / "report"
    argv = ["suggest", str(folder), "--preset", "fast", "--scorer", "rgb", "--top", "2", "--json", str(out_json)]
    assert main([*argv, "--out", str(out_dir)]) == 0
    text = capsys.readouterr().out
    assert "pan_deg" in text and "rig mode" in text
    doc = json.loads(out_json.read_text())
    assert doc["mode"] == "rig" and doc["preset"] == "fast" and doc["latency_ms"] > 0
    assert 1 <= len(doc["suggestions"]) <= 2
    pt = PanTilt(load_scene("tabletop:0").rig.pan_tilt)
    cfg = SearchConfig.preset("fast")  # ranked by the objective: score less the coverage penalty
    objective = [
        s["score"] - cfg.coverage_penalty * max(0.0, cfg.coverage_min - s["coverage"]) for s in doc["suggestions"]
    ]
    assert objective == sorted(objective, reverse=True)
    # what the inputs cover, said in the text and the JSON, with the exploratory candidate
    assert 0.0 <= doc["covered_fraction"] <= 1.0
    assert f"the inputs cover {100 * doc['covered_fraction']:.0f} % of the reachable views" in text
    if doc["explore"] is not None:
        assert doc["explore"]["coverage"] < cfg.coverage_min and "explore pan" in text
        assert -180 <= doc["explore"]["pan_deg"] <= 180
    for s in doc["suggestions"]:
        assert set(s) >= {
            "cam2world",
            "pan_deg",
            "tilt_deg",
            "position_m",
            "yaw_deg",
            "pitch_deg",
            "score",
            "coverage",
            "terms",
        }
        pan, tilt = math.radians(s["pan_deg"]), math.radians(s["tilt_deg"])
        assert pt.within_limits(pan, tilt)
        np.testing.assert_allclose(pt.forward(pan, tilt), np.array(s["cam2world"]), atol=1e-9)
    assert (out_dir / "report.png").stat().st_size > 1000


def test_suggest_free_mode_and_rig_file(folder, tmp_path, capsys):
    ds = load_dataset(folder)
    bare = tmp_path / "bare"
    save_dataset(bare, ds.frames, meta={})  # a folder from elsewhere: no platform metadata
    assert main(["suggest", str(bare), "--preset", "fast", "--scorer", "rgb"]) == 2
    assert "--rig FILE" in capsys.readouterr().err
    rig_file = tmp_path / "rig.yaml"
    rig = load_scene("tabletop:0").rig.pan_tilt
    rig_file.write_text(yaml.safe_dump({"base_xyz_m": list(rig.base_xyz_m), "pan_limits_deg": [-30.0, 30.0]}))
    out_json = tmp_path / "r.json"
    assert (
        main(
            [
                "suggest",
                str(bare),
                "--preset",
                "fast",
                "--scorer",
                "rgb",
                "--rig",
                str(rig_file),
                "--json",
                str(out_json),
            ]
        )
        == 0
    )
    for s in json.loads(out_json.read_text())["suggestions"]:
        assert -30.0 - 1e-9 <= s["pan_deg"] <= 30.0 + 1e-9
    out_json = tmp_path / "f.json"
    assert (
        main(["suggest", str(bare), "--preset", "fast", "--scorer", "rgb", "--mode", "free", "--json", str(out_json)])
        == 0
    )
    doc = json.loads(out_json.read_text())
    assert doc["mode"] == "drone" and "pan_deg" not in doc["suggestions"][0]  # "free" is read as drone


def test_suggest_falls_back_to_rgb_only_when_not_asked(folder, tmp_path, capsys, monkeypatch):
    import aes_planner.field as field
    from aes_planner.field.scorer import ScorerError

    real = field.build_scorer

    def no_field(kind, *a, **k):
        if kind == "field":
            raise ScorerError("no field checkpoint")
        return real(kind, *a, **k)

    monkeypatch.setattr(field, "build_scorer", no_field)
    out_json = tmp_path / "s.json"
    assert main(["suggest", str(folder), "--preset", "fast", "--json", str(out_json)]) == 0
    assert "scoring with rgb instead" in capsys.readouterr().out
    assert json.loads(out_json.read_text())["scorer"] == "rgb"
    assert main(["suggest", str(folder), "--preset", "fast", "--scorer", "field"]) == 2
    assert "no field checkpoint" in capsys.readouterr().err


def test_suggest_truth_scene_for_a_scene_file(tmp_path, capsys, monkeypatch):
    """A folder rendered from a scene file gets its report's ground truth only from --truth-scene
    (a path inside a data folder is never opened); a bad --truth-scene fails before the search."""
    import aes_planner.search as search
    import aes_planner.search.report as report

    scene = "tests/scenes/harbour_rig.yaml"
    folder = tmp_path / "harbour"
    args = ["sim", "render", "--scene", scene, "--views", "3", "--out", str(folder), "--supersample", "1"]
    assert main([*args, "--width", "32", "--height", "24"]) == 0
    seen = []
    real_report = report.write_report

    def spy(path, images, result, renderers, **kw):
        seen.append(sorted(renderers))
        scores.append(kw.get("scores", {}))
        return real_report(path, images, result, renderers, **kw)

    scores = []

    monkeypatch.setattr(report, "write_report", spy)
    base = ["suggest", str(folder), "--preset", "fast", "--scorer", "rgb", "--out", str(tmp_path / "r")]
    assert main(base) == 0
    capsys.readouterr()
    assert main([*base, "--truth-scene", scene, "--json", str(tmp_path / "t.json")]) == 0
    assert seen == [["rgb"], ["rgb", "truth"]]
    # the truth row is labelled with the teacher's score of the ground truth at each suggestion,
    # also printed; it agrees with an independent ground-truth scorer (up to the report's uint8)
    printed = capsys.readouterr().out.split("ground truth (the teacher on the simulator's render at each suggestion): ")
    assert len(printed) == 2 and "truth" not in scores[0]
    truth = scores[1]["truth"]
    assert printed[1].split("\n")[0] == ", ".join(f"#{i + 1} {v:.3f}" for i, v in enumerate(truth))
    from aes_planner.search import GroundTruthScorer
    from aes_planner.sim import SimSource
    from aes_planner.teachers import get_teacher

    poses = np.stack([s["cam2world"] for s in json.loads((tmp_path / "t.json").read_text())["suggestions"]])
    source = SimSource(scene, supersample=2)
    k = load_dataset(folder).frames[0].intrinsics
    images = source.render_rgb(poses, k)  # [K, H, W, 3] in [0, 1]
    expected = GroundTruthScorer(source, get_teacher(), k).score(torch.as_tensor(poses)).score.double().numpy()
    assert images.shape[0] == len(truth)
    np.testing.assert_allclose(truth, expected, atol=0.02)
    assert (tmp_path / "r" / "report.png").stat().st_size > 1000
    capsys.readouterr()

    def no_search(*a, **k):
        raise AssertionError("the search ran before the bad argument was refused")

    monkeypatch.setattr(search, "search_views", no_search)
    assert main([*base, "--truth-scene", str(tmp_path / "missing.yaml")]) == 2
    assert "--truth-scene" in capsys.readouterr().err
    assert main(["suggest", str(folder), "--scorer", "rgb", "--truth-scene", scene]) == 2
    assert "--out" in capsys.readouterr().err


def test_suggest_says_why_fewer_than_top(folder, capsys, monkeypatch):
    """Fewer suggestions than --top: the command names what the search left out."""
    import aes_planner.search as search

    real = search.search_views

    def fewer(*a, **k):
        result = real(*a, **k)
        result.suggestions = result.suggestions[:1]
        result.dropped_uncovered, result.dropped_duplicates = 1, 1
        return result

    monkeypatch.setattr(search, "search_views", fewer)
    assert main(["suggest", str(folder), "--preset", "fast", "--scorer", "rgb", "--top", "3"]) == 0
    text = capsys.readouterr().out
    assert "1 suggestion(s)" in text
    assert "note: 1 refined candidate(s) left out: their coverage fell below" in text
    assert "note: 1 refined candidate(s) left out: they converged onto a better one" in text
    assert main(["suggest", str(folder), "--preset", "fast", "--scorer", "rgb", "--top", "1"]) == 0
    assert "note:" not in capsys.readouterr().out  # as many as asked for: nothing to explain


def test_table_columns_stay_aligned_far_from_the_origin(capsys):
    from types import SimpleNamespace

    from aes_planner.cli.suggest import print_table

    def sug(pos, score):
        return SimpleNamespace(
            position_m=np.array(pos), yaw_rad=0.5, pitch_rad=-0.2, score=score, coverage=0.9, terms={}
        )

    result = SimpleNamespace(
        mode="free", suggestions=[sug([100000.96, -3000.85, 2.57], 0.812), sug([1.0, 2.0, 3.0], 0.645)]
    )
    print_table(result, 2)
    head, *rows = capsys.readouterr().out.splitlines()
    assert "100000.96" in rows[0] and "-3000.85" in rows[0]
    # the score column starts at the same place in every row, under its heading
    starts = {row.index(score) for row, score in zip(rows, ("0.812", "0.645"), strict=True)}
    assert len(starts) == 1 and head.index("score") <= starts.pop() < head.index("coverage")


def test_report_labels_each_row_with_its_own_score():
    """A row given its own scores (RGB, ground truth) shows them; the others show the search's."""
    from aes_planner.search.pipeline import Suggestion
    from aes_planner.search.report import suggestion_label

    s = Suggestion(np.eye(4), np.zeros(3), 0.0, 0.0, score=0.61, coverage=0.7, terms={}, pan_rad=2.1, tilt_rad=0.14)
    assert suggestion_label(0, s) == "#1 pan 120 tilt 8 s=0.61"
    assert suggestion_label(1, s, 0.268) == "#2 pan 120 tilt 8 s=0.27"
