"""Bad-input sweep of training (aes_planner.field.train and ``train``): configs, cache workers, cache
entries (damaged, random, leaving the cache, declaring huge arrays), the resume checkpoint, and
values that can only diverge. Each is refused with one line naming the key or file, before any work
and before allocating what the file declares; a training step renders a bounded set of targets.
"""

import io
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from tests.helpers import write_checkpoint, write_file

# -------------------------------------------------------------------------------------- configs
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


@pytest.mark.parametrize(
    "line, key",
    [("lr: 1e30", "lr"), ("weight_decay: 1e30", "weight_decay"), ("score_weight: 1e300", "score_weight")],
)
def test_train_refuses_diverging_values_before_any_work(tmp_path, cli_error, line, key):
    config = write_file(tmp_path, "t.yaml", line + "\n")
    cli_error(["train", "--config", config, "--out", tmp_path / "o", "--cache", tmp_path / "c"], key)
    assert not (tmp_path / "o").exists() and not (tmp_path / "c").exists()


def test_train_refuses_targets_whose_maps_exceed_a_cache_entry(tmp_path, clean_error):
    from aes_planner.field.train import TrainConfig, build_cache
    from aes_planner.teachers.ven import VENTeacher

    cfg = TrainConfig(targets=10_000, search_targets=10_000)
    clean_error(build_cache, cfg, tmp_path / "c", None, VENTeacher.random(), match="targets")
    assert not (tmp_path / "c").exists()


# -------------------------------------------------------------------------------- cache entries


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


def _npz_bomb(path: Path, shape: tuple, how: str) -> Path:
    """A cache entry whose ``images`` member declares ``shape`` float64 but holds almost nothing:
    ``how="truncated"`` a header alone, ``"deflated"`` 16 MB of zeros compressed to a few kB."""
    import zipfile

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


# --------------------------------------------------------------------------------------- resume
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
    write_checkpoint(tmp_path / "last.npz", c)
    assert _resume(model, opt, tmp_path / "last.npz", steps=10) == 1
    RESUME_CASES[how](c)
    write_checkpoint(tmp_path / "last.npz", c)
    clean_error(_resume, model, opt, tmp_path / "last.npz", 10, match="last.npz")


def test_train_resume_refuses_an_old_torch_last_checkpoint(tmp_path, checkpoint, clean_error, no_unpickling):
    from aes_planner.field.train import TrainConfig, train

    (tmp_path / "last.pt").write_bytes(b"\x80\x02 never read")
    clean_error(train, TrainConfig(), [], tmp_path, resume=True, match="pickle-based format, which is never loaded")


# ----------------------------------------------------------------------------- targets per step


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
