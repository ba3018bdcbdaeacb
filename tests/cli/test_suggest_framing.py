"""``suggest --keep/--avoid``: a subject held whole in every suggestion, outlined in the report;
bad regions are one error line naming the flag, before any search."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aes_planner.cli import main


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("framing") / "ds"
    argv = ["sim", "render", "--scene", "tabletop:102", "--views", "4", "--supersample", "1", "--out", str(root)]
    assert main(argv) == 0
    return root


@pytest.mark.parametrize(
    "args, words",
    [
        (["--keep", "nope.png:1,1,5,5"], "no input frame is named 'nope.png'"),
        (["--keep", "00003.png:1,1,500,5"], "outside the 128x96 image"),
        (["--keep", "00003.png:5,5,5,9"], "--keep 00003.png: the box 5,5,5,9 has zero size"),
        (["--avoid", "00003.png:1,2,3"], "--avoid"),
        (["--keep-at", "thirds"], "--keep-at"),
        (["--keep", "00003.png:35,31,51,77", "--keep-margin", "0.5"], "--keep-margin"),
        (["--photo-rank"], "--photo-rank ranks the views that hold a kept subject"),
    ],
)
def test_bad_regions_are_one_line_naming_the_flag(folder, cli_error, args, words):
    cli_error(["suggest", folder, "--preset", "fast", *args], words, seconds=120)


def test_keep_holds_the_subject_and_the_report_outlines_it(folder, tmp_path, capsys):
    out, js = tmp_path / "report", tmp_path / "s.json"
    argv = ["suggest", str(folder), "--preset", "fast", "--keep", "00003.png:35,31,51,77", "--keep-at", "centre"]
    assert main([*argv, "--json", str(js), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "framing: keep 00003.png:35,31,51,77" in printed
    assert "% of the reachable views that hold the kept subject" in printed  # what the inputs cover of them
    doc = json.loads(js.read_text())
    assert doc["keep_margin"] == 0.05 and len(doc["keep"]) == 1
    assert 0.0 <= doc["covered_fraction"] <= 1.0
    assert all(s["held"] == pytest.approx(1.0) for s in doc["suggestions"])
    import cv2

    report = cv2.imread(str(out / "report.png"))
    green = (report[..., 1] > 150) & (report[..., 0] < 110) & (report[..., 2] < 110)  # the outlines (BGR)
    assert green.sum() > 50
    assert np.isfinite(np.asarray(doc["keep"][0]["centre_m"])).all()


def test_photo_rank_ranks_the_suggestion_on_the_input_photos(folder, tmp_path, capsys):
    js = tmp_path / "s.json"
    argv = ["suggest", str(folder), "--preset", "fast", "--keep", "00003.png:35,31,51,77", "--photo-rank"]
    assert main([*argv, "--json", str(js)]) == 0
    printed = capsys.readouterr().out
    assert "#1 ranked on the input photos warped into it: teacher" in printed
    doc = json.loads(js.read_text())
    assert doc["photo_rank"] is True
    best = doc["suggestions"][0]
    assert best["held"] == pytest.approx(1.0)
    assert 0.0 < best["terms"]["photo_cover"] <= 1.0 and np.isfinite(best["terms"]["photo"])
