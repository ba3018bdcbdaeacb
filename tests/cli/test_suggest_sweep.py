"""Bad-input sweep of ``suggest`` and the dataset folders it reads (``sim render``, ``dataset info``):
a damaged platform block, a rig file that sets nothing, a report path that is a symlink, folder or
FIFO, an unbounded ``--top``, a drone box thinner than a drone, a width that is not a number: one
``error:`` line with exit 2 before any work; full-resolution photos are downscaled as read, in
bounded memory; a closed pipe ends the command quietly.
"""

from pathlib import Path

import pytest

from aes_planner.cli import main

# ------------------------------------------------------------------------------ dataset folders


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "ds"
    argv = ["sim", "render", "--scene", "indoor:3", "--views", "2", "--width", "16", "--height", "12"]
    assert main([*argv, "--supersample", "1", "--out", str(root)]) == 0
    return root


META_CASES = {
    "rig_unknown_key": (lambda m: m["rig"].update(colour=1), "meta.rig.colour"),
    "rig_not_a_mapping": (lambda m: m.update(rig="x"), "meta.rig"),
    "platform_unknown": (lambda m: m.update(platform="submarine"), "meta.platform"),
    "rig_number_not_list": (lambda m: m["rig"].update(base_xyz_m=5), "meta.rig.base_xyz_m"),
    "rig_empty": (lambda m: m.update(rig={}), "meta.rig: empty"),
    "rig_base_far": (lambda m: m["rig"].update(base_xyz_m=[1e30, 0, 0]), "meta.rig.base_xyz_m: a coordinate of 1e+30"),
    "rig_lever_long": (lambda m: m["rig"].update(lever_arm_m=[1e6, 0, 0]), "meta.rig.lever_arm_m"),
    "drone_box_huge": (
        lambda m: m.update(platform="drone", drone={"bounds_min_m": [-1e300] * 3, "bounds_max_m": [1e300] * 3}),
        "meta.drone.bounds_min_m: a coordinate of 1e+300",
    ),
    "drone_box_wide": (
        lambda m: m.update(platform="drone", drone={"bounds_min_m": [0, 0, 0], "bounds_max_m": [1e7, 1, 1]}),
        "meta.drone.bounds_max_m: a box 1e+07 m across",
    ),
}


@pytest.mark.parametrize("how", sorted(META_CASES))
def test_suggest_dataset_meta_bad_platform(tmp_path, dataset, cli_error, how):
    import json
    import shutil

    folder = tmp_path / "ds"
    shutil.copytree(dataset, folder)
    doc = json.loads((folder / "cameras.json").read_text())
    fn, match = META_CASES[how]
    fn(doc["meta"])
    (folder / "cameras.json").write_text(json.dumps(doc))
    cli_error(["suggest", folder, "--scorer", "rgb", "--preset", "fast"], match)


@pytest.mark.parametrize("command", ["suggest", "demo"])
def test_a_symlinked_report_in_the_output_folder_is_refused_before_any_work(tmp_path, dataset, cli_error, command):
    out, victim = tmp_path / "out", tmp_path / "victim.png"
    out.mkdir()
    (out / "report.png").symlink_to(victim)
    argv = ["suggest", dataset, "--preset", "fast"] if command == "suggest" else ["demo", "--scene", "bogus:1"]
    cli_error([*argv, "--out", out], "report.png: is a symlink")
    assert not victim.exists()


def test_sim_render_refuses_a_camera_its_own_loader_would_refuse(tmp_path, cli_error):
    argv = ["sim", "render", "--scene", "indoor:3", "--views", "1", "--supersample", "1"]
    cli_error([*argv, "--width", "2000", "--height", "1", "--out", tmp_path / "wide"], "0.0389 deg fields of view")
    assert not (tmp_path / "wide" / "cameras.json").exists()
    cli_error([*argv, "--out", ""], "an empty value")


def test_suggest_rig_file_that_sets_nothing(tmp_path, dataset, cli_error):
    (tmp_path / "rig.yaml").write_text("# nothing\n")
    cli_error(["suggest", dataset, "--rig", tmp_path / "rig.yaml", "--preset", "fast"], "sets nothing")


def test_a_width_that_is_not_a_number_is_named(tmp_path, dataset, cli_error):
    import json
    import shutil

    folder = tmp_path / "ds"
    shutil.copytree(dataset, folder)
    doc = json.loads((folder / "cameras.json").read_text())
    doc["frames"][0]["width"] = str(doc["frames"][0]["width"])
    (folder / "cameras.json").write_text(json.dumps(doc))
    cli_error(["dataset", "info", folder], "frames[0].width: expected a whole number of pixels, got '16'")


def test_a_closed_pipe_ends_the_command_quietly(dataset):
    import subprocess
    import sys

    cmd = f"{sys.executable} -m aes_planner dataset info {dataset} | head -c 1"
    out = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, text=True, timeout=120)
    assert "error" not in out.stderr and "Traceback" not in out.stderr, out.stderr


def test_suggest_report_never_reads_a_scene_file_named_by_the_folder(tmp_path, dataset):
    from aes_planner.cli.suggest import _ground_truth

    meta = {"source": "aes-planner sim render", "scene": str(tmp_path / "elsewhere.yaml")}
    (tmp_path / "elsewhere.yaml").write_text("not: a scene\n")
    assert _ground_truth(meta, None) is None


# ------------------------------------------------------------------------ rig and drone folders


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep3")
    scenes = Path(__file__).parents[1] / "scenes"
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


# ----------------------------------------------------------------------- full-resolution photos


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


@pytest.mark.slow  # three processes; the reduced decode itself: tests/dataset/test_dataset.py
def test_suggest_on_full_resolution_photos_is_downscaled_and_bounded(folders, tmp_path):
    """Three 12 MP photos (and two of 24 MP, over a frame's size cap): decoded reduced and
    downscaled as read, so the command's peak RSS is that of the same suggestion on 640x480 photos
    plus little (it was 21.5 GB for eight 12 MP photos before they were downscaled). Measured
    against a baseline run in the same environment, not as an absolute figure: what torch, numba's
    kernels and the allocator cost varies with the machine and with whether the kernels are cached."""
    import subprocess
    import sys

    runs = (
        ("640x480", _photos(folders["rig"], tmp_path / "small", 640, 480)),
        ("4000x3000", _photos(folders["rig"], tmp_path / "photos", 4000, 3000)),
        ("6000x4000", _photos(folders["rig"], tmp_path / "big", 6000, 4000, count=2)),
    )
    code = (
        "import resource, sys\n"
        "from aes_planner.cli import main\n"
        "rc = main(['suggest', sys.argv[1], '--preset', 'fast'])\n"
        "print('maxrss_kb', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
        "sys.exit(rc)\n"
    )
    peak_mb = {}
    for size, folder in runs:
        out = subprocess.run([sys.executable, "-c", code, str(folder)], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        assert f"of {size} px downscaled as read" in out.stdout and "suggestion(s)" in out.stdout
        peak_mb[size] = int(out.stdout.split("maxrss_kb")[1].split()[0]) / 1024
    for size in ("4000x3000", "6000x4000"):
        # one 24 MP photo decoded whole is 72 MB of uint8 (288 MB as float): the margin admits neither twice
        assert peak_mb[size] - peak_mb["640x480"] < 150, f"peak RSS by photo size (MB): {peak_mb}"
