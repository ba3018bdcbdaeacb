"""``aes-planner score`` and ``aes-planner teachers``, run in-process through the real parser."""

import json

import cv2
import numpy as np
import pytest
import torch

from aes_planner.cli import main
from aes_planner.images import read_image
from aes_planner.teachers.composition import TERMS
from aes_planner.teachers.synthetic import canvas, draw_disc, draw_horizon
from aes_planner.teachers.ven import VENTeacher


def write_png(path, image):  # image [3, H, W] float in [0, 1]
    arr = (image.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    assert cv2.imwrite(str(path), arr[..., ::-1])
    return path


@pytest.fixture
def pictures(tmp_path):
    good = write_png(
        tmp_path / "good.png", draw_disc(draw_horizon(canvas(96, 128), 2 / 3), 1 / 3, 0.45, 0.1, (0.85, 0.2, 0.15))
    )
    blank = write_png(tmp_path / "blank.png", canvas(64, 64))
    return good, blank


def test_score_prints_scores_and_terms(pictures, capsys):
    good, blank = pictures
    assert main(["score", str(good), str(blank)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("teacher composition")
    assert str(good) in out[1] and "thirds" in out[1] and "horizon_level" in out[1] and "subject_presence" in out[1]
    assert float(out[1].split("score ")[1].split()[0]) > 0.75
    assert str(blank) in out[2] and "score 0.0000" in out[2]


def test_score_json(pictures, capsys):
    good, blank = pictures
    assert main(["score", "--json", str(good), str(blank)]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["path"] for r in rows] == [str(good), str(blank)]
    assert set(rows[0]) == {"path", "score", "terms"}
    assert set(TERMS) <= set(rows[0]["terms"]) and "score" not in rows[0]["terms"]
    assert rows[0]["score"] > 0.7 > 0.1 > rows[1]["score"]


def test_ven_without_weights_gives_the_advice(pictures, capsys):
    assert main(["score", "--teacher", "ven", str(pictures[0])]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: VEN needs its released weights")
    assert "--weights PATH" in err and "github.com/zijunwei/ViewEvaluationNet" in err


def test_ven_with_released_layout_scores_exactly_what_the_network_computes(tmp_path, capsys):
    ven = VENTeacher.random(seed=2)
    weights = tmp_path / "EvaluationNet.pth.tar"
    torch.save({"state_dict": {f"single_pass_net.{k}": v for k, v in ven.net.state_dict().items()}}, weights)
    img = write_png(tmp_path / "view224.png", torch.rand(3, 224, 224, generator=torch.Generator().manual_seed(0)))
    assert main(["score", "--teacher", "ven", "--weights", str(weights), "--json", str(img)]) == 0
    row = json.loads(capsys.readouterr().out)[0]
    assert row["terms"] == {}
    # The original network on the same pixels: uint8 / 255, ImageNet normalisation, no resizing.
    x = torch.from_numpy(cv2.imread(str(img))[..., ::-1].astype(np.float32) / 255).permute(2, 0, 1)[None]
    with torch.no_grad():
        expected = ven.net(ven.preprocess(x))[0, 0].item()
    assert row["score"] == expected


@pytest.mark.parametrize(
    "argv, match",
    [
        (["score", "missing.png"], "no such image file"),
        (["score", "--teacher", "nope", "IMG"], "unknown teacher 'nope'"),
        (["score", "--weights", "w.pt", "IMG"], "does not take the options"),
        (["score", "--teacher", "ven", "--weights", "missing.pt", "IMG"], "does not exist"),
    ],
)
def test_user_errors_exit_2_with_one_line(pictures, capsys, argv, match):
    argv = [str(pictures[0]) if a == "IMG" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err


def test_not_an_image(tmp_path, capsys):
    bad = tmp_path / "notes.png"
    bad.write_text("hello")
    assert main(["score", str(bad)]) == 2
    assert "not an image OpenCV can read" in capsys.readouterr().err


def test_read_image_formats(tmp_path):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((5, 7), 128, np.uint8))
    rgba = tmp_path / "rgba.png"
    cv2.imwrite(str(rgba), np.dstack([np.full((4, 4), v, np.uint8) for v in (10, 20, 30, 40)]))
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), np.full((3, 3, 3), 65535, np.uint16))
    g, r, d = read_image(grey), read_image(rgba), read_image(deep)
    assert g.shape == (3, 5, 7) and torch.allclose(g, torch.full_like(g, 128 / 255))
    assert r.shape == (3, 4, 4) and torch.allclose(r[:, 0, 0], torch.tensor([30, 20, 10]) / 255)  # BGRA -> RGB
    assert torch.equal(d, torch.ones(3, 3, 3))


def test_teachers_list_and_convert(tmp_path, capsys):
    assert main(["teachers", "list"]) == 0
    assert capsys.readouterr().out.splitlines()[:2] == ["composition  (default)", "ven"]
    src = tmp_path / "EvaluationNet.pth.tar"
    ven = VENTeacher.random(seed=3)
    torch.save(
        {"state_dict": {f"single_pass_net.{k}": v for k, v in ven.net.state_dict().items()}, "best": np.float64(1)}, src
    )
    assert main(["teachers", "convert-ven", str(src), str(tmp_path / "ven.pt")]) == 0
    assert "--weights" in capsys.readouterr().out
    assert set(torch.load(tmp_path / "ven.pt", weights_only=True)) == set(ven.net.state_dict())
