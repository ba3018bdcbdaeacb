"""``suggest`` on a folder of photos alone: the pose step first (said so), the hand-held search space,
each suggestion said from its nearest photo, the JSON in the written poses' frame, the posed folder
kept next to the report."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from aes_planner.cli import main
from aes_planner.dataset import load_dataset
from aes_planner.platform import platform_from_meta


@pytest.mark.slow  # the field on stereo from ten photos: minutes on a loaded machine
def test_suggest_on_photos_alone(arc_set, tmp_path, capsys):
    images, _ = arc_set
    photos = tmp_path / "walk"
    shutil.copytree(images, photos)
    out = tmp_path / "report"
    code = main(["suggest", str(photos), "--preset", "fast", "--top", "2", "--json", str(tmp_path / "s.json"),
                 "--out", str(out)])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 0
    assert "photos without poses: running the pose step first" in text
    assert "handheld mode" in text and "search space: hand-held, within" in text
    assert "positions in units of the distance between the cameras of IMG_0000.jpg and IMG_0001.jpg" in text
    posed = out / "posed"  # kept next to the report
    assert (
        (posed / "cameras.json").is_file() and (posed / "transforms.json").is_file() and (out / "report.png").is_file()
    )
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["mode"] == "handheld" and doc["posed_folder"] == str(posed)
    assert doc["unit"].startswith("the distance between the cameras of IMG_0000.jpg")
    # suggestion #1: a view refined at a photo the teacher likes best when its lower bound clears the
    # best photo, else that photo turned on the spot when that clears it, else the photo as taken;
    # said from that photo either way
    first, refine = doc["suggestions"][0], doc["refine"]
    assert first["from_photo"]["photo"] == refine["photo"]
    assert [first["refined"], first["turned"], first["as_taken"]].count(True) == 1
    assert refine["kind"] == ("refined" if first["refined"] else "turn" if first["turned"] else "as_taken")
    if refine["confident"]:
        assert "#1 refined at a photo the teacher likes best" in text and first["refined"]
        assert first["terms"]["photo_gain_low"] >= refine["min_gain"] and first["terms"]["photo_gain"] > 0
    else:
        assert f"#1 is the photo the teacher likes best, {refine['best_photo']}" in text
        assert refine["photo"] == refine["best_photo"] and refine["top_gain_low"] < refine["min_gain"]
        if first["turned"]:
            assert "turned on the spot" in text and refine["fallback_turn"]
            assert first["terms"]["photo_gain_low"] >= refine["fallback_min_gain"]
            assert first["from_photo"]["right"] == pytest.approx(0, abs=1e-9) and first["from_photo"][
                "forward"
            ] == pytest.approx(0, abs=1e-9)
        else:
            assert "as taken" in text
    data = load_dataset(posed)
    platform = platform_from_meta(data.meta, data.frames[0].intrinsics)
    for i, s in enumerate(doc["suggestions"]):
        c2w = np.asarray(s["cam2world"])
        assert bool(platform.contains(c2w[:3, 3]))  # in the written frame, inside the region walked
        move = s["from_photo"]
        assert move["photo"] in data.meta["photos"]
        assert f"#{i + 1} {move['text']}" in text
        # the move, applied to the named photo's pose, lands on the suggestion
        photo = data.cam2worlds()[data.meta["photos"].index(move["photo"])]
        yaw = np.arctan2(photo[1, 2], photo[0, 2])
        forward, left = np.array([np.cos(yaw), np.sin(yaw), 0]), np.array([-np.sin(yaw), np.cos(yaw), 0])
        back = photo[:3, 3] + move["forward"] * forward - move["right"] * left + [0, 0, move["up"]]
        np.testing.assert_allclose(back, c2w[:3, 3], atol=1e-6)


@pytest.mark.parametrize(
    "flag, value, said",
    [("--refine-forward", "0,x", "--refine-forward"), ("--refine-forward", "0.9", "--refine-forward"),
     ("--refine-turn", "-2", "--refine-turn"), ("--refine-turn", "nan", "--refine-turn"),
     ("--refine-at", "0", "--refine-at"), ("--refine-caution", "-1", "--refine-caution"),
     ("--refine-min-gain", "nan", "--refine-min-gain")],
)  # fmt: skip
def test_bad_refinement_is_refused_before_the_pose_step(arc_set, tmp_path, capsys, flag, value, said):
    images, _ = arc_set
    code = main(["suggest", str(images), flag, value, "--posed", str(tmp_path / "posed")])
    err = capsys.readouterr().err
    assert code == 2 and said in err and err.count("\n") == 1
    assert not (tmp_path / "posed").exists()  # refused before the pose step ran
