"""Bad-input sweep of the new boundaries: launch files and ``--set``, ``suggest``,
``eval search|field``, ``train`` (configs, caches, checkpoints), ``demo``, ``replay``, and the field
checkpoint loader. Every bad input ends in one ``error:`` line with exit 2 (or an
``AesPlannerError`` from the API), fast, before any long work, and writes nothing outside its
output folder. Each case here was a traceback, a hang, a "this is a bug" line or silently accepted
nonsense before it was fixed.
"""

import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.cli import main
from aes_planner.errors import AesPlannerError


def tree(folder: Path) -> set:
    return {p.relative_to(folder) for p in folder.rglob("*")}


@pytest.fixture
def work(tmp_path):
    (tmp_path / "a_file").write_text("x")
    return tmp_path


# ------------------------------------------------------------------------------ launch files
LAUNCH_FILES = {
    "list.yaml": ("- 1\n- 2\n", "is a mapping"),
    "scalar.yaml": ("42\n", "is a mapping"),
    "unicode_id.yaml": ("nodes: [{id: é, type: planner}]\n", "ASCII"),
    "long_id.yaml": ("nodes: [{id: " + "a" * 5000 + ", type: planner}]\n", "64 at most"),
    "bigint.yaml": ("nodes: [{id: p, type: planner, config: {max_moves: " + "9" * 5000 + "}}]\n", "cannot be read"),
    "month13.yaml": ("nodes: [{id: p, type: planner}]\nscene: !!timestamp 2001-13-45\n", "cannot be read"),
}


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_launch_file_bad_input(work, cli_error, name):
    text, match = LAUNCH_FILES[name]
    (work / name).write_text(text)
    cli_error(["launch", work / name, "--timeout", "5"], match, seconds=20)


def test_launch_remap_of_a_topic_the_node_does_not_have(work, cli_error):
    (work / "l.yaml").write_text("nodes: [{id: p, type: planner, remap: {no/such/topic: x/y}}]\n")
    cli_error(["launch", work / "l.yaml", "--timeout", "5"], "is not a topic of planner", seconds=30)


SET_CASES = [
    ("planner.max_moves=[1,2", "not valid YAML"),
    ("planner.max_moves=!!python/object/apply:os.system ['true']", "constructor"),
    ("planner.max_moves=" + "9" * 5000, "cannot be read"),
    ("planner.max_moves=&a [*a, *a]", "max_moves"),
]


@pytest.mark.parametrize("item, match", SET_CASES, ids=range(len(SET_CASES)))
def test_launch_set_bad_values(cli_error, item, match):
    cli_error(["launch", "sim_closed_loop", "--set", item, "--timeout", "5"], match, seconds=30)


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_launch_and_demo_timeout_must_be_finite_and_positive(work, cli_error, value):
    cli_error(["launch", "sim_closed_loop", "--timeout", value], "--timeout", seconds=10)
    cli_error(["demo", "--timeout", value, "--out", work / "run"], "--timeout", seconds=10)
    assert not (work / "run").exists()


@given(st.text(max_size=40))
def test_set_values_never_crash_the_launch_parser(text):
    from aes_planner.graph.launch_file import apply_overrides, parse_launch

    data = {"nodes": [{"id": "planner", "type": "planner"}]}
    try:
        parse_launch(apply_overrides(data, [f"planner.max_moves={text}", f"scene={text}"]))
    except AesPlannerError as exc:
        assert "\n" not in str(exc).strip() and len(str(exc)) < 1200


# ------------------------------------------------------------------------------ output paths
def out_cases(w):
    return [
        (["suggest", w / "nowhere", "--json", w], "is a folder"),
        (["suggest", w / "nowhere", "--json", w / "a_file" / "x.json"], "not a folder"),
        (["suggest", w / "nowhere", "--out", w / "a_file"], "not a folder"),
        (["suggest", w / "nowhere", "--out", w / "a_file" / "o"], "cannot create"),
        (["suggest", w / "nowhere", "--threads", "0"], "--threads"),
        (["suggest", w / "nowhere", "--threads", "100000"], "--threads"),
        (["eval", "search", "--scene", "indoor:1", "--json", w], "is a folder"),
        (["eval", "search", "--scene", "indoor:1", "--out", w / "a_file"], "not a folder"),
        (["eval", "field", "--scene", "indoor:1", "--out", w / "a_file"], "not a folder"),
        (["eval", "field", "--scene", "indoor:1", "--out", w / "o", "--json", w], "is a folder"),
        (["train", "--out", w / "a_file", "--cache", w / "cache"], "--out"),
        (["train", "--out", w / "o", "--cache", w / "a_file"], "--cache"),
        (["train", "--out", w / "o", "--cache", w / "a_file" / "c"], "--cache"),
        (["demo", "--out", w / "a_file"], "not a folder"),
        (["demo", "--out", w / "a_file" / "run"], "cannot create"),
    ]


@pytest.mark.parametrize("i", range(13))
def test_output_destinations_are_checked_before_the_work(work, cli_error, i):
    argv, match = out_cases(work)[i]
    before = tree(work)
    cli_error(argv, match, seconds=30)
    assert tree(work) - before <= {Path("cache"), Path("o")}  # at most the other (good) folder


def test_os_errors_on_a_named_file_are_one_line_not_a_bug(monkeypatch, capsys):
    import aes_planner.cli.sim as sim_cli

    def full_disk(args):
        raise OSError(28, "No space left on device", "/data/out.png")

    monkeypatch.setattr(sim_cli, "run_families", full_disk)
    assert main(["sim", "families"]) == 2
    err = capsys.readouterr().err
    assert err == "error: /data/out.png: No space left on device\n"


# ------------------------------------------------------------------------------ eval
EVAL_CASES = [
    (["eval", "search", "--scene", "indoor:1", "--oracle-step-deg", "1e-9"], "oracle_step_deg"),
    (["eval", "search", "--scene", "indoor:1", "--oracle-step-deg", "1e9"], "oracle_step_deg"),
    (["eval", "search", "--scene", "indoor:1", "--views", "999"], "views"),
    (["eval", "search", "--scene", "indoor:1", "--views", ""], "views"),
    (["eval", "search", "--scenes", "0"], "--scenes"),
    (["eval", "search", "--scenes", "-1"], "--scenes"),
    (["eval", "search", "--scene", "indoor:1", "--scene", "nowhere:1"], "unknown scene family"),
    (["eval", "field", "--scene", "indoor:1", "--targets", "100000000"], "targets"),
    (["eval", "field", "--scene", "indoor:1", "--render-width", "0"], "render_width_px"),
    (["eval", "field", "--scenes", "0"], "--scenes"),
    (["eval", "field", "--scenes", "100000000"], "--scenes"),
]


@pytest.mark.parametrize("argv, match", EVAL_CASES, ids=range(len(EVAL_CASES)))
def test_eval_bad_input(work, cli_error, argv, match):
    out = ["--out", str(work / "o")]
    cli_error([*argv, *out], match, seconds=30)


# ------------------------------------------------------------------------------ field checkpoints
@pytest.fixture(scope="module")
def checkpoint():
    from aes_planner.field.model import FieldModel, FieldModelConfig

    model = FieldModel(FieldModelConfig(hidden=4, encoder_channels=4), 4, (16, 16), "composition")
    return model.checkpoint({"step": 1})


class Evil:
    def __reduce__(self):
        return (print, ("unpickled!",))


def corrupt(ckpt, how):
    c = dict(ckpt)
    sd = dict(c["state_dict"])
    name = next(k for k, v in sd.items() if v.is_floating_point())
    if how == "nan":
        sd[name] = torch.full_like(sd[name], float("nan"))
    elif how == "huge":
        sd[name] = torch.full_like(sd[name], 1e30)
    elif how == "shape":
        sd[name] = sd[name].flatten()[:1]
    elif how == "state_str":
        return {**c, "state_dict": "x"}
    elif how == "no_config":
        del c["model_config"]
        return c
    elif how == "channels":
        return {**c, "feature_channels": -3}
    elif how == "channels_str":
        return {**c, "feature_channels": "abc"}
    elif how == "size":
        return {**c, "feature_size": 5}
    return {**c, "state_dict": sd}


def write(path, ckpt, how=None):
    """Write a checkpoint in the trainer's format (``tensorfile.save``: the trainer's own writer
    refuses NaN, a damaged file may still hold them); ``how="objects"``: then swap a weight for a
    pickled object array (``np.savez`` pickles those on write), which the loader must refuse unread."""
    from aes_planner import tensorfile

    tensorfile.save(path, ckpt)
    if how == "objects":
        with np.load(path) as npz:
            arrays = {k: npz[k] for k in npz.files}
        arrays["a0"] = np.array([Evil()], dtype=object)
        np.savez(path, **arrays)
    return path


CKPT_CASES = ["nan", "huge", "shape", "state_str", "no_config", "channels", "channels_str", "size", "objects"]


@pytest.mark.parametrize("how", CKPT_CASES)
def test_field_checkpoint_loader_refuses_damaged_files(tmp_path, checkpoint, clean_error, capsys, how):
    from aes_planner.field.model import load_model

    path = write(tmp_path / "model.npz", corrupt(checkpoint, how), how)
    clean_error(load_model, path, match=str(path))
    assert "unpickled!" not in capsys.readouterr().out


@pytest.mark.parametrize("cut", [0, 10, 200, -100])
def test_field_checkpoint_loader_refuses_truncated_files(tmp_path, checkpoint, clean_error, cut):
    from aes_planner.field.model import load_model

    write(tmp_path / "good.npz", checkpoint)
    assert load_model(tmp_path / "good.npz") is not None
    raw = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "bad.npz").write_bytes(raw[:cut])
    clean_error(load_model, tmp_path / "bad.npz", match="bad.npz")


def test_field_checkpoint_loader_refuses_an_old_torch_file(tmp_path, checkpoint, clean_error, capsys, request):
    from aes_planner.field.model import load_model

    torch.save({**checkpoint, "extra": Evil()}, tmp_path / "model.pt")
    request.getfixturevalue("no_unpickling")
    error = clean_error(load_model, tmp_path / "model.pt", match="model.pt")
    assert "pickle-based format, which is never loaded; retrain with `aes-planner train`" in str(error)
    assert "unpickled!" not in capsys.readouterr().out


def test_eval_field_model_flag_refuses_a_damaged_checkpoint(work, checkpoint, cli_error):
    write(work / "nan.npz", corrupt(checkpoint, "nan"))
    cli_error(["eval", "field", "--scene", "indoor:1", "--model", work / "nan.npz", "--out", work / "o"], "NaN")


@given(st.binary(max_size=300))
def test_field_checkpoint_loader_random_bytes(tmp_path_factory, data):
    from aes_planner.field.model import read_checkpoint

    path = tmp_path_factory.mktemp("ck") / "x.npz"
    path.write_bytes(data)
    with pytest.raises(AesPlannerError):
        read_checkpoint(path)


@given(st.data())
def test_field_checkpoint_loader_damaged_bytes(tmp_path_factory, checkpoint_bytes, data):
    from aes_planner.field.model import ModelError, load_model

    raw = bytearray(checkpoint_bytes)
    for _ in range(data.draw(st.integers(1, 3))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path_factory.mktemp("ck") / "x.npz"
    path.write_bytes(bytes(raw[: data.draw(st.integers(1, len(raw)))]))
    try:
        load_model(path)  # a change the archive cannot see (padding, a name byte of the JSON) may load
    except ModelError as exc:
        assert "x.npz" in str(exc) and "\n" not in str(exc)


@pytest.fixture(scope="module")
def checkpoint_bytes(checkpoint, tmp_path_factory):
    return write(tmp_path_factory.mktemp("ck") / "good.npz", checkpoint).read_bytes()


# ------------------------------------------------------------------------------ train
TRAIN_CONFIGS = {
    "seed: -1": "seed",
    "seed: 100000000000000000000": "seed",
    "threads: 0": "threads",
    "threads: 100000": "threads",
    "val_samples: -3": "val_samples",
    "warmup_steps: -10": "warmup_steps",
    "weight_decay: -1": "weight_decay",
    "targets: 100000000": "targets",
    "search_targets: 100000000": "search_targets",
}


@pytest.mark.parametrize("line", sorted(TRAIN_CONFIGS))
def test_train_config_bad_values(work, cli_error, line):
    (work / "t.yaml").write_text(line + "\n")
    cli_error(["train", "--config", work / "t.yaml", "--out", work / "o", "--cache", work / "c"], TRAIN_CONFIGS[line])
    assert not (work / "c").exists() and not (work / "o").exists()


def test_train_cache_workers_are_bounded(work, cli_error):
    cli_error(["train", "--cache-workers", "1000000", "--out", work / "o", "--cache", work / "c"], "--cache-workers")


def good_sample(views=2, targets=3):
    from aes_planner.field.train import _SPLAT_FIELDS

    rng = np.random.default_rng(0)
    eye = np.broadcast_to(np.eye(4), (views, 4, 4)).copy()
    return {
        **{f"splat_{n}": np.zeros(5, np.float32) for n in _SPLAT_FIELDS},
        "origin": np.zeros(3),
        "images": rng.integers(0, 255, (views, 3, 12, 16), dtype=np.uint8),
        "fmaps": rng.random((views, 4, 4, 4), dtype=np.float32),
        "cam2world_local": eye,
        "intrinsics": np.array([10.0, 10.0, 8.0, 6.0, 16, 12]),
        "stride": np.array(4),
        "targets": np.broadcast_to(np.eye(4), (targets, 4, 4)).copy(),
        "search_targets": np.array(0),
        "target_maps": rng.random((targets, 4, 4, 4), dtype=np.float32),
        "target_scores": rng.random(targets, dtype=np.float32),
    }


SAMPLE_CASES = {
    "missing": lambda a: a.pop("fmaps"),
    "nan": lambda a: a["fmaps"].fill(np.nan),
    "inf_targets": lambda a: a["targets"].fill(np.inf),
    "dtype": lambda a: a.update(images=a["images"].astype(np.float64)),
    "shape": lambda a: a.update(target_maps=a["target_maps"][:, :1]),
    "views": lambda a: a.update(fmaps=a["fmaps"][:1]),
    "objects": lambda a: a.update(images=np.array([{}], dtype=object)),
}


@pytest.mark.parametrize("how", sorted(SAMPLE_CASES))
def test_train_cache_sample_damaged(tmp_path, clean_error, how):
    from aes_planner.field.train import load_sample

    np.savez(tmp_path / "good.npz", **good_sample())
    assert set(load_sample(tmp_path / "good.npz")) >= {"fmaps", "targets"}
    a = good_sample()
    SAMPLE_CASES[how](a)
    np.savez(tmp_path / "bad.npz", **a, allow_pickle=True) if how == "objects" else np.savez(tmp_path / "bad.npz", **a)
    clean_error(load_sample, tmp_path / "bad.npz", match="bad.npz")


@given(st.binary(max_size=400))
def test_train_cache_sample_random_bytes(tmp_path_factory, data):
    from aes_planner.field.train import load_sample

    path = tmp_path_factory.mktemp("cache") / "x.npz"
    path.write_bytes(data)
    with pytest.raises(AesPlannerError, match="x.npz"):
        load_sample(path)


RESUME_CASES = {
    "step_negative": lambda c: c.update(step=-5),
    "step_past_the_end": lambda c: c.update(step=10**12),
    "step_done": lambda c: c.update(step=10),
    "no_optimizer": lambda c: c.pop("optimizer"),
    "bad_optimizer": lambda c: c.update(optimizer={"x": 1}),
    "nan": lambda c: c["state_dict"].update({k: torch.full_like(v, float("nan")) for k, v in c["state_dict"].items()}),
    "not_ours": lambda c: c.update(format=99),
}


@pytest.mark.parametrize("how", sorted(RESUME_CASES))
def test_train_resume_refuses_damaged_last_checkpoint(tmp_path, checkpoint, clean_error, how):
    from aes_planner.field.model import FieldModel
    from aes_planner.field.train import _resume

    model = FieldModel.from_checkpoint(checkpoint)
    opt = torch.optim.AdamW(model.parameters())
    c = {**checkpoint, "state_dict": dict(checkpoint["state_dict"]), "optimizer": opt.state_dict()}
    write(tmp_path / "last.npz", c)
    assert _resume(model, opt, tmp_path / "last.npz", steps=10) == 1
    RESUME_CASES[how](c)
    write(tmp_path / "last.npz", c)
    clean_error(_resume, model, opt, tmp_path / "last.npz", 10, match="last.npz")


def test_train_resume_refuses_an_old_torch_last_checkpoint(tmp_path, checkpoint, clean_error, no_unpickling):
    from aes_planner.field.train import TrainConfig, train

    (tmp_path / "last.pt").write_bytes(b"\x80\x02 never read")
    clean_error(train, TrainConfig(), [], tmp_path, resume=True, match="pickle-based format, which is never loaded")


def test_train_cache_entry_that_is_a_folder_or_leaves_the_cache(tmp_path, clean_error):
    from aes_planner.field.train import TrainConfig, build_cache

    cfg = TrainConfig(samples=1, val_samples=0, families=["indoor"], sources=["rig"], targets=1, search_targets=0)
    teacher = cfg.make_teacher()

    def no_render(name):
        raise AssertionError("must not render")

    (tmp_path / "c").mkdir()
    # the name the cache gives sample 0
    name, kind, views, seed = cfg.sample_spec(0)
    sc = cfg.scorer
    file = f"{name.replace(':', '-')}_{kind}_v{views}_r{seed}_{teacher.name}_w{sc.render_width_px}"
    file += f"_g{sc.max_gaussians}_t{cfg.targets}_s{cfg.gt_supersample}.npz"
    (tmp_path / "c" / file).mkdir()
    clean_error(build_cache, cfg, tmp_path / "c", no_render, teacher, match="not a file")
    (tmp_path / "c" / file).rmdir()
    (tmp_path / "secret.npz").write_bytes(b"x")
    (tmp_path / "c" / file).symlink_to(tmp_path / "secret.npz")
    clean_error(build_cache, cfg, tmp_path / "c", no_render, teacher, match="outside the cache")


# ------------------------------------------------------------------------------ suggest
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


# ------------------------------------------------------------------------------ replay
@pytest.fixture
def recording(tmp_path):
    """A recording with a malformed message, one of another type on the same topic, and a
    clock jump of 30 years, written with the MCAP writer directly."""
    from mcap.writer import Writer

    from aes_planner.messages import Diagnostics, encode
    from aes_planner.messages.samples import sample_messages
    from aes_planner.transport.foxglove_view import OUR_ENCODING, our_schema

    good = encode(Diagnostics(1.0, "n"))
    other = encode(sample_messages()["GimbalState"])
    path = tmp_path / "r.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        name, enc, data = our_schema("Diagnostics", 1)
        ch = w.register_channel("/t/d", OUR_ENCODING, w.register_schema(name, enc, data))
        for i, (payload, t) in enumerate([(good, 0), (good[: len(good) // 2], 1), (other, 2), (good, 10**18)]):
            w.add_message(ch, log_time=t, publish_time=t, data=payload, sequence=i)
        w.finish()
    return path


def test_replay_skips_what_does_not_decode_and_caps_clock_jumps(recording, monkeypatch, deadline):
    from aes_planner.messages import Diagnostics
    from aes_planner.transport import InProcessBus
    from aes_planner.transport import record as rec

    monkeypatch.setattr(rec, "MAX_REPLAY_GAP_S", 0.05)
    bus = InProcessBus()
    sub = bus.subscribe("t/d", Diagnostics, depth=10)
    with deadline(10):
        n = rec.replay(recording, bus, rate=1.0)
    assert n == 2  # the first and the last; truncated and foreign-typed ones skipped
    assert len(sub.take()) == 2 and sub.rejected == 0
    bus.close()


@pytest.mark.parametrize("rate", ["1e-300", "nan", "-1", "inf", "5000"])
def test_replay_rate_bounds(recording, cli_error, rate):
    cli_error(["replay", recording, "--rate", rate, "--wait", "0"], "--rate", seconds=10)


def test_replay_topics_are_checked(recording, cli_error):
    cli_error(["replay", recording, "--topics", "bad topic", "--wait", "0"], "topic name", seconds=10)


# ------------------------------------------------------------------------------ node runner
def test_a_node_with_a_very_long_period_still_stops_promptly():
    from aes_planner.graph.base import Node
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.messages import Diagnostics
    from aes_planner.transport import InProcessBus

    class Slow(Node):
        config_class = dict
        inputs = {"x/in": (Diagnostics, 1)}

        @property
        def period_s(self):
            return 1e9

        def step(self, inputs, now):
            return {}

    bus = InProcessBus()
    runner = NodeRunner(Slow({}, "slow"), bus)
    runner.open()
    runner.start_thread()
    time.sleep(0.2)
    t0 = time.monotonic()
    runner.request_stop()
    runner.join(5.0)
    assert time.monotonic() - t0 < 1.0 and not runner._thread.is_alive()
    runner.close()
    bus.close()


PROCESS_LAUNCHES = {
    "remap.yaml": ("nodes: [{id: p, type: planner, remap: {no/such/topic: x/y}}]\n", "is not a topic of planner"),
    "noscene.yaml": ("nodes: [{id: c, type: sim_camera}]\n", "needs a scene"),
    "badscene.yaml": ("scene: nowhere:1\nnodes: [{id: c, type: sim_camera}]\n", "unknown scene family"),
}


@pytest.mark.parametrize("name", sorted(PROCESS_LAUNCHES))
def test_multi_process_launch_checks_what_the_children_would_die_of(work, cli_error, name):
    text, match = PROCESS_LAUNCHES[name]
    (work / name).write_text(text)
    cli_error(["launch", work / name, "--processes", "--timeout", "5"], match, seconds=30)


def test_alias_bomb_message_is_said_once(work, cli_error):
    lines = ['a: &a ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"{c}: &{c} [{', '.join(['*' + p] * 9)}]" for p, c in zip("abcdefgh", "bcdefghi")]
    (work / "bomb.yaml").write_text("\n".join(lines) + "\nnodes: [{id: p, type: planner}]\n")
    line = cli_error(["launch", work / "bomb.yaml"], "expands to more than")
    assert "cannot be read" not in line


def test_multi_process_launch_needs_a_fixed_hub_port(cli_error):
    cli_error(["launch", "sim_closed_loop", "--processes", "--listen", "tcp/127.0.0.1:0"], "fixed port", seconds=30)
