"""Distillation of the aesthetic field: data cache, training loop, data parallelism.

Read top to bottom: :class:`TrainConfig`; :func:`build_cache` renders what never changes
between epochs (input frames, their reconstruction and teacher maps, the teacher's maps and
scores of ground-truth renders at held-out target poses) into ``cache_dir`` as ``.npz`` files
(arrays only, never pickle); :func:`train` is the loop: pick a cached sample, embed its
Gaussians, render the field at its targets, MSE against the teacher's maps (in units of each
channel's RMS) plus ``score_weight`` x MSE of the head's scores, AdamW with cosine decay.

Scenes come from a ``make_source(name) -> SceneSource`` the caller passes (the CLI passes the
simulator's ``SimSource``; the core never imports the simulator). Scene names are
``family:seed`` with seeds from ``TRAIN_SEED_START`` on; evaluation uses seeds below
``EVAL_SEED_END`` (see :mod:`aes_planner.eval.field`), so the two never meet.

**Data parallel**: under ``torchrun`` (``WORLD_SIZE > 1``) each process trains on its own
samples and the gradients are averaged with a gloo all-reduce before every step (what
``DistributedDataParallel`` does), after rank 0's initial weights are broadcast: the replicas
stay identical. Only rank 0 writes checkpoints.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import Tensor

from aes_planner import tensorfile
from aes_planner.config import from_dict, require, to_dict
from aes_planner.errors import AesPlannerError
from aes_planner.field.common import ScorerConfig
from aes_planner.field.model import FieldInputs, FieldModel, FieldModelConfig, embed_inputs, render_maps
from aes_planner.field.protocol import SOURCES, plan_views
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import LocalFrame
from aes_planner.platform import Platform
from aes_planner.reconstruct import SplatSet
from aes_planner.runtime import MAX_THREADS, set_threads
from aes_planner.sources import SceneSource
from aes_planner.teachers import Teacher, get_teacher

__all__ = [
    "EVAL_SEED_END",
    "TRAIN_SEED_START",
    "TrainConfig",
    "TrainingDivergedError",
    "Proposer",
    "build_cache",
    "hard_targets",
    "load_sample",
    "make_hard_sample",
    "train",
]

log = logging.getLogger(__name__)

#: Seeds of the scenes each split uses, disjoint by construction: evaluation (``aes-planner eval
#: field``) from 0, validation (model selection during training, the D / resolution study) from
#: 500, training from 1000 (and ``+ 100000 x config.seed``).
EVAL_SEED_START = 0
VAL_SEED_START = 500
TRAIN_SEED_START = 1000
EVAL_SEED_END = VAL_SEED_START
#: Hard samples' scenes start this far above the training seeds (training scenes the spread-out
#: samples do not use).
HARD_SEED_OFFSET = 50_000
FAMILIES = ("indoor", "outdoor", "tabletop", "gallery")


#: Largest learning rate (AdamW's steps are about lr in size: past 1 the weights only jump).
MAX_LR = 1.0
#: Largest weight of a loss term (the map term has weight 1).
MAX_LOSS_WEIGHT = 1e3


@dataclass
class TrainConfig:
    """Everything a training run depends on (YAML ``--config`` loads into it).

    * ``teacher``, ``teacher_weights``: the teacher to distil (``ven`` needs its weights file).
    * ``families``, ``sources``: scene families and input kinds (``rig`` sweeps, ``free``
      trajectories) the samples alternate over; ``samples`` cached samples in all.
    * ``min_views``, ``max_views``: input views per sample (the paper's 2-6); ``targets``:
      held-out target poses per sample along a trajectory, plus ``search_targets`` spread over the
      space the viewpoint search explores (:mod:`aes_planner.field.protocol`).
    * ``steps``, ``lr``, ``weight_decay``, ``warmup_steps``: AdamW with linear warm-up and cosine
      decay to 5 % of ``lr``.
    * ``score_weight``: weight of the MSE between the head's scores of the predicted and the
      teacher's maps, beside the feature-map MSE (the head's global terms must come out right).
    * ``rank_weight``: weight of the same MSE after removing each sample's mean score: what a
      search needs is the order of views within one scene, not the scene's level.
    * ``listwise_weight``, ``listwise_temperature``: weight of a listwise term (cross-entropy
      between the softmax of the teacher's and of the field's scores over each sample's targets,
      at a temperature in units of that sample's score spread): it weights the top of each scene,
      which is what a search picks from, over the order of its poor views.
    * ``expectile``: asymmetry of the score and rank errors (0.5: plain squared errors; below
      0.5 over-estimates cost more, so the field learns a cautious score where it is unsure).
    * ``init_from``: a model checkpoint (``model.npz``) to start from, or ``default`` for the
      shipped one (fine-tuning); None starts from scratch.
    * ``hard_samples``: extra samples whose targets are a viewpoint search's own candidates (hard
      examples: the views a search over the field ranks highest are those it over-rates most),
      mixed with the ``samples``; each takes ``hard_views`` input views of the rig's survey sweep
      (RGB only, as ``eval search``), and its targets are the ``hard_top`` best stage-1 candidates
      by the search's objective, the search's suggestions, and ``hard_random`` other candidates
      drawn at random (the contrast the within-scene rank needs). The search is the caller's
      ``propose`` (:data:`Proposer`; the CLI runs ``hard_preset`` over the ``hard_field``
      checkpoint, by default the ``init_from`` one: a second round takes the picks of the field
      the first round made).
    * ``checkpoint_every``: steps between checkpoints; ``seed``: everything random.
    * ``scorer``: render width and Gaussian budget (what the field is used with).
    * ``model``: the architecture.
    * ``gt_supersample``: anti-aliasing of the ground-truth renders the teacher scores.
    * ``threads``: CPU threads for torch and the rasterizer per process (1 is fastest on a
      shared machine: measured 0.09 s of CPU per step with 1 thread against 1.0 s with 2
      while other jobs ran; scale out with ``torchrun`` processes instead).
    """

    teacher: str = "composition"
    teacher_weights: str | None = None
    families: list[str] = field(default_factory=lambda: list(FAMILIES))
    sources: list[str] = field(default_factory=lambda: ["rig", "free"])
    samples: int = 320
    val_samples: int = 24
    min_views: int = 2
    max_views: int = 6
    targets: int = 12
    search_targets: int = 12
    steps: int = 4000
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    score_weight: float = 4.0
    rank_weight: float = 0.0
    listwise_weight: float = 0.0
    listwise_temperature: float = 0.5
    expectile: float = 0.5
    init_from: str | None = None
    hard_samples: int = 0
    hard_views: int = 4
    hard_top: int = 24
    hard_random: int = 24
    hard_preset: str = "balanced"
    hard_field: str | None = None
    checkpoint_every: int = 250
    seed: int = 0
    gt_supersample: int = 2
    threads: int = 1
    scorer: ScorerConfig = field(default_factory=ScorerConfig)
    model: FieldModelConfig = field(default_factory=FieldModelConfig)

    def __post_init__(self):
        require(len(self.families) >= 1, "families", "name at least one scene family")
        require(all(s in SOURCES for s in self.sources) and self.sources, "sources", f"each one of {list(SOURCES)}")
        require(self.samples >= 1, "samples", f"must be >= 1, got {self.samples}")
        require(
            1 <= self.min_views <= self.max_views <= 16,
            "min_views",
            f"need 1 <= min_views <= max_views <= 16, got {self.min_views}, {self.max_views}",
        )
        require(self.targets >= 1 and self.steps >= 1, "targets", "targets and steps must be >= 1")
        require(
            math.isfinite(self.lr) and 0 < self.lr <= MAX_LR, "lr", f"must be in (0, {MAX_LR:g}] (AdamW), got {self.lr}"
        )
        for name in ("score_weight", "rank_weight", "listwise_weight"):
            w = getattr(self, name)
            require(0 <= w <= MAX_LOSS_WEIGHT, name, f"must be in [0, {MAX_LOSS_WEIGHT:g}] (a loss weight), got {w}")
        require(
            math.isfinite(self.listwise_temperature) and self.listwise_temperature > 0,
            "listwise_temperature",
            f"must be > 0 (in units of a sample's score spread), got {self.listwise_temperature}",
        )
        require(
            math.isfinite(self.expectile) and 0 < self.expectile < 1,
            "expectile",
            f"must be in (0, 1) (0.5 = the plain squared error), got {self.expectile}",
        )
        require(
            0 <= self.hard_samples <= 1_000_000, "hard_samples", f"must be in [0, 1000000], got {self.hard_samples}"
        )
        require(1 <= self.hard_views <= 16, "hard_views", f"must be in [1, 16], got {self.hard_views}")
        require(
            0 <= self.hard_top <= 1000 and 0 <= self.hard_random <= 1000 and self.hard_top + self.hard_random >= 1,
            "hard_top",
            f"hard_top and hard_random must be in [0, 1000], together >= 1, got {self.hard_top}, {self.hard_random}",
        )
        require(self.search_targets >= 0, "search_targets", f"must be >= 0, got {self.search_targets}")
        require(self.checkpoint_every >= 1, "checkpoint_every", "must be >= 1")
        require(1 <= self.gt_supersample <= 4, "gt_supersample", f"must be in [1, 4], got {self.gt_supersample}")
        require(self.samples <= 1_000_000, "samples", f"must be <= 1000000, got {self.samples}")
        require(0 <= self.val_samples <= 100_000, "val_samples", f"must be in [0, 100000], got {self.val_samples}")
        require(self.targets <= 10_000, "targets", f"must be <= 10000, got {self.targets}")
        require(self.search_targets <= 10_000, "search_targets", f"must be <= 10000, got {self.search_targets}")
        require(self.steps <= 10**9, "steps", f"must be <= 1e9, got {self.steps}")
        require(self.warmup_steps >= 0, "warmup_steps", f"must be >= 0, got {self.warmup_steps}")
        require(
            0 <= self.weight_decay <= 1 / self.lr,
            "weight_decay",
            f"must be in [0, 1/lr = {1 / self.lr:g}] (AdamW shrinks the weights by lr*weight_decay per step, which "
            f"past 1 flips their sign), got {self.weight_decay}",
        )
        require(0 <= self.seed < 2**31, "seed", f"must be in [0, 2^31), got {self.seed}")
        require(1 <= self.threads <= MAX_THREADS, "threads", f"must be in [1, {MAX_THREADS}], got {self.threads}")

    def make_teacher(self) -> Teacher:
        """The teacher this config distils (with its weights file, if any)."""
        return get_teacher(self.teacher, **({"weights": self.teacher_weights} if self.teacher_weights else {}))

    def sample_spec(self, index: int, split: str = "train") -> tuple[str, str, int, int]:
        """(scene name, source, views, rng seed) of cached sample ``index`` of ``split``
        (``train``, ``val`` or ``hard``): families round-robin, a new scene seed per round, sources
        alternating. Hard samples are training scenes of their own (seeds from
        ``TRAIN_SEED_START + HARD_SEED_OFFSET``), the survey sweep's ``hard_views`` views."""
        fam = self.families[index % len(self.families)]
        start = {
            "train": TRAIN_SEED_START + self.seed * 100_000,
            "val": VAL_SEED_START,
            "hard": TRAIN_SEED_START + self.seed * 100_000 + HARD_SEED_OFFSET,
        }[split]
        seed = start + index // len(self.families)
        if split == "hard":
            rng = np.random.default_rng([self.seed, index, 1])
            return f"{fam}:{seed}", "sweep", self.hard_views, int(rng.integers(2**31))
        source = self.sources[(index // len(self.families)) % len(self.sources)]
        rng = np.random.default_rng([self.seed, index])
        views = int(rng.integers(self.min_views, self.max_views + 1))
        return f"{fam}:{seed}", source, views, int(rng.integers(2**31))


# ---------------------------------------------------------------------------------- cache
_SPLAT_FIELDS = [f for f in SplatSet.__dataclass_fields__]


def make_sample(
    source: SceneSource, kind: str, n_views: int, seed: int, teacher: Teacher, config: TrainConfig
) -> dict[str, np.ndarray]:
    """One training sample as arrays: inputs, reconstruction, teacher maps at ``config.targets``
    trajectory targets followed by ``config.search_targets`` search targets."""
    rng = np.random.default_rng(seed)
    plan = plan_views(source.platform, kind, n_views, config.targets, rng, config.search_targets)
    frames = [source.capture(p, depth=plan.depth) for p in plan.inputs]
    inputs = FieldInputs.from_frames(frames, teacher, config.scorer.reconstruct_config())
    targets = plan.targets if plan.search_targets is None else np.concatenate([plan.targets, plan.search_targets])
    maps, scores = _teacher_targets(source, targets, teacher)
    return {
        **inputs_to_arrays(inputs),
        "targets": targets,
        "search_targets": np.array(0 if plan.search_targets is None else len(plan.search_targets)),
        "target_maps": maps,
        "target_scores": scores,
    }


def _teacher_targets(source: SceneSource, targets: np.ndarray, teacher: Teacher) -> tuple[np.ndarray, np.ndarray]:
    """The teacher's maps ``[T, C, fh, fw]`` and scores ``[T]`` of the ground truth at ``targets [T, 4, 4]``."""
    maps_list, scores_list = [], []
    for i in range(0, len(targets), TARGET_CHUNK):  # renders in chunks: 10,000 at once would be gigabytes
        gt = torch.from_numpy(source.render_rgb(targets[i : i + TARGET_CHUNK])).permute(0, 3, 1, 2)  # [t, 3, H, W]
        with torch.no_grad():
            maps_list.append(teacher.features(gt))
            scores_list.append(teacher.head(maps_list[-1]))
        del gt
    return torch.cat(maps_list).numpy(), torch.cat(scores_list).numpy()


#: A viewpoint search over the field, as training's hard examples take it: ``propose(frames,
#: inputs_cam2world [V, 4, 4], platform, seed) -> (candidates [C, 4, 4], objective [C],
#: suggestions [S, 4, 4])``: the search's stage-1 candidates with the objective it ranks them by,
#: and the views it suggests (world frame, float64). The field does not import the search (it sits
#: a floor above): the caller passes it (``aes-planner train`` runs a preset's search).
Proposer = Callable[[list, np.ndarray, Platform, int], tuple[np.ndarray, np.ndarray, np.ndarray]]


def hard_targets(
    candidates: np.ndarray, objective: np.ndarray, suggestions: np.ndarray, top: int, n_random: int, rng
) -> np.ndarray:
    """The targets of a hard sample ``[K, 4, 4]``: the search's ``suggestions``, the ``top``
    candidates by ``objective`` (best first; those the argmax over a noisy field picks among, so
    those it over-rates), then ``n_random`` of the other candidates drawn at random (the
    contrast: a within-scene rank needs views the field should rate lower)."""
    candidates, objective = np.asarray(candidates, np.float64), np.asarray(objective, np.float64)
    require(
        candidates.ndim == 3 and candidates.shape[1:] == (4, 4) and objective.shape == (len(candidates),),
        "candidates",
        f"need [C, 4, 4] poses and [C] objective values, got {candidates.shape} and {objective.shape}",
    )
    order = np.argsort(-objective, kind="stable")  # [C]
    rest = order[top:]
    picked = rng.choice(rest, size=min(n_random, len(rest)), replace=False) if len(rest) else rest
    suggestions = np.asarray(suggestions, np.float64).reshape(-1, 4, 4)
    return np.concatenate([suggestions, candidates[order[:top]], candidates[np.sort(picked)]])


def make_hard_sample(
    source: SceneSource, n_views: int, seed: int, teacher: Teacher, config: TrainConfig, propose: Proposer
) -> dict[str, np.ndarray]:
    """One hard sample: the rig's survey sweep of ``n_views`` RGB frames (as ``eval search``
    takes them), the search ``propose`` runs on them, and the teacher's maps at
    :func:`hard_targets` of its result."""
    plan = plan_views(source.platform, "sweep", n_views, 1, np.random.default_rng(seed))
    frames = [source.capture(p, depth=False) for p in plan.inputs]
    inputs = FieldInputs.from_frames(frames, teacher, config.scorer.reconstruct_config())
    candidates, objective, suggestions = propose(frames, plan.inputs, source.platform, seed)
    rng = np.random.default_rng([seed, 1])
    targets = hard_targets(candidates, objective, suggestions, config.hard_top, config.hard_random, rng)
    maps, scores = _teacher_targets(source, targets, teacher)
    return {
        **inputs_to_arrays(inputs),
        "targets": targets,
        "search_targets": np.array(0),
        "target_maps": maps,
        "target_scores": scores,
    }


def inputs_to_arrays(inputs: FieldInputs) -> dict[str, np.ndarray]:
    k = inputs.intrinsics
    return {
        **{f"splat_{n}": getattr(inputs.splats, n) for n in _SPLAT_FIELDS},
        "origin": np.asarray(inputs.local_frame.origin_m),
        "images": (inputs.images.numpy() * 255).round().astype(np.uint8),
        "fmaps": inputs.fmaps.numpy(),
        "cam2world_local": inputs.cam2world_local,
        "intrinsics": np.array([k.fx, k.fy, k.cx, k.cy, k.width, k.height], np.float64),
        "stride": np.array(inputs.stride),
    }


def arrays_to_inputs(a: dict[str, np.ndarray]) -> FieldInputs:
    fx, fy, cx, cy, w, h = a["intrinsics"].tolist()
    return FieldInputs(
        SplatSet(**{n: a[f"splat_{n}"] for n in _SPLAT_FIELDS}),
        LocalFrame(tuple(float(v) for v in a["origin"])),
        torch.from_numpy(a["images"].astype(np.float32) / 255.0),
        torch.from_numpy(a["fmaps"]),
        a["cam2world_local"],
        Intrinsics(fx, fy, cx, cy, int(w), int(h)),
        int(a["stride"]),
    )


#: Arrays of a cached sample: name -> (dtype kind, number of dimensions).
_SAMPLE_ARRAYS = {
    **{f"splat_{n}": (None, None) for n in _SPLAT_FIELDS},
    "origin": ("f", 1),
    "images": ("u", 4),
    "fmaps": ("f", 4),
    "cam2world_local": ("f", 3),
    "intrinsics": ("f", 1),
    "stride": ("i", 0),
    "targets": ("f", 3),
    "target_maps": ("f", 4),
    "target_scores": ("f", 1),
}


#: Largest cache entry (a training sample's arrays in all), written or read.
MAX_SAMPLE_BYTES = 512 << 20
#: Targets rendered and scored at a time while a sample is made.
TARGET_CHUNK = 64


#: Most targets one training step renders (with gradients): a sample with more gives a random
#: subset of them each step, so a step's memory does not grow with ``targets``.
TARGETS_PER_STEP = 256


def _some_targets(sample: dict, rng: np.random.Generator) -> dict:
    """``sample`` with at most :data:`TARGETS_PER_STEP` of its targets (a random subset, in order)."""
    t = len(sample["targets"])
    if t <= TARGETS_PER_STEP:
        return sample
    idx = np.sort(rng.choice(t, TARGETS_PER_STEP, replace=False))
    return {**sample, **{k: sample[k][idx] for k in ("targets", "target_maps", "target_scores")}}


def check_sample_size(config: TrainConfig, teacher: Teacher) -> None:
    """Refuse a config whose samples would exceed :data:`MAX_SAMPLE_BYTES` (the teacher's maps of
    every target dominate: VEN's are 400 kB each), naming ``targets``, before anything is rendered."""
    c, (fh, fw) = teacher.feature_channels, teacher.feature_size
    per_target = c * fh * fw * 4 + 16 * 8 + 4  # its map, its pose and its score
    need = (config.targets + config.search_targets) * per_target
    require(
        need <= MAX_SAMPLE_BYTES,
        "targets",
        f"{config.targets} + {config.search_targets} search targets with {teacher.name}'s {c}x{fh}x{fw} maps make "
        f"{need / 2**20:.0f} MiB per cached sample, over {MAX_SAMPLE_BYTES >> 20} MiB; use at most "
        f"{MAX_SAMPLE_BYTES // per_target} targets in all",
    )


class TrainingDivergedError(AesPlannerError):
    """Training diverged (a non-finite loss or weight): stopped before anything non-finite is saved."""


def _diverged(what: str, step: int, config: TrainConfig, out_dir: Path) -> str:
    last = out_dir / "last.npz"
    kept = f"the last finite checkpoint is kept ({last}, --resume)" if last.exists() else "no checkpoint was written"
    return (
        f"training diverged at step {step + 1}: {what}; {kept}. Lower lr (now {config.lr:g}) or the loss weights "
        f"(score_weight {config.score_weight:g}, rank_weight {config.rank_weight:g}, "
        f"listwise_weight {config.listwise_weight:g}), or weight_decay ({config.weight_decay:g})"
    )


class CacheError(AesPlannerError):
    """A cached sample file that cannot be used; the message names it (delete it to re-render)."""


def load_sample(path: Path) -> dict[str, np.ndarray]:
    """A cached sample's arrays, checked (no pickle, every array present with its kind and rank,
    finite numbers): a damaged file is a :class:`CacheError` naming it, not a crash mid-training."""
    path = Path(path)
    redo = "delete it and the cache renders it again"
    try:  # every header checked before its data is read: an entry declaring a huge array is refused
        a = tensorfile.read_npz(path, max_bytes=MAX_SAMPLE_BYTES)
    except tensorfile.TensorFileError as exc:
        raise CacheError(f"{str(exc)[:300]}; {redo}") from None
    for name, (kind, ndim) in _SAMPLE_ARRAYS.items():
        v = a.get(name)
        if v is None:
            raise CacheError(f"{path}: the array {name!r} is missing; {redo}")
        if (kind is not None and v.dtype.kind != kind) or (ndim is not None and v.ndim != ndim):
            raise CacheError(f"{path}: {name} is {v.dtype}{list(v.shape)}, not a {kind}-array of rank {ndim}; {redo}")
        if v.dtype.kind == "f" and not np.isfinite(v).all():
            raise CacheError(f"{path}: {name} holds NaN or Inf; {redo}")
    v, t = a["images"].shape[0], a["targets"].shape[0]
    ok = (
        a["fmaps"].shape[0] == v
        and a["cam2world_local"].shape[1:] == (4, 4)
        and a["cam2world_local"].shape[0] == v
        and a["targets"].shape[1:] == (4, 4)
        and a["target_maps"].shape[0] == t
        and a["target_scores"].shape == (t,)
        and a["target_maps"].shape[1:] == a["fmaps"].shape[1:]
        and a["intrinsics"].shape == (6,)
        and a["origin"].shape == (3,)
    )
    if not ok:
        raise CacheError(f"{path}: the arrays' shapes do not agree with each other; {redo}")
    return a


def build_cache(
    config: TrainConfig,
    cache_dir: Path,
    make_source: Callable[[str], SceneSource],
    teacher: Teacher,
    progress: Callable[[Iterable], Iterable] = lambda it: it,
    split: str = "train",
    workers: int = 1,
    propose: Proposer | None = None,
    propose_tag: str = "",
) -> list[Path]:
    """Render every sample of ``split`` (``train``: ``samples``, ``val``: ``val_samples``,
    ``hard``: ``hard_samples``, which needs the search ``propose`` and a ``propose_tag`` naming
    the field it searches over) that is not yet in ``cache_dir``; returns the sample files in order.
    The file name holds everything the sample depends on, so a changed config never reuses a
    stale sample. ``workers > 1`` renders in that many processes (``make_source`` and ``propose``
    must then be picklable, e.g. a class or a ``functools.partial``; each process loads its own teacher)."""
    require(split in ("train", "val", "hard"), "split", f"must be train, val or hard, got {split!r}")
    require(
        split != "hard" or propose is not None or not config.hard_samples,
        "propose",
        "hard samples need a search to propose their targets",
    )
    check_sample_size(config, teacher)
    cache_dir.mkdir(parents=True, exist_ok=True)
    sc = config.scorer
    tag = f"{teacher.name}_w{sc.render_width_px}_g{sc.max_gaussians}_t{config.targets}_s{config.gt_supersample}"
    if config.search_targets:
        tag += f"_q{config.search_targets}"
    if split == "hard":  # the targets depend on the search and the field it ran over
        tag = f"{teacher.name}_w{sc.render_width_px}_g{sc.max_gaussians}_s{config.gt_supersample}"
        tag += f"_hard{config.hard_top}+{config.hard_random}_{config.hard_preset}_{propose_tag}"
    count = {"train": config.samples, "val": config.val_samples, "hard": config.hard_samples}[split]
    jobs = []
    for i in range(count):
        name, kind, views, seed = config.sample_spec(i, split)
        jobs.append(
            (name, kind, views, seed, cache_dir / f"{name.replace(':', '-')}_{kind}_v{views}_r{seed}_{tag}.npz")
        )
    root = cache_dir.resolve()
    for job in jobs:
        p = job[-1]
        if p.is_symlink() and root not in p.resolve().parents:
            raise CacheError(f"{p}: a symlink that leads outside the cache {root}; remove it")
        if p.exists() and not p.is_file():
            raise CacheError(f"{p}: not a file; remove it and the cache renders the sample again")
    missing = [job for job in jobs if not job[-1].exists()]
    hard = propose if split == "hard" else None
    if workers > 1 and len(missing) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        ctx = multiprocessing.get_context("spawn")  # no fork of a process holding torch/numba threads
        with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            futures = [pool.submit(_cache_sample, make_source, None, config, *job, hard) for job in missing]
            for fut in progress(futures):
                fut.result()
    else:
        for job in progress(missing):
            _cache_sample(make_source, teacher, config, *job, hard)
    return [job[-1] for job in jobs]


def _cache_sample(
    make_source, teacher, config: TrainConfig, name: str, kind: str, views: int, seed: int, path: Path, propose=None
):
    """Render one sample into ``path`` (atomically); a worker process loads its own ``teacher``.
    With ``propose`` it is a hard sample (:func:`make_hard_sample`)."""
    if teacher is None:
        set_threads(1)
        teacher = config.make_teacher()
    if propose is None:
        arrays = make_sample(make_source(name), kind, views, seed, teacher, config)
    else:
        arrays = make_hard_sample(make_source(name), views, seed, teacher, config, propose)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(path)


# ---------------------------------------------------------------------------------- loop
def _world() -> tuple[int, int]:
    if int(os.environ.get("WORLD_SIZE", "1")) > 1 and not dist.is_initialized():
        dist.init_process_group("gloo")
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _lr(config: TrainConfig, step: int) -> float:
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    t = (step - config.warmup_steps) / max(1, config.steps - config.warmup_steps)
    return config.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


def sample_loss(
    model: FieldModel,
    teacher: Teacher,
    sample: dict,
    inputs: FieldInputs,
    score_weight: float,
    width_px: int,
    rank_weight: float = 0.0,
    listwise_weight: float = 0.0,
    listwise_temperature: float = 0.5,
    expectile: float = 0.5,
) -> tuple[Tensor, dict[str, float]]:
    """The distillation loss of one cached sample at all its targets."""
    from aes_planner.field.common import render_intrinsics

    g = embed_inputs(model, inputs)
    k = render_intrinsics(inputs.intrinsics, width_px)
    maps, _ = render_maps(model, g, inputs.local_frame, torch.from_numpy(sample["targets"]), k)
    target = torch.from_numpy(sample["target_maps"])
    scale = model.map_scale[None, :, None, None]
    map_loss = ((maps - target) / scale).pow(2).mean()
    score = teacher.head(maps)  # [T]
    err = score - torch.from_numpy(sample["target_scores"])  # [T]
    score_loss = expectile_loss(err, expectile)
    rank_loss = expectile_loss(err - err.mean(), expectile)  # the order within the scene, without its level
    loss = map_loss + score_weight * score_loss + rank_weight * rank_loss
    if listwise_weight > 0:
        loss = loss + listwise_weight * listwise_loss(
            score, torch.from_numpy(sample["target_scores"]), listwise_temperature
        )
    return loss, {"map": float(map_loss.detach()), "score": float(score_loss.detach())}


def expectile_loss(err: Tensor, expectile: float) -> Tensor:  # [T] -> []
    """Mean squared error with over-estimates (``err > 0``) weighted ``2 (1 - expectile)`` and
    under-estimates ``2 expectile``: 0.5 is the plain MSE; below 0.5 the minimiser is a lower
    expectile, so the prediction drops where the error is wide (what an argmax over many
    candidates picks)."""
    weight = torch.where(err > 0, 2.0 * (1.0 - expectile), 2.0 * expectile)
    return (weight * err.pow(2)).mean()


def listwise_loss(pred: Tensor, true: Tensor, temperature: float) -> Tensor:
    """Cross-entropy between softmax(true / tau) and softmax(pred / tau) over one scene's targets
    ([T] each), tau = temperature x the spread (std) of ``true``; minus its entropy, so that 0 is a
    perfect order. Scenes whose targets all score alike (spread < 1e-6) contribute 0."""
    spread = float(true.std()) if true.numel() > 1 else 0.0
    if spread < 1e-6:
        return pred.sum() * 0.0
    tau = temperature * spread
    p_true = torch.softmax(true.to(pred.dtype) / tau, 0)
    return (p_true * (torch.log_softmax(true.to(pred.dtype) / tau, 0) - torch.log_softmax(pred / tau, 0))).sum()


def train(
    config: TrainConfig,
    samples: list[Path],
    out_dir: Path,
    resume: bool = False,
    val_samples: list[Path] | None = None,
    progress: Callable[[Iterable], Iterable] = lambda it: it,
    on_step: Callable[[int, float], None] | None = None,
) -> FieldModel:
    """Train on cached ``samples``; writes ``out_dir/last.npz`` (resumable, with the optimiser)
    and ``out_dir/model.npz`` (the model alone) every ``checkpoint_every`` steps and at the end.
    Returns the trained model."""
    if resume and not (out_dir / "last.npz").exists() and (out_dir / "last.pt").exists():
        raise CacheError(
            f"{out_dir / 'last.pt'} was written by an older aes-planner in torch's pickle-based format, which is never "
            "loaded; retrain with `aes-planner train` into another --out (or delete it to start over)"
        )
    rank, world = _world()
    set_threads(config.threads)
    torch.manual_seed(config.seed)
    teacher = config.make_teacher()
    model = FieldModel(config.model, teacher.feature_channels, teacher.feature_size, teacher.name)
    data = [load_sample(p) for p in samples]
    inputs = [arrays_to_inputs(d) for d in data]
    if config.init_from is not None:
        _init_from(model, config.init_from)
    else:
        maps = np.concatenate([d["target_maps"] for d in data])
        model.map_scale.copy_(torch.from_numpy(np.sqrt((maps**2).mean((0, 2, 3))) + 1e-8).float())
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    out_dir.mkdir(parents=True, exist_ok=True)
    last = out_dir / "last.npz"
    start = 0
    if resume and last.exists():
        start = _resume(model, opt, last, config.steps)
        log.info("resumed from %s at step %d", last, start)
    if world > 1:
        for p in [*model.parameters(), *model.buffers()]:
            dist.broadcast(p.data, 0)
    val = [(d, arrays_to_inputs(d)) for d in (load_sample(p) for p in (val_samples or []))]
    model.train()
    ema = None
    t0 = time.perf_counter()
    bar = progress(range(start, config.steps))
    for step in bar:
        rng = np.random.default_rng([config.seed, step, rank])
        i = int(rng.integers(len(data)))
        for group in opt.param_groups:
            group["lr"] = _lr(config, step)
        loss, parts = sample_loss(
            model,
            teacher,
            _some_targets(data[i], rng),
            inputs[i],
            config.score_weight,
            config.scorer.render_width_px,
            config.rank_weight,
            config.listwise_weight,
            config.listwise_temperature,
            config.expectile,
        )
        opt.zero_grad(set_to_none=False)
        loss.backward()
        if world > 1:
            for p in model.parameters():
                dist.all_reduce(p.grad, op=dist.ReduceOp.SUM)
                p.grad /= world
        value = float(loss.detach())
        if not math.isfinite(value):
            raise TrainingDivergedError(_diverged(f"the loss is {value}", step, config, out_dir))
        opt.step()
        bad = next((n for n, p in model.named_parameters() if not torch.isfinite(p).all()), None)
        if bad is not None:
            raise TrainingDivergedError(_diverged(f"the weight {bad} holds NaN or Inf", step, config, out_dir))
        ema = value if ema is None else 0.95 * ema + 0.05 * value
        if hasattr(bar, "set_postfix"):
            bar.set_postfix(loss=f"{ema:.4f}", map=f"{parts['map']:.4f}", score=f"{parts['score']:.5f}")
        if on_step is not None:
            on_step(step, value)
        done = step + 1
        if rank == 0 and (done % config.checkpoint_every == 0 or done == config.steps):
            metrics = validate(model, teacher, val, config.scorer.render_width_px) if val else {}
            model.train()
            _save(model, opt, config, done, out_dir, time.perf_counter() - t0, metrics)
    if world > 1:
        dist.barrier()
    return model.eval()


def _init_from(model: FieldModel, source: str) -> None:
    """Start from the weights (and channel scales) of a model checkpoint, or of the shipped one."""
    from aes_planner.field.model import ModelError, load_model

    try:
        loaded = load_model(None if source == "default" else source)
        model.load_state_dict(loaded.state_dict())
    except (ModelError, RuntimeError) as exc:
        raise CacheError(f"init_from {source}: cannot start from it ({str(exc)[:160]}); train from scratch") from None
    log.info("starting from %s", source)


def _resume(model: FieldModel, opt, last: Path, steps: int) -> int:
    """Load ``last.npz`` into ``model`` and ``opt``; returns its step. A checkpoint that is not ours,
    damaged, of another architecture or already past ``steps`` is a :class:`CacheError`."""
    from aes_planner.field.model import ModelError, read_checkpoint

    ckpt = read_checkpoint(last)
    redo = "delete it to start over, or train into another --out"
    step = ckpt.get("step")
    if not isinstance(step, int) or isinstance(step, bool) or not 0 <= step <= steps:
        raise CacheError(f"{last}: step {step!r} is not in [0, steps={steps}]; raise --steps or {redo}")
    if step == steps:
        raise CacheError(f"{last}: already trained to step {step}; raise --steps to continue, or {redo}")
    try:
        loaded = FieldModel.from_checkpoint(ckpt)
    except ModelError as exc:
        raise CacheError(f"{last}: {exc}; {redo}") from None
    try:
        model.load_state_dict(loaded.state_dict())
    except RuntimeError:
        raise CacheError(f"{last}: its architecture differs from this config's model; {redo}") from None
    try:
        opt.load_state_dict(ckpt["optimizer"])
    except (KeyError, ValueError, TypeError, RuntimeError, IndexError) as exc:
        raise CacheError(
            f"{last}: its optimizer state does not fit ({type(exc).__name__}: {str(exc)[:120]}); {redo}"
        ) from None
    return step


def validate(model: FieldModel, teacher: Teacher, val: list[tuple[dict, FieldInputs]], width_px: int) -> dict:
    """Agreement with the teacher on validation samples: PLCC and SRCC of the scores over all
    their targets pooled, the mean per-sample PLCC, and the feature-map MSE (channel units)."""
    from aes_planner.metrics import plcc, srcc

    model.eval()
    pred, true, per, per_search, top, mse = [], [], [], [], [], []
    with torch.no_grad():
        for d, inputs in val:
            from aes_planner.field.common import render_intrinsics

            g = embed_inputs(model, inputs)
            k = render_intrinsics(inputs.intrinsics, width_px)
            poses = torch.from_numpy(d["targets"])
            maps = torch.cat(  # in chunks: every target of a sample at once could be gigabytes
                [
                    render_maps(model, g, inputs.local_frame, poses[j : j + TARGET_CHUNK], k)[0]
                    for j in range(0, len(poses), TARGET_CHUNK)
                ]
            )
            p, t = teacher.head(maps).numpy(), d["target_scores"]
            pred.append(p)
            true.append(t)
            per.append(plcc(p, t))
            n_search = int(d.get("search_targets", 0))
            if n_search >= 3:  # the order of views the search would pick among
                per_search.append(plcc(p[-n_search:], t[-n_search:]))
                ts = t[-n_search:]
                if ts.max() > ts.mean():  # the teacher's score at the field's pick, 1 = the best target
                    top.append(float((ts[int(np.argmax(p[-n_search:]))] - ts.mean()) / (ts.max() - ts.mean())))
            scale = model.map_scale[None, :, None, None]
            mse.append(float(((maps - torch.from_numpy(d["target_maps"])) / scale).pow(2).mean()))
    p, t = np.concatenate(pred), np.concatenate(true)
    return {
        "val_plcc": plcc(p, t),
        "val_srcc": srcc(p, t),
        "val_plcc_per_sample": float(np.mean(per)) if per else 0.0,
        "val_map_mse": float(np.mean(mse)),
        **({"val_plcc_search": float(np.mean(per_search))} if per_search else {}),
        **({"val_top1_search": float(np.mean(top))} if top else {}),
    }


def _save(model: FieldModel, opt, config: TrainConfig, step: int, out_dir: Path, seconds: float, metrics: dict) -> None:
    import json

    extra = {"train_config": to_dict(config), "step": step, "train_seconds": seconds, "metrics": metrics}
    if metrics:
        log.info("step %d: %s", step, metrics)
        with open(out_dir / "metrics.jsonl", "a") as f:
            f.write(json.dumps({"step": step, "seconds": round(seconds, 1), **metrics}) + "\n")
    from aes_planner.field.model import write_checkpoint

    write_checkpoint(out_dir / "model.npz", model.checkpoint(extra))  # each written atomically
    write_checkpoint(out_dir / "last.npz", {**model.checkpoint(extra), "optimizer": opt.state_dict()})
    log.info("step %d: checkpoint in %s", step, out_dir)


def load_config(data: dict | None) -> TrainConfig:
    return from_dict(TrainConfig, data or {}, "train")
