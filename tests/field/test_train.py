"""Training: a short run lowers the loss; data-parallel replicas stay identical; the shipped
checkpoint loads from the installed package and predicts finite scores."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from aes_planner import tensorfile
from aes_planner.config import ConfigError
from aes_planner.field.model import DEFAULT_CHECKPOINT, FieldModel, load_model, read_checkpoint
from aes_planner.field.train import (
    TRAIN_SEED_START,
    VAL_SEED_START,
    CacheError,
    arrays_to_inputs,
    build_cache,
    expectile_loss,
    listwise_loss,
    load_config,
    load_sample,
    sample_loss,
    train,
)
from aes_planner.sim import SimCameraConfig, SimSource
from aes_planner.teachers import get_teacher

TINY = {
    "samples": 2,
    "val_samples": 1,
    "families": ["tabletop"],
    "sources": ["free", "rig"],
    "min_views": 2,
    "max_views": 2,
    "targets": 3,
    "gt_supersample": 1,
    "checkpoint_every": 10,
    "warmup_steps": 2,
    "lr": 0.01,
    "scorer": {"render_width_px": 16},
    "model": {"embed_dim": 2, "encoder_channels": 4, "hidden": 8, "attention_dim": 4},
}


def _source(name):
    return SimSource(name, camera=SimCameraConfig(width=32, height=24, supersample=1))


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    d = tmp_path_factory.mktemp("cache")
    cfg = load_config({**TINY, "steps": 1})
    teacher = get_teacher()
    return build_cache(cfg, d, _source, teacher), build_cache(cfg, d, _source, teacher, split="val")


def test_splits_use_disjoint_seeds(cache):
    cfg = load_config(TINY)
    train_seeds = {int(cfg.sample_spec(i)[0].split(":")[1]) for i in range(50)}
    val_seeds = {int(cfg.sample_spec(i, "val")[0].split(":")[1]) for i in range(50)}
    assert min(train_seeds) >= TRAIN_SEED_START > max(val_seeds) >= VAL_SEED_START
    train_files, val_files = cache
    assert len(train_files) == 2 and len(val_files) == 1 and all(p.exists() for p in train_files + val_files)


def test_short_training_lowers_the_loss_and_resumes(cache, tmp_path):
    train_files, val_files = cache
    cfg = load_config({**TINY, "steps": 30})
    teacher = get_teacher()
    data = [load_sample(p) for p in train_files]

    def loss_of(model):
        with torch.no_grad():
            return sum(float(sample_loss(model, teacher, d, arrays_to_inputs(d), 4.0, 16)[0]) for d in data)

    first = train(load_config({**TINY, "steps": 20}), train_files, tmp_path, val_samples=val_files)
    train(cfg, train_files, tmp_path, resume=True)
    out = tmp_path / "model.npz"
    ckpt = read_checkpoint(out)
    assert "optimizer" in read_checkpoint(tmp_path / "last.npz") and "optimizer" not in ckpt
    assert ckpt["step"] == 30 and ckpt["teacher"] == "composition" and "code_version" in ckpt
    assert ckpt["train_config"]["steps"] == 30
    fresh = FieldModel(first.config, 4, (16, 16), "composition")
    fresh.map_scale.copy_(first.map_scale)
    assert loss_of(load_model(out)) < loss_of(fresh)
    metrics = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert all(np.isfinite(m["val_plcc"]) for m in metrics)


def test_torchrun_replicas_stay_identical(cache, tmp_path):
    train_files, _ = cache
    script = tmp_path / "ddp.py"
    script.write_text(
        "import os, sys\n"
        "from aes_planner import tensorfile\n"
        "from pathlib import Path\n"
        "from aes_planner.field import train as T\n"
        f"cfg = T.load_config({{**{TINY!r}, 'steps': 4, 'checkpoint_every': 100}})\n"
        f"files = [Path(p) for p in {[str(p) for p in train_files]!r}]\n"
        "out = Path(sys.argv[1])\n"
        "model = T.train(cfg, files, out / os.environ['RANK'])\n"
        "tensorfile.save(out / f\"rank{os.environ['RANK']}.npz\", dict(model.state_dict()))\n"
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with socket.socket() as sock:  # a free port: two suites running at once must not meet
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_addr", "127.0.0.1"]
    cmd += ["--master_port", str(port)]
    subprocess.run([*cmd, str(script), str(tmp_path)], check=True, env=env, timeout=600, capture_output=True)
    a = tensorfile.load(tmp_path / "rank0.npz")
    b = tensorfile.load(tmp_path / "rank1.npz")
    assert all(torch.equal(a[k], b[k]) for k in a)
    fresh = FieldModel(load_config(TINY).model, 4, (16, 16), "composition").state_dict()
    assert not torch.equal(a["embed.0.weight"], fresh["embed.0.weight"])  # they trained, and agree


def test_shipped_checkpoint_loads_offline_from_the_package():
    code = (
        "import socket\n"
        "def refuse(*a, **k): raise OSError('network disabled in this test')\n"
        "socket.socket.connect = refuse; socket.create_connection = refuse\n"
        "import numpy as np, torch\n"
        "from importlib import resources\n"
        "from aes_planner.field import AestheticField\n"
        "from aes_planner.geometry.poses import view_to_cam2world\n"
        f"assert resources.files('aes_planner.field').joinpath({DEFAULT_CHECKPOINT!r}).is_file()\n"
        "f = AestheticField.load_default()\n"
        "out = f.score(torch.from_numpy(view_to_cam2world(np.array([[0.0, 0, 1, 0.3, 0.1]]))))\n"
        "assert torch.isfinite(out.score).all(); print('ok', f.model.config.embed_dim)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=Path.home())
    assert res.returncode == 0 and res.stdout.startswith("ok"), res.stderr[-2000:]


def test_samples_carry_search_targets_and_validation_scores_their_order(cache, tmp_path):
    train_files, val_files = cache
    cfg = load_config(TINY)
    for path in train_files + val_files:
        d = load_sample(path)
        n_search = int(d["search_targets"])
        assert n_search == cfg.search_targets == 12
        assert len(d["targets"]) == len(d["target_scores"]) == cfg.targets + n_search
    model = train(load_config({**TINY, "steps": 2}), train_files, tmp_path, val_samples=val_files)
    metrics = json.loads((tmp_path / "metrics.jsonl").read_text().splitlines()[-1])
    assert np.isfinite(metrics["val_plcc_search"]) and model is not None


def test_rig_search_targets_cover_the_joint_range_and_keep_the_plan():
    from aes_planner.field.protocol import plan_views
    from aes_planner.geometry.pantilt import PanTilt

    platform = _source("indoor:1000").platform
    plain = plan_views(platform, "rig", 4, 10, np.random.default_rng(3))
    with_search = plan_views(platform, "rig", 4, 10, np.random.default_rng(3), n_search=200)
    assert plain.search_targets is None
    assert np.array_equal(plain.inputs, with_search.inputs) and np.array_equal(plain.targets, with_search.targets)
    pt = PanTilt(platform.rig)
    joints = np.array(
        [[(s := pt.inverse_direction(pose[:3, 2])).pan_rad, s.tilt_rad] for pose in with_search.search_targets]
    )  # [200, 2]
    (plo, phi), (tlo, thi) = pt.pan_limits_rad, pt.tilt_limits_rad
    assert joints[:, 0].min() >= plo - 1e-6 and joints[:, 0].max() <= phi + 1e-6
    assert joints[:, 1].min() >= tlo - 1e-6 and joints[:, 1].max() <= thi + 1e-6
    # spread over the range, unlike the trajectory (which stays within a few degrees of one tilt)
    assert np.ptp(joints[:, 1]) > 0.8 * (thi - tlo) and np.ptp(joints[:, 0]) > 0.8 * (phi - plo)


def test_sweep_and_survey_samples_take_their_inputs_as_the_product_does():
    from aes_planner.field.protocol import plan_views
    from aes_planner.geometry.pantilt import PanTilt
    from aes_planner.platform import RIG_FREE_BOX_HALF_M
    from aes_planner.sim.spec import DroneSpec

    platform = _source("indoor:1000").platform
    pt = PanTilt(platform.rig)
    (plo, phi), (tlo, thi) = pt.pan_limits_rad, pt.tilt_limits_rad
    depths = set()
    for seed in range(6):
        plan = plan_views(platform, "sweep", 4, 40, np.random.default_rng(seed), n_search=8)
        joints = pt.sweep(4)
        assert np.allclose(plan.inputs, pt.forward(joints[:, 0], joints[:, 1]))  # sim render's, the planner's
        aims = np.array([[(s := pt.inverse_direction(p[:3, 2])).pan_rad, s.tilt_rad] for p in plan.targets])
        assert (aims[:, 0] >= plo - 1e-6).all() and (aims[:, 0] <= phi + 1e-6).all()
        assert (aims[:, 1] >= tlo - 1e-6).all() and (aims[:, 1] <= thi + 1e-6).all()
        # the targets are stage-1 candidates: within the search's jitter of the sweep's path
        path = np.concatenate([np.linspace(a, b, 200) for a, b in zip(joints[:-1], joints[1:])])  # [P, 2]
        off = np.abs(aims[:, None] - path[None]).max(-1).min(-1)  # [T] per-axis offset from the path
        assert off.max() <= 0.35 * platform.intrinsics.hfov_rad + 0.02
        depths.add(plan.depth)
    assert depths == {True, False}  # half the sweeps carry depth, as the simulator writes it
    base = np.asarray(platform.rig.base_xyz_m)
    lo, hi = base - RIG_FREE_BOX_HALF_M, base + RIG_FREE_BOX_HALF_M
    arcs = 0
    for seed in range(6):
        plan = plan_views(platform, "survey", 1 + seed, 20, np.random.default_rng(seed), n_search=20)
        assert plan.depth
        arc = DroneSpec(bounds_min_m=tuple(np.maximum(lo, [-np.inf, -np.inf, 0.3])), bounds_max_m=tuple(hi))
        arcs += bool(np.allclose(plan.inputs, arc.survey_poses(1 + seed)))  # else along the diagonal
        for poses in (plan.inputs, plan.targets, plan.search_targets):
            xyz = poses[:, :3, 3]
            assert np.isfinite(poses).all() and (xyz >= lo - 1e-9).all() and (xyz <= hi + 1e-9).all()
    assert 0 < arcs < 6  # both patterns: a drone's survey arc and the diagonal
    with pytest.raises(ConfigError, match="sources"):
        load_config({**TINY, "sources": ["sweep", "orbit"]})


def test_cache_workers_render_the_same_samples(tmp_path):
    import functools

    cfg = load_config({**TINY, "samples": 2})
    make = functools.partial(SimSource, camera=SimCameraConfig(width=32, height=24, supersample=1))
    teacher = get_teacher()
    one = build_cache(cfg, tmp_path / "one", make, teacher)
    two = build_cache(cfg, tmp_path / "two", make, teacher, workers=2)
    assert [p.name for p in one] == [p.name for p in two] and all(p.exists() for p in two)
    for a, b in zip(one, two, strict=True):
        da, db = load_sample(a), load_sample(b)
        assert da.keys() == db.keys() and all(np.array_equal(da[k], db[k]) for k in da)
    assert not list((tmp_path / "two").glob("*.tmp.npz"))


def test_listwise_loss_is_zero_for_the_teachers_order_and_weights_the_top():
    true = torch.tensor([0.50, 0.52, 0.61, 0.40, 0.58], dtype=torch.float64)
    assert float(listwise_loss(true.clone(), true, 0.5)) == pytest.approx(0.0, abs=1e-12)
    reversed_ = listwise_loss(-true, true, 0.5)
    top_swapped = listwise_loss(true[[0, 1, 4, 3, 2]], true, 0.5)  # the best two exchanged
    bottom_swapped = listwise_loss(true[[3, 1, 2, 0, 4]], true, 0.5)  # the worst two exchanged
    assert float(reversed_) > float(top_swapped) > float(bottom_swapped) > 0
    pred = true.clone().requires_grad_()
    (listwise_loss(pred * 0.5, true, 0.5)).backward()
    assert torch.isfinite(pred.grad).all() and float(pred.grad.abs().sum()) > 0
    flat = torch.full((4,), 0.5, dtype=torch.float64)
    assert float(listwise_loss(torch.randn(4, dtype=torch.float64), flat, 0.5)) == 0.0  # no order to learn


def test_expectile_loss_is_the_mse_at_one_half_and_leans_against_over_estimates():
    err = torch.tensor([0.3, -0.3, 0.1, -0.2], dtype=torch.float64)
    assert float(expectile_loss(err, 0.5)) == pytest.approx(float(err.pow(2).mean()), rel=1e-12)
    over, under = torch.tensor([0.2], dtype=torch.float64), torch.tensor([-0.2], dtype=torch.float64)
    assert float(expectile_loss(over, 0.25)) == pytest.approx(3 * float(expectile_loss(under, 0.25)))
    # the constant that minimises it over a spread of targets sits below their mean at 0.25
    targets = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    grid = torch.linspace(0, 1, 1001, dtype=torch.float64)
    best = grid[int(torch.argmin(torch.stack([expectile_loss(c - targets, 0.25) for c in grid])))]
    assert float(best) == pytest.approx(1 / 10, abs=1e-3)  # tau * 1 / (tau * 1 + (1 - tau) * 3)
    with pytest.raises(ConfigError, match="expectile"):
        load_config({**TINY, "expectile": 1.0})
    with pytest.raises(ConfigError, match="expectile"):
        load_config({**TINY, "expectile": float("nan")})


def test_listwise_and_init_from_knobs_are_checked():
    with pytest.raises(ConfigError, match="listwise_temperature"):
        load_config({**TINY, "listwise_temperature": 0.0})
    with pytest.raises(ConfigError, match="listwise_weight"):
        load_config({**TINY, "listwise_weight": -1.0})
    for bad in ({"hard_top": 0, "hard_random": 0}, {"hard_top": -1}, {"hard_random": 1001}):
        with pytest.raises(ConfigError, match="hard_top"):
            load_config({**TINY, **bad})
    with pytest.raises(ConfigError, match="hard_views"):
        load_config({**TINY, "hard_views": 0})
    with pytest.raises(ConfigError, match="hard_samples"):
        load_config({**TINY, "hard_samples": -1})


def test_init_from_starts_at_the_checkpoints_weights(cache, tmp_path):
    train_files, val_files = cache
    first = train(load_config({**TINY, "steps": 3}), train_files, tmp_path / "a")
    tuned_cfg = {
        **TINY,
        "steps": 1,
        "lr": 1e-12,
        "init_from": str(tmp_path / "a" / "model.npz"),
        "listwise_weight": 1.0,
    }
    tuned = train(load_config(tuned_cfg), train_files, tmp_path / "b", val_samples=val_files)
    for (name, a), b in zip(first.state_dict().items(), tuned.state_dict().values(), strict=True):
        assert torch.allclose(a, b, atol=1e-6), name  # one step at lr 1e-12 from the same weights
    metrics = json.loads((tmp_path / "b" / "metrics.jsonl").read_text().splitlines()[-1])
    assert -10.0 < metrics["val_top1_search"] <= 1.0
    with pytest.raises(CacheError, match="init_from default"):  # the shipped model is another architecture
        train(load_config({**TINY, "steps": 1, "init_from": "default"}), train_files, tmp_path / "c")


# ----------------------------------------------------------- divergence stops training, never saved
@pytest.mark.parametrize(
    "knob",
    ["lr: 1e30", "lr: 2", "weight_decay: 1e30", "score_weight: 1e300", "rank_weight: 1e4", "listwise_weight: 5e3"],
)
def test_config_values_that_can_only_diverge_are_refused(knob):
    from aes_planner.config import load_yaml_text

    key = knob.split(":")[0]
    with pytest.raises(ConfigError, match=key):
        load_config({**TINY, **load_yaml_text(knob)})


def _finite_checkpoints(folder: Path) -> list[Path]:
    files = sorted(folder.glob("*.npz"))
    for f in files:
        ckpt = read_checkpoint(f)
        assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values()), f
    return files


@pytest.mark.parametrize("where", ["loss", "weights"])
def test_divergence_stops_with_an_error_and_keeps_the_last_finite_checkpoint(cache, tmp_path, monkeypatch, where):
    from aes_planner.field import train as train_module
    from aes_planner.field.train import TrainingDivergedError

    real_loss, real_step = train_module.sample_loss, torch.optim.AdamW.step
    calls = {"n": 0}

    def loss_nan_at_3(*args, **kwargs):
        loss, parts = real_loss(*args, **kwargs)
        calls["n"] += 1
        return (loss * float("nan"), parts) if calls["n"] == 3 else (loss, parts)

    def step_inf_at_3(self, *args, **kwargs):
        out = real_step(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 3:
            with torch.no_grad():
                self.param_groups[0]["params"][0].fill_(float("inf"))
        return out

    if where == "loss":
        monkeypatch.setattr(train_module, "sample_loss", loss_nan_at_3)
    else:
        monkeypatch.setattr(torch.optim.AdamW, "step", step_inf_at_3)
    cfg = load_config({**TINY, "steps": 6, "checkpoint_every": 1, "val_samples": 0})
    with pytest.raises(TrainingDivergedError, match="diverged at step 3") as info:
        train(cfg, cache[0], tmp_path)
    assert "last finite checkpoint is kept" in str(info.value) and "lr" in str(info.value)
    assert read_checkpoint(tmp_path / "last.npz")["step"] == 2
    assert len(_finite_checkpoints(tmp_path)) == 2


def test_a_non_finite_checkpoint_is_never_written(tmp_path):
    from aes_planner.field.model import ModelError, write_checkpoint

    model = FieldModel(load_config(TINY).model, 4, (16, 16), "composition")
    ckpt = model.checkpoint({"optimizer": {"state": {0: {"exp_avg": torch.tensor([1.0, float("inf")])}}}})
    with pytest.raises(ModelError, match="NaN or Inf"):
        write_checkpoint(tmp_path / "m.npz", ckpt)
    assert not list(tmp_path.iterdir())


def test_hard_targets_are_the_suggestions_the_search_top_and_random_others():
    from aes_planner.field.train import hard_targets

    rng = np.random.default_rng(0)
    poses = np.repeat(np.eye(4)[None], 10, 0)
    poses[:, 0, 3] = np.arange(10)  # candidate i sits at x = i
    objective = np.array([0.1, 0.9, 0.3, 0.8, 0.2, 0.7, 0.0, 0.6, 0.5, 0.4])
    sugg = np.eye(4)[None].copy()
    sugg[0, 1, 3] = 5.0
    got = hard_targets(poses, objective, sugg, top=3, n_random=4, rng=rng)  # [1 + 3 + 4, 4, 4]
    x = got[:, 0, 3]
    assert got.shape == (8, 4, 4) and got[0, 1, 3] == 5.0  # the suggestion first
    assert list(x[1:4]) == [1, 3, 5]  # then the best three by the objective, best first
    rest = set(x[4:])
    assert len(rest) == 4 and rest <= {0, 2, 4, 6, 7, 8, 9}  # four others, none repeated
    # fewer candidates than asked: all of them, once
    few = hard_targets(poses[:3], objective[:3], np.zeros((0, 4, 4)), top=2, n_random=5, rng=rng)
    assert sorted(few[:, 0, 3]) == [0, 1, 2]
    with pytest.raises(ConfigError, match="candidates"):
        hard_targets(poses, objective[:4], sugg, 3, 4, rng)


def test_hard_samples_take_the_survey_sweep_and_the_teacher_at_the_searchs_views(tmp_path):
    from aes_planner.field.train import HARD_SEED_OFFSET, hard_targets

    calls = []

    def propose(frames, inputs, platform, seed):  # a stand-in search: 6 candidates near the first input
        calls.append((len(frames), inputs.copy(), seed))
        assert all(f.depth_m is None for f in frames)  # RGB only, as a real rig
        cands = np.repeat(inputs[:1], 6, 0)
        cands[:, :3, 3] += np.linspace(0, 0.3, 6)[:, None]
        return cands, np.arange(6.0), cands[-1:]

    cfg = load_config({**TINY, "hard_samples": 1, "hard_views": 3, "hard_top": 2, "hard_random": 2})
    teacher = get_teacher()
    with pytest.raises(ConfigError, match="propose"):
        build_cache(cfg, tmp_path, _source, teacher, split="hard")
    (path,) = build_cache(cfg, tmp_path, _source, teacher, split="hard", propose=propose, propose_tag="abc")
    assert "hard2+2" in path.name and path.name.endswith("_abc.npz")
    name, kind, views, seed = cfg.sample_spec(0, "hard")
    assert kind == "sweep" and views == 3 and int(name.split(":")[1]) >= TRAIN_SEED_START + HARD_SEED_OFFSET
    d = load_sample(path)
    ((n, inputs, s),) = calls
    assert n == 3 and s == seed and len(d["images"]) == 3
    cands = np.repeat(inputs[:1], 6, 0)
    cands[:, :3, 3] += np.linspace(0, 0.3, 6)[:, None]
    want = hard_targets(cands, np.arange(6.0), cands[-1:], 2, 2, np.random.default_rng([seed, 1]))
    assert np.allclose(d["targets"], want) and len(d["targets"]) == 5
    gt = torch.from_numpy(_source(name).render_rgb(want)).permute(0, 3, 1, 2)
    assert np.allclose(d["target_scores"], teacher.score(gt).numpy(), atol=1e-5)
    assert int(d["search_targets"]) == 0  # the same arrays as a usual sample: they mix in one list
