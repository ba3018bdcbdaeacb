"""Bad-input sweep: the commands this package's hardening owns (sim, dataset, score,
teachers) and the CLI's last-resort guard. Every bad input exits 2 with one ``error:`` line, no
traceback, no hang, and nothing written outside the output folder.
"""

import json
import shutil
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from aes_planner.cli import main
from tests.helpers import tree

SHOWCASE = Path(str(resources.files("aes_planner.sim") / "scenes" / "showcase.yaml"))
ASSET = Path(str(resources.files("aes_planner.sim") / "assets" / "sunset.png"))
SMALL = ["--width", "8", "--height", "6", "--supersample", "1", "--views", "1"]


@pytest.fixture
def work(tmp_path):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "binary.yaml").write_bytes(bytes(range(256)))
    scene = yaml.safe_load(SHOWCASE.read_text())
    scene["objects"][6]["material"]["image"] = "../outside.png"
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "escape.yaml").write_text(yaml.safe_dump(scene))
    shutil.copy(ASSET, tmp_path / "outside.png")
    return tmp_path


SIM_CASES = [
    (["--scene", "indoor:3", "--out", "{w}/a_file"], "not a folder"),
    (["--scene", "indoor:3", "--out", "{w}/a_file/sub"], "cannot create"),
    (["--scene", "indoor:3", "--views", "0", "--out", "{w}/o"], "--views"),
    (["--scene", "indoor:3", "--views", "-2", "--out", "{w}/o"], "--views"),
    (["--scene", "indoor:3", "--views", "100000000", "--out", "{w}/o"], "--views"),
    (["--scene", "indoor:3", "--width", "100000", "--out", "{w}/o"], "width"),
    (["--scene", "indoor:3", "--width", "0", "--out", "{w}/o"], "width"),
    (["--scene", "indoor:3", "--supersample", "0", "--out", "{w}/o"], "supersample"),
    (["--scene", "indoor:3", "--supersample", "1000", "--out", "{w}/o"], "supersample"),
    (["--scene", "indoor:-5", "--out", "{w}/o"], "out of range"),
    (["--scene", "indoor:" + "7" * 40, "--out", "{w}/o"], "out of range"),
    (["--scene", "{w}/missing.yaml", "--out", "{w}/o"], "neither a file nor"),
    (["--scene", "{w}/binary.yaml", "--out", "{w}/o"], "not UTF-8"),
    (["--scene", "{w}/scenes/escape.yaml", "--out", "{w}/o"], "leads outside"),
]


@pytest.mark.parametrize("argv, match", SIM_CASES, ids=range(len(SIM_CASES)))
def test_sim_render_bad_input(work, cli_error, argv, match):
    before = tree(work)
    argv = [a.format(w=work) for a in argv]
    cli_error(["sim", "render", *SMALL[:-2], *argv] if "--views" in argv else ["sim", "render", *SMALL, *argv], match)
    assert tree(work) == before  # nothing written anywhere


def test_sim_render_allow_outside_paths_is_the_opt_in(work, capsys):
    out = work / "o"
    assert main(["sim", "render", *SMALL, "--scene", str(work / "scenes" / "escape.yaml"), "--out", str(out),
                 "--allow-outside-paths"]) == 0  # fmt: skip
    assert {p.name for p in out.iterdir()} == {"cameras.json", "images", "depth"}


@pytest.fixture
def ns(tmp_path):
    folder = tmp_path / "ns"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.zeros((12, 16, 3), np.uint8))
    shutil.copy(folder / "a.png", tmp_path / "secret.png")

    def write(frames):
        (folder / "transforms.json").write_text(json.dumps({"fl_x": 20.0, "frames": frames}))
        return folder / "transforms.json"

    return write


def test_dataset_commands_bad_input(ns, tmp_path, cli_error):
    eye = np.eye(4).tolist()
    cli_error(["dataset", "import", "nerfstudio", ns([]), "--out", tmp_path / "o"], "nothing to import")
    cli_error(["dataset", "import", "nerfstudio", ns([{"file_path": "../secret.png", "transform_matrix": eye}]),
               "--out", tmp_path / "o"], "leads outside")  # fmt: skip
    good = ns([{"file_path": "a.png", "transform_matrix": eye}])
    cli_error(["dataset", "import", "nerfstudio", good, "--out", good], "not a folder")
    cli_error(["dataset", "import", "re10k", good, "--out", tmp_path / "o"], "needs --frames")
    (tmp_path / "clip.txt").write_bytes(bytes(range(256)))
    cli_error(["dataset", "import", "re10k", tmp_path / "clip.txt", "--frames", tmp_path, "--out", tmp_path / "o"],
              "not a text file")  # fmt: skip
    (tmp_path / "clip.txt").write_text("https://example.invalid/v\n")
    cli_error(["dataset", "import", "re10k", tmp_path / "clip.txt", "--frames", tmp_path, "--out", tmp_path / "o"],
              "nothing to import")  # fmt: skip
    cli_error(["dataset", "import", "re10k", tmp_path / "clip.txt", "--frames", tmp_path, "--every", "0",
               "--out", tmp_path / "o"], "every")  # fmt: skip
    assert not (tmp_path / "o").exists()
    cli_error(["dataset", "info", tmp_path / "nowhere"], "not found")
    cli_error(["dataset", "info", tmp_path / "clip.txt"], "not valid JSON")
    cli_error(["dataset", "info", tmp_path / "secret.png"], "not valid JSON")


def test_dataset_info_outside_paths_flag(ns, tmp_path, capsys, cli_error):
    path = ns([{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}])
    assert main(["dataset", "import", "nerfstudio", str(path), "--out", str(tmp_path / "ds")]) == 0
    doc = json.loads((tmp_path / "ds" / "cameras.json").read_text())
    doc["frames"][0]["image"] = str(tmp_path / "secret.png")
    (tmp_path / "ds" / "cameras.json").write_text(json.dumps(doc))
    cli_error(["dataset", "info", tmp_path / "ds"], "leads outside")
    capsys.readouterr()
    assert main(["dataset", "info", str(tmp_path / "ds"), "--allow-outside-paths"]) == 0
    assert "1 frames" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "render", "--scene", "indoor:3", "--views", "many", "--out", "o"],
        ["sim", "render", "--out", "o"],
        ["dataset", "import", "colmap", "x", "--out", "o"],
        ["score"],
        ["nonsense"],
    ],
)
def test_argument_errors_exit_2_without_traceback(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert "Traceback" not in capsys.readouterr().err


def test_unexpected_exceptions_are_one_line_and_visible_with_v(monkeypatch, capsys):
    import aes_planner.cli.sim as sim_cli

    def broken(args):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(sim_cli, "run_families", broken)
    assert main(["sim", "families"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unexpected RuntimeError: boom second line" in err and "bug" in err
    with pytest.raises(RuntimeError, match="boom"):
        main(["-v", "sim", "families"])


def test_bench_json_destination_is_checked_before_running(tmp_path, cli_error):
    (tmp_path / "afile").write_text("x")
    cli_error(["bench", "sim", "--quick", "--json", tmp_path], "is a folder", seconds=10)
    cli_error(["bench", "sim", "--quick", "--json", tmp_path / "afile" / "b.json"], "cannot write", seconds=10)
