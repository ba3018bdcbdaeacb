"""Bad-input sweep, third round (issue 33): every case ends in one ``error:`` line with exit 2 (or an
``AesPlannerError`` from the API), a documented safe result, or a rejection a running node counts.
Each case here crashed the interpreter, allocated gigabytes, hung, printed a traceback or was
silently accepted before it was fixed.
"""

import io
from pathlib import Path

import numpy as np
import pytest

from aes_planner.cli import main

RIG = "{base_xyz_m: [0, 0, 1.3], pan_limits_deg: [-150, 150], tilt_limits_deg: [-60, 60]}"


def write(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


# ----------------------------------------------------------------- 3. no input crashes the process
@pytest.mark.parametrize("device", ["-1", "-2", "-2147483648", "2147483648", "1e3", "[0]", "''", '"a\\0b"'])
def test_camera_device_is_checked_before_opencv_sees_it(tmp_path, cli_error, device):
    # cv2.VideoCapture(-1) dies of a segmentation fault: the config must refuse it first.
    launch = write(
        tmp_path,
        "cam.yaml",
        f"nodes:\n  - id: camera\n    type: camera\n    config: {{device: {device}, calibration: c.yaml, rig: {RIG}}}\n",
    )
    cli_error(["launch", launch, "--timeout", "5"], "device", seconds=30)


@pytest.mark.parametrize(
    "coefficients", ["[0.1, 0.0, 0.0]", "[0.1, 0, 0, 0, 0, 0]", "[" + ", ".join(["0.01"] * 15) + "]"]
)
def test_calibration_distortion_count_is_what_opencv_takes(tmp_path, clean_error, coefficients):
    from aes_planner.drivers.camera import load_calibration

    cal = write(
        tmp_path,
        "cal.yaml",
        "image_width: 64\nimage_height: 48\ncamera_matrix: {rows: 3, cols: 3, data: [50, 0, 32, 0, 50, 24, 0, 0, 1]}\n"
        f"distortion_coefficients: {coefficients}\n",
    )
    clean_error(load_calibration, cal, match="distortion_coefficients")


# ------------------------------------- 8. one validation path for every YAML file: wrong shapes named
SHAPES = {
    "type_list": ("nodes: [{id: p, type: [planner]}]\n", "nodes[0].type"),
    "type_mapping": ("nodes: [{id: p, type: {a: 1}}]\n", "nodes[0].type"),
    "type_missing": ("nodes: [{id: p}]\n", "nodes[0].type"),
    "id_list": ("nodes: [{id: [p], type: planner}]\n", "nodes[0].id"),
    "config_list": ("nodes: [{id: p, type: planner, config: [1]}]\n", "nodes[0].config"),
    "config_int_key": ("nodes: [{id: p, type: planner, config: {1: 2}}]\n", "nodes[0].config"),
    "remap_int": ("nodes: [{id: p, type: planner, remap: {a/b: 3}}]\n", "nodes[0].remap"),
    "respawn_str": ("nodes: [{id: p, type: planner, respawn: yes please}]\n", "nodes[0].respawn"),
    "nodes_mapping": ("nodes: {p: 1}\n", "nodes"),
    "nodes_ints": ("nodes: [1, 2]\n", "nodes[0]"),
    "nodes_string": ("nodes: abc\n", "nodes"),
    "only_external": ("nodes: [{id: fc, type: external}]\n", "external"),
    "huge_int": ("nodes: [{id: p, type: planner, config: {max_moves: 100000000000000000000000}}]\n", "64 bits"),
}


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("with_set", [False, True], ids=["plain", "set"])
def test_launch_file_of_the_wrong_shape_names_the_key(tmp_path, cli_error, name, with_set):
    text, key = SHAPES[name]
    launch = write(tmp_path, "l.yaml", text)
    extra = ["--set", "p.settle_s=0.5"] if with_set and name != "only_external" else []
    line = cli_error(["launch", launch, *extra, "--timeout", "3"], key, seconds=30)
    assert "unhashable" not in line and "has no attribute" not in line


def test_only_external_nodes_refused_by_a_multi_process_launch_too(tmp_path, cli_error):
    launch = write(tmp_path, "l.yaml", "nodes: [{id: fc, type: external}, {id: fc2, type: external}]\n")
    cli_error(["launch", launch, "--processes", "--timeout", "3"], "would start nothing", seconds=30)


@pytest.mark.parametrize(
    "args, match",
    [
        ('["--help"]', "emulator_args[0]"),
        ('["--models", "xl430-w250"]', "emulator_args[0]"),
        ('["--seed"]', "emulator_args[0]"),
        ('["--seed", "1e3"]', "invalid int value"),
        ('["--drop-rate", "2"]', "drop_rate"),
        ('["--link", "/nonexistent/folder/pty"]', "does not exist"),
    ],
)
def test_emulator_arguments_end_in_the_emulators_own_error(tmp_path, cli_error, args, match):
    launch = write(
        tmp_path,
        "g.yaml",
        "nodes:\n  - id: gimbal\n    type: gimbal\n"
        f"    config: {{emulate: true, emulator_args: {args}, device: {{type: dynamixel_pan_tilt, port: x}}}}\n",
    )
    cli_error(["launch", launch, "--timeout", "3"], match, seconds=20)  # not a 30 s wait


SCENE_EDITS = {
    "type_list": ("- type: box", "- type: [box]", "objects[1].type"),
    "type_mapping": ("- type: box", "- type: {box: 1}", "objects[1].type"),
    "light_type_list": ("- type: ambient", "- type: [ambient]", "lights[0].type"),
    "seed_huge_int": ("seed: 7}", "seed: 100000000000000000000000}", "64 bits"),
    "seed_float": ("seed: 7}", "seed: 1e23}", "seed"),
    "octaves_huge": ("octaves: 3,", "octaves: 100000000000000000000000,", "64 bits"),
}


@pytest.mark.parametrize("name", sorted(SCENE_EDITS))
def test_scene_file_of_the_wrong_shape_names_the_key(tmp_path, cli_error, name):
    old, new, key = SCENE_EDITS[name]
    showcase = (Path(__file__).parents[2] / "sim" / "scenes" / "showcase.yaml").read_text()
    assert old in showcase
    scene = write(tmp_path, "s.yaml", showcase.replace(old, new, 1))
    argv = ["sim", "render", "--scene", scene, "--views", "1", "--out", tmp_path / "out", "--allow-outside-paths"]
    cli_error([*argv, "--width", "32", "--height", "24"], key, seconds=60)
    assert not (tmp_path / "out").exists()


def test_a_post_init_that_breaks_on_a_value_is_a_config_error(clean_error):
    # The shared mechanism: whatever a dataclass's own check trips over is named, not a traceback.
    from dataclasses import dataclass

    from aes_planner.config import from_dict

    @dataclass
    class Odd:
        n: int = 1

        def __post_init__(self):
            float(2**self.n)  # OverflowError for a big n

    clean_error(from_dict, Odd, {"n": 5000}, "block", match="block: invalid value (OverflowError")


# -------------------------------------------------- 7. training values that can only diverge
@pytest.mark.parametrize(
    "line, key",
    [("lr: 1e30", "lr"), ("weight_decay: 1e30", "weight_decay"), ("score_weight: 1e300", "score_weight")],
)
def test_train_refuses_diverging_values_before_any_work(tmp_path, cli_error, line, key):
    config = write(tmp_path, "t.yaml", line + "\n")
    cli_error(["train", "--config", config, "--out", tmp_path / "o", "--cache", tmp_path / "c"], key)
    assert not (tmp_path / "o").exists() and not (tmp_path / "c").exists()


# ------------------------------------------------------------------------------ 12. smaller ones
@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep3")
    scenes = Path(__file__).parents[1] / "node" / "scenes"
    out = {}
    for name, scene in (("rig", "tabletop:0"), ("drone", str(scenes / "yard_drone.yaml"))):
        args = ["sim", "render", "--scene", scene, "--views", "3", "--out", str(root / name), "--supersample", "1"]
        assert main([*args, "--width", "32", "--height", "24"]) == 0
        out[name] = root / name
    return out


@pytest.mark.parametrize("top", ["1000000000", "65", "0", "-1"])
def test_suggest_top_is_bounded_by_what_a_suggestion_holds(folders, cli_error, top):
    cli_error(["suggest", folders["rig"], "--top", top], "--top", seconds=30)


@pytest.mark.parametrize("what", ["folder", "fifo"])
def test_suggest_out_where_report_png_is_not_a_file(folders, tmp_path, cli_error, what):
    import os

    out = tmp_path / "out"
    out.mkdir()
    (out / "report.png").mkdir() if what == "folder" else os.mkfifo(out / "report.png")
    cli_error(["suggest", folders["rig"], "--out", out], "report.png", seconds=30)


def test_a_report_that_cannot_be_written_is_an_error(tmp_path, clean_error):
    from aes_planner.images import write_image

    (tmp_path / "r.png").mkdir()
    clean_error(write_image, tmp_path / "r.png", np.zeros((4, 4, 3), np.uint8), match="could not write")
    clean_error(write_image, tmp_path / "r.unknown", np.zeros((4, 4, 3), np.uint8), match="could not write")


@pytest.mark.parametrize(
    "box", [([0, 0, 1], [0, 0, 1]), ([0, 0, 1], [1e-300, 1e-300, 1.0000001]), ([0, 0, 1], [2, 2, 1.05])]
)
def test_a_drone_box_thinner_than_a_drone_holds_is_refused(folders, tmp_path, cli_error, box):
    import json
    import shutil

    ds = tmp_path / "ds"
    shutil.copytree(folders["drone"], ds)
    doc = json.loads((ds / "cameras.json").read_text())
    doc["meta"]["drone"] = {"bounds_min_m": box[0], "bounds_max_m": box[1]}
    (ds / "cameras.json").write_text(json.dumps(doc))
    cli_error(["suggest", ds, "--preset", "fast"], "meta.drone", seconds=30)


@pytest.mark.parametrize(
    "argv",
    [
        ["score", "x.png", "--teacher", ""],
        ["score", "x.png", "--teacher", "  "],
        ["score", "x.png", "--teacher="],
        ["score", ""],
        ["suggest", "x", "--scorer", ""],
        ["launch", "sim_closed_loop", "--connect", ""],
        ["train", "--out", ""],
    ],
)
def test_an_empty_option_value_is_refused_not_taken_for_the_default(cli_error, argv):
    cli_error(argv, "an empty value", seconds=10)


@pytest.mark.parametrize("deg_s", [45001.0, 1500.0, 1e6])
def test_profile_velocity_is_bounded_by_what_the_servo_can_be_set_to(clean_error, deg_s):
    from aes_planner.drivers.dynamixel_config import DynamixelPanTiltConfig

    clean_error(DynamixelPanTiltConfig, port="/dev/x", profile_velocity_deg_s=deg_s, match="profile_velocity_deg_s")
    assert DynamixelPanTiltConfig(port="/dev/x", profile_velocity_deg_s=1400.0).profile_velocity_deg_s == 1400.0


# ------------------------------------------------- 6. full-resolution photos: downscaled at the boundary
def _photos(src: Path, dst: Path, width: int, height: int, count: int | None = None) -> Path:
    """The views of the dataset ``src`` as JPEG photos of ``width x height`` (intrinsics scaled, no depth)."""
    import json

    import cv2

    (dst / "images").mkdir(parents=True)
    doc = json.loads((src / "cameras.json").read_text())
    doc["frames"] = doc["frames"][:count]
    for f in doc["frames"]:
        img = cv2.resize(cv2.imread(str(src / f["image"])), (width, height), interpolation=cv2.INTER_CUBIC)
        f["image"] = f["image"].replace(".png", ".jpg")
        cv2.imwrite(str(dst / f["image"]), img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        s = width / f["width"]
        f.update(width=width, height=height, fx=f["fx"] * s, fy=f["fy"] * s, cx=f["cx"] * s, cy=f["cy"] * s)
        f.pop("depth", None)
    (dst / "cameras.json").write_text(json.dumps(doc))
    return dst


def test_downscale_frame_keeps_the_camera():
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.images import downscale_frame
    from aes_planner.messages import PosedFrame

    k = Intrinsics(3000.0, 3000.0, 2000.0, 1500.0, 4000, 3000)
    depth = np.full((3000, 4000), 2.0, np.float32)
    depth[:, :2000] = 0.0  # unknown on the left: never averaged into the known half
    frame = PosedFrame(np.zeros((3000, 4000, 3), np.uint8), k, np.eye(4), 1.0, depth, "f", pan_rad=0.1, tilt_rad=0.2)
    small = downscale_frame(frame, 320)
    assert small.image.shape == (240, 320, 3) and small.depth_m.shape == (240, 320)
    assert small.intrinsics.hfov_rad == pytest.approx(k.hfov_rad) and small.intrinsics.cx == pytest.approx(160.0)
    assert set(np.unique(small.depth_m)) == {0.0, 2.0} and (small.pan_rad, small.frame_id) == (0.1, "f")
    tiny = downscale_frame(small, 320)
    assert tiny is small


def test_suggest_on_full_resolution_photos_is_downscaled_and_bounded(folders, tmp_path):
    """Three 12 MP photos (and one of 24 MP, over a frame's size cap): read one at a time and
    downscaled; the whole command stays under 1.5 GB of peak RSS (measured ~0.5 GB for eight)."""
    import subprocess
    import sys

    photos = _photos(folders["rig"], tmp_path / "photos", 4000, 3000)
    big = _photos(folders["rig"], tmp_path / "big", 6000, 4000, count=2)
    code = (
        "import resource, sys\n"
        "from aes_planner.cli import main\n"
        "rc = main(['suggest', sys.argv[1], '--preset', 'fast'])\n"
        "print('maxrss_kb', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
        "sys.exit(rc)\n"
    )
    for folder, size in ((photos, "4000x3000"), (big, "6000x4000")):
        out = subprocess.run([sys.executable, "-c", code, str(folder)], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        assert f"of {size} px downscaled as read" in out.stdout and "suggestion(s)" in out.stdout
        rss_mb = int(out.stdout.split("maxrss_kb")[1].split()[0]) / 1024
        assert rss_mb < 1500, f"peak RSS {rss_mb:.0f} MB"


def test_the_planner_keeps_frames_at_the_working_size():
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.images import MAX_WORKING_SIDE_PX
    from aes_planner.messages import PosedFrame
    from aes_planner.node.planner import PlannerConfig, PlannerNode
    from tests.node.nodekit import RIG, FakeTeacher, ScriptedProposer

    node = PlannerNode(PlannerConfig(rig=RIG, active=False), proposer=ScriptedProposer(), teacher=FakeTeacher())
    k = Intrinsics(1000.0, 1000.0, 640.0, 480.0, 1280, 960)
    frame = PosedFrame(np.zeros((960, 1280, 3), np.uint8), k, ScriptedProposer().rig.forward(0.0, 0.0), 1.0)
    node.step({"camera/frame": [frame]}, 1.0)
    assert node.counters["frames_rejected"] == 0 and node._frame.width == MAX_WORKING_SIDE_PX


def _npz_bomb(path: Path, shape: tuple, how: str) -> Path:
    """A cache entry whose ``images`` member declares ``shape`` float64 but holds almost nothing:
    ``how="truncated"`` a header alone, ``"deflated"`` 16 MB of zeros compressed to a few kB."""
    import zipfile

    from tests.cli.test_cli_sweep_new import good_sample

    np.savez(path, **good_sample())
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    body = header.getvalue() + (b"\0" * (16 << 20) if how == "deflated" else b"")
    members = {}
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    members["images.npy"] = body
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for n, data in members.items():
            z.writestr(n, data)
    return path


@pytest.mark.parametrize(
    "shape, how", [((10**6, 10**6), "truncated"), ((2**31, 64), "deflated"), ((3, 3, 12, 16), "deflated")]
)
def test_a_cache_entry_that_declares_a_huge_array_is_refused_before_allocating(tmp_path, clean_error, shape, how):
    import tracemalloc

    from aes_planner.field.train import load_sample

    path = _npz_bomb(tmp_path / "s.npz", shape, how)
    tracemalloc.start()
    try:
        clean_error(load_sample, path, match="s.npz")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20, f"{peak / 2**20:.0f} MiB allocated before refusing"


def test_train_refuses_targets_whose_maps_exceed_a_cache_entry(tmp_path, clean_error):
    from aes_planner.field.train import TrainConfig, build_cache
    from aes_planner.teachers.ven import VENTeacher

    cfg = TrainConfig(targets=10_000, search_targets=10_000)
    clean_error(build_cache, cfg, tmp_path / "c", None, VENTeacher.random(), match="targets")
    assert not (tmp_path / "c").exists()


def test_a_training_step_renders_a_bounded_subset_of_targets():
    from aes_planner.field.train import TARGETS_PER_STEP, _some_targets

    rng = np.random.default_rng(0)
    t = 10_000
    sample = {"targets": np.zeros((t, 4, 4)), "target_maps": np.arange(t)[:, None], "target_scores": np.arange(t)}
    some = _some_targets(sample, rng)
    assert len(some["targets"]) == TARGETS_PER_STEP and np.all(np.diff(some["target_scores"]) > 0)
    assert np.array_equal(some["target_maps"][:, 0], some["target_scores"])  # the same targets in each array
    small = {k: v[:24] for k, v in sample.items()}
    assert _some_targets(small, rng) is small  # the usual sizes: every target, as before
