"""The aesthetic field: the paper's student, in a form that trains and runs on a 2-core CPU.

Pipeline (section 3.1 of the paper, CPU parts in brackets):

1. **Geometry** (frozen): Gaussians from :func:`aes_planner.reconstruct.reconstruct` (depth,
   stereo or sphere mode, as the frames allow), in the reconstruction's local frame.
2. **Aesthetic encoder** (frozen): the teacher's ``features()`` on each input view, a map
   ``[C, h, w]`` (4 x 16 x 16 for ``composition``).
3. **Embedding head** (trained): per input view, a small CNN fuses the upsampled teacher map
   with the image (opponent colour) at the reconstruction's stride resolution; each Gaussian
   gathers that per-pixel feature through its provenance (``source_frame``, ``source_pixel``),
   adds geometry cues (inverse distance, normal and ray direction in its source camera, its
   size) and an MLP predicts its embedding ``f [D]``. The Gaussian also keeps the teacher map
   of its view at its pixel ``t [C]`` (in units of each channel's RMS).
4. **Rasterisation** of ``[t, f]`` and, in the colour slot, ``d_src`` at the target pose
   (``d_src``: the unit direction from the Gaussian to the camera that observed it), with alpha
   and depth.
5. **View conditioning** (the paper's pose conditioning): per pixel, the cosine between the
   target ray and the rendered ``d_src`` (how far the target looks from where the content was
   seen) and the target's inverse depth join the rendered embedding. ``condition=False`` leaves
   them out (the ablation).
6. **Downsampler** (a light transformer) predicting a *correction* of the splatted map ``t``
   pooled to the teacher's size (zero at initialisation: an untrained field is the ``splat``
   baseline): pooling to twice the teacher's map size, a per-cell MLP, pooling to the map size, a
   3x3 convolution and one global self-attention layer (the teacher's saliency depends on what
   else is in the frame), then a 1x1 projection to ``C`` channels, scaled per channel.
7. **Scoring**: the teacher's own ``head`` (and its terms), through ``explain_scores`` (for the
   composition teacher one compiled kernel, forward and gradient).

:class:`FieldModel` holds the trained parts; :class:`FieldInputs` what one set of frames gives
them; :class:`AestheticField` is the :class:`~aes_planner.field.scorer.Scorer`.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from aes_planner import tensorfile
from aes_planner.config import from_dict, require, short_repr
from aes_planner.errors import AesPlannerError
from aes_planner.field.common import ScorerConfig, local_world2cam, render_intrinsics
from aes_planner.field.scorer import ScoreOutput, Scorer, ScorerError, check_poses
from aes_planner.gaussians import Gaussians, autograd_on, rasterize
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import LocalFrame
from aes_planner.messages import PosedFrame
from aes_planner.reconstruct import ReconstructConfig, SplatSet, reconstruct
from aes_planner.teachers import Teacher, get_teacher

__all__ = [
    "CHECKPOINT_FORMAT",
    "DEFAULT_CHECKPOINT",
    "NOCOND_CHECKPOINT",
    "AestheticField",
    "FieldInputs",
    "FieldModel",
    "FieldModelConfig",
    "ModelError",
    "expected_terms",
    "load_model",
    "shared_model",
    "opponent",
    "read_checkpoint",
    "shared_model",
    "write_checkpoint",
]

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = 1
#: Largest weight a checkpoint may hold: trained weights are O(1); beyond this a file is damaged.
MAX_ABS_WEIGHT = 1e4
#: The shipped checkpoints, package data of ``aes_planner.field``: the field, and the same
#: trained without view conditioning (the ablation of ``aes-planner eval field``).
DEFAULT_CHECKPOINT = "default_field.npz"
NOCOND_CHECKPOINT = "default_field_nocond.npz"
#: Largest total array size a checkpoint file may hold (the shipped one is ~230 KB).
MAX_CHECKPOINT_BYTES = 2**30
_GEOM = 8  # geometry cues per Gaussian
_COND = 2  # view-conditioning channels per pixel (cosine to the source view, inverse depth)
_EPS = 1e-6
#: Attention scores computed at a time without autograd, bytes: a few poses' ``[n, n]`` score
#: matrices that stay in the core's L2 cache from their product through the softmax to the
#: product with the values (docs/benchmarks.md, perf-2: 2.3x faster at a stage-1 batch).
_ATTENTION_CHUNK_BYTES = 1 << 20


class ModelError(AesPlannerError, ValueError):
    """A field checkpoint that cannot be used (missing, wrong format, another teacher)."""


@dataclass
class FieldModelConfig:
    """Architecture of the trained parts.

    * ``embed_dim``: ``D``, channels each Gaussian carries and the rasterizer renders.
    * ``encoder_channels``: width of the per-view CNN.
    * ``hidden``: width of the per-Gaussian and per-pixel MLPs and the downsampler.
    * ``attention_dim``: query/key width of the downsampler's global attention.
    * ``condition``: view conditioning on the input and target poses (off = the ablation).
    """

    embed_dim: int = 8
    encoder_channels: int = 16
    hidden: int = 32
    attention_dim: int = 8
    condition: bool = True

    def __post_init__(self):
        for name in ("embed_dim", "encoder_channels", "hidden", "attention_dim"):
            v = getattr(self, name)
            require(isinstance(v, int) and 1 <= v <= 512, name, f"must be an integer in [1, 512], got {v!r}")


def opponent(images: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1] -> [B, 3, H, W]
    """Luminance, red-green, yellow-blue (the teacher's colour space), centred near 0."""
    m = images.new_tensor([[0.299, 0.587, 0.114], [0.5, -0.5, 0.0], [0.25, 0.25, -0.5]])
    return torch.einsum("oc,bchw->bohw", m, images) - images.new_tensor([0.5, 0.0, 0.0])[None, :, None, None]


def pointwise(layers: nn.Sequential, x: Tensor) -> Tensor:  # [B, Cin, H, W] -> [B, Cout, H, W]
    """``layers(x)`` for a stack of 1x1 ``Conv2d`` and ``ReLU``, computed as matrix products over
    channels-last pixels: the same values (and gradients) as the convolutions, about 3x faster on
    CPU for the downsampler's per-cell MLP (docs/benchmarks.md, figures behind code comments).
    Each product is ``mm`` then the bias added in place: ``addmm`` first copies the broadcast bias
    into its output, a pass over memory as long as the product itself at these widths."""
    b, _, h, w = x.shape
    y = x.permute(0, 2, 3, 1).reshape(b * h * w, -1)  # [BHW, Cin]: a view when x is channels-last
    for layer in layers:
        if isinstance(layer, nn.Conv2d):
            y = torch.mm(y, layer.weight[:, :, 0, 0].t())
            if layer.bias is not None:
                y = y.add_(layer.bias)  # in place: mm's backward does not need its output
        elif isinstance(layer, nn.ReLU):
            y = torch.relu_(y)  # in place: the product before it is not needed by its backward
        else:
            y = layer(y)
    return y.reshape(b, h, w, -1).permute(0, 3, 1, 2)  # channels-last [B, Cout, H, W]


class FieldModel(nn.Module):
    """The trained parts of the field (embedding head, downsampler) and the teacher map scale."""

    def __init__(self, config: FieldModelConfig, feature_channels: int, feature_size: tuple[int, int], teacher: str):
        super().__init__()
        self.config = config
        self.teacher_name = teacher
        self.feature_channels = c = int(feature_channels)
        self.feature_size = (int(feature_size[0]), int(feature_size[1]))
        e, h, d = config.encoder_channels, config.hidden, config.embed_dim
        self.encoder = nn.Sequential(
            nn.Conv2d(3 + c, e, 3, padding=1), nn.ReLU(), nn.Conv2d(e, e, 3, padding=1), nn.ReLU()
        )
        self.embed = nn.Sequential(nn.Linear(e + c + _GEOM, h), nn.ReLU(), nn.Linear(h, d))
        n_in = c + d + 1 + (_COND if config.condition else 0)
        self.pixel = nn.Sequential(nn.Conv2d(n_in, h, 1), nn.ReLU(), nn.Conv2d(h, h, 1), nn.ReLU())
        self.cell = nn.Conv2d(h + c, h, 3, padding=1)
        self.query = nn.Linear(h, config.attention_dim)
        self.key = nn.Linear(h, config.attention_dim)
        self.value = nn.Linear(h, h)
        self.out = nn.Conv2d(2 * h, c, 1)
        # the correction starts at zero: an untrained field is the splatted teacher map
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        # per-channel scale of the teacher's maps (set from training data): the network works in units
        self.register_buffer("map_scale", torch.ones(c))
        self.float()  # float32 whatever torch's default dtype (the field computes in float32)

    # ------------------------------------------------------------------ per input view
    def encode_views(self, images: Tensor, fmaps: Tensor, size: tuple[int, int]) -> Tensor:
        """Per-pixel features ``[V, E + C, h, w]`` of input views at ``size`` (the stride grid):
        ``images [V, 3, H, W]`` in [0, 1], teacher maps ``fmaps [V, C, fh, fw]``."""
        img = F.adaptive_avg_pool2d(images, size) if images.shape[-2:] != size else images
        up = F.interpolate(fmaps / self.map_scale[None, :, None, None], size=size, mode="bilinear", align_corners=False)
        return torch.cat([self.encoder(torch.cat([opponent(img), up], 1)), up], 1)

    def embed_gaussians(self, pixel_features: Tensor, geometry: Tensor) -> Tensor:  # [N, E + C], [N, 8] -> [N, D]
        return self.embed(torch.cat([pixel_features, geometry], 1))

    # ------------------------------------------------------------------ at target views
    def decode(self, rendered: Tensor, alpha: Tensor, cond: Tensor | None) -> Tensor:
        """Teacher-shaped maps ``[B, C, fh, fw]`` from the rendered embedding ``[B, C + D, H, W]``
        (the splatted teacher map in channel units, then the learned channels), alpha
        ``[B, H, W]`` and the conditioning ``[B, 2, H, W]`` (ignored when unconditioned): the
        splatted map pooled to the teacher's size plus a learned correction."""
        return self.decode_pooled(self.pool_input(rendered, alpha, cond))

    def pool_input(self, rendered: Tensor, alpha: Tensor, cond: Tensor | None) -> Tensor:
        """The decoder's input pooled to twice the teacher's map size, ``[B, C + D + 1 (+ 2), 2fh,
        2fw]`` channels-last (the arguments as in :meth:`decode`): what :meth:`decode_pooled` and
        :meth:`splat_maps` take, ~15x smaller than the render."""
        parts = [rendered, alpha[:, None]]
        if self.config.condition:
            parts.append(cond)
        fh, fw = self.feature_size
        x = torch.cat(parts, 1).contiguous(memory_format=torch.channels_last)  # pixels channels-last from here
        return F.adaptive_avg_pool2d(x, (2 * fh, 2 * fw))  # [B, C + D + 1 (+ 2), 2fh, 2fw]

    def cell_alpha(self, pooled: Tensor) -> Tensor:  # [B, C + D + 1 (+ 2), 2fh, 2fw] -> [B, 1, fh, fw]
        """The rendered alpha per cell of the teacher's map: how much of each cell the inputs saw."""
        a = self.feature_channels + self.config.embed_dim
        return F.avg_pool2d(pooled[:, a : a + 1], 2).clamp(0.0, 1.0)

    def splat_maps(self, pooled: Tensor) -> Tensor:  # [B, C + D + 1 (+ 2), 2fh, 2fw] -> [B, C, fh, fw]
        """The splatted teacher map alone, without the learned correction (the ``splat`` baseline,
        an untrained field): the search's cheap screen of stage-1 candidates."""
        return F.avg_pool2d(pooled[:, : self.feature_channels], 2) * self.map_scale[None, :, None, None]

    def decode_pooled(self, x: Tensor) -> Tensor:  # [B, C + D + 1 (+ 2), 2fh, 2fw] -> [B, C, fh, fw]
        """:meth:`decode` from :meth:`pool_input`'s output."""
        fh, fw = self.feature_size
        base = F.avg_pool2d(x[:, : self.feature_channels], 2)  # [B, C, fh, fw] splatted map, channel units
        x = F.avg_pool2d(pointwise(self.pixel, x), 2)  # [B, h, fh, fw]
        x = torch.relu_(self.cell(torch.cat([x, base], 1))) + x
        b, h = x.shape[:2]
        tokens = x.permute(0, 2, 3, 1).reshape(b, fh * fw, h)  # [B, n, h]: a view of channels-last x
        ctx = self._attend(tokens)  # [B, n, h]
        # the 1x1 projection of [x, ctx] as one product over the tokens (no [B, 2h, fh, fw] concatenation)
        out = torch.addmm(
            self.out.bias, torch.cat([tokens, ctx], 2).reshape(b * fh * fw, 2 * h), self.out.weight[:, :, 0, 0].t()
        )
        out = out.reshape(b, fh, fw, -1).permute(0, 3, 1, 2)  # [B, C, fh, fw] channels-last
        return (base + out) * self.map_scale[None, :, None, None]

    def _attend(self, tokens: Tensor) -> Tensor:  # [B, n, h] -> [B, n, h]
        """Global self-attention over each pose's tokens. Without autograd (stage 1's batches) a
        few poses at a time, scaled in place: the ``[B, n, n]`` scores of a whole batch (16 MB
        at 64 poses) went through memory three times; a chunk's stay in cache. The same values
        bit for bit (each pose's products and softmax are computed alone either way)."""
        scale = 1.0 / math.sqrt(self.query.out_features)
        q, k, v = self.query(tokens), self.key(tokens), self.value(tokens)  # [B, n, a], [B, n, a], [B, n, h]
        if torch.is_grad_enabled():
            return torch.bmm(torch.softmax(torch.bmm(q, k.transpose(1, 2)) * scale, -1), v)
        b, n = tokens.shape[:2]
        chunk = max(1, _ATTENTION_CHUNK_BYTES // (4 * n * n))
        ctx = tokens.new_empty(b, n, v.shape[2])
        for s in range(0, b, chunk):
            scores = torch.bmm(q[s : s + chunk], k[s : s + chunk].transpose(1, 2)).mul_(scale)  # [c, n, n]
            torch.bmm(torch.softmax(scores, -1), v[s : s + chunk], out=ctx[s : s + chunk])
        return ctx

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self, extra: dict | None = None) -> dict:
        """A dict of tensors and plain values, for :func:`write_checkpoint` / :func:`read_checkpoint`."""
        from aes_planner import __version__

        return {
            "format": CHECKPOINT_FORMAT,
            "model_config": asdict(self.config),
            "teacher": self.teacher_name,
            "feature_channels": self.feature_channels,
            "feature_size": list(self.feature_size),
            "code_version": __version__,
            "state_dict": self.state_dict(),
            **(extra or {}),
        }

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> FieldModel:
        """The model of a checkpoint dict, every entry checked (a :class:`ModelError` names the
        first bad one): the architecture's numbers, the weights' names and shapes, finite weights."""
        if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
            raise ModelError(
                f"not an aes-planner field checkpoint of format {CHECKPOINT_FORMAT}; retrain with `aes-planner train`"
            )
        missing = [
            k for k in ("model_config", "feature_channels", "feature_size", "teacher", "state_dict") if k not in ckpt
        ]
        if missing:
            raise ModelError(f"field checkpoint lacks {missing}; retrain with `aes-planner train`")
        channels, size, teacher = ckpt["feature_channels"], ckpt["feature_size"], ckpt["teacher"]
        if not (isinstance(channels, int) and not isinstance(channels, bool) and 1 <= channels <= 4096):
            raise ModelError(
                f"field checkpoint: feature_channels must be an integer in [1, 4096], got {short_repr(channels)}"
            )
        if not (
            isinstance(size, (list, tuple))
            and len(size) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 1024 for v in size)
        ):
            raise ModelError(f"field checkpoint: feature_size must be 2 integers in [1, 1024], got {short_repr(size)}")
        if not (isinstance(teacher, str) and teacher.replace("_", "").isalnum() and len(teacher) <= 64):
            raise ModelError(f"field checkpoint: teacher must be a teacher's name, got {short_repr(teacher)}")
        state = ckpt["state_dict"]
        if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
            raise ModelError("field checkpoint: state_dict must map names to tensors; retrain with `aes-planner train`")
        for name, v in state.items():
            if v.is_floating_point() and not bool(torch.isfinite(v).all()):
                raise ModelError(
                    f"field checkpoint: weight {short_repr(name)} holds NaN or Inf; retrain or use another file"
                )
            if v.is_floating_point() and v.numel() and float(v.abs().max()) > MAX_ABS_WEIGHT:
                raise ModelError(
                    f"field checkpoint: weight {short_repr(name)} reaches {float(v.abs().max()):.3g}, beyond "
                    f"{MAX_ABS_WEIGHT:g} (trained weights are small; this file is damaged)"
                )
        model = cls(from_dict(FieldModelConfig, ckpt["model_config"], "model_config"), channels, tuple(size), teacher)
        try:
            model.load_state_dict(state)
        except RuntimeError as exc:
            text = " ".join(str(exc).split())
            raise ModelError(f"field checkpoint does not fit its architecture: {text[:300]}") from None
        return model.eval()


def read_checkpoint(path: str | Path) -> dict:
    """The dict of a checkpoint file written by :func:`write_checkpoint` (an
    :mod:`aes_planner.tensorfile` ``.npz``, never unpickled), every failure (missing, truncated,
    an old torch-format file, not a checkpoint) a :class:`ModelError` naming the file."""
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"field checkpoint {p} does not exist; train one with `aes-planner train --out DIR`")
    try:
        ckpt = tensorfile.load(p, max_bytes=MAX_CHECKPOINT_BYTES)
    except tensorfile.LegacyTorchFileError as exc:
        raise ModelError(f"{exc}; retrain with `aes-planner train`") from None
    except tensorfile.TensorFileError as exc:
        raise ModelError(f"not a readable field checkpoint: {exc}; retrain with `aes-planner train`") from None
    if not isinstance(ckpt, dict):
        raise ModelError(f"{p}: not an aes-planner field checkpoint; retrain with `aes-planner train`")
    return ckpt


def write_checkpoint(path: str | Path, ckpt: dict) -> Path:
    """Write a checkpoint dict (:meth:`FieldModel.checkpoint`, plus e.g. the optimizer's state)
    atomically as an :mod:`aes_planner.tensorfile` ``.npz``. A NaN or Inf in any tensor is refused
    (:class:`ModelError`): a diverged model is never saved."""
    where = _non_finite(ckpt, "checkpoint")
    if where is not None:
        raise ModelError(f"{path}: not written: {where} holds NaN or Inf (training diverged)")
    return tensorfile.save(path, ckpt)


def _non_finite(tree: Any, where: str) -> str | None:
    """The first place in a checkpoint tree holding a non-finite float tensor or array, or None."""
    if isinstance(tree, torch.Tensor):
        return None if not tree.is_floating_point() or bool(torch.isfinite(tree).all()) else where
    if isinstance(tree, np.ndarray):
        return None if tree.dtype.kind != "f" or bool(np.isfinite(tree).all()) else where
    if isinstance(tree, Mapping):
        items = tree.items()
    elif isinstance(tree, (list, tuple)):
        items = enumerate(tree)
    else:
        return None
    for k, v in items:
        found = _non_finite(v, f"{where}[{k!r}]")
        if found is not None:
            return found
    return None


def load_model(path: str | Path | None = None) -> FieldModel:
    """A :class:`FieldModel` from ``path`` (default: the shipped checkpoint; a bare name such as
    ``NOCOND_CHECKPOINT`` picks another packaged one), read by :func:`read_checkpoint` (no pickle)."""
    if path is None or path in (DEFAULT_CHECKPOINT, NOCOND_CHECKPOINT):
        ref = resources.files("aes_planner.field").joinpath(path or DEFAULT_CHECKPOINT)
        if not ref.is_file():
            raise ModelError(
                f"the packaged checkpoint {path or DEFAULT_CHECKPOINT} is missing from aes_planner.field; reinstall the package "
                "or pass model=FILE (train one with `aes-planner train`)"
            )
        with resources.as_file(ref) as p:
            ckpt = read_checkpoint(p)
    else:
        ckpt = read_checkpoint(path)
    try:
        with autograd_on():  # normal weights, also under a caller's inference_mode (the search differentiates)
            return FieldModel.from_checkpoint(ckpt)
    except ModelError as exc:
        raise ModelError(f"{path}: {exc}") from None


_shared_models: dict[str, FieldModel] = {}


def shared_model(name: str | None = None) -> FieldModel:
    """The packaged checkpoint ``name`` (default :data:`DEFAULT_CHECKPOINT`) loaded once per
    process, in eval mode with its weights frozen: what every field built without a model of its
    own scores with, so a planner's rebuilds and a loop's suggestions do not read, check and
    rebuild the same weights each time (docs/benchmarks.md, "perf-2"). Read-only: to train or
    change a model, :func:`load_model` gives a fresh one."""
    key = name or DEFAULT_CHECKPOINT
    model = _shared_models.get(key)
    if model is None:
        model = load_model(key).eval().requires_grad_(False)
        _shared_models[key] = model
    return model


# ---------------------------------------------------------------------------------- inputs
@dataclass
class FieldInputs:
    """What a set of posed frames gives the field: the reconstruction and, per input view, the
    image and teacher map (all local-frame, float32 except poses). Cacheable as arrays."""

    splats: SplatSet
    local_frame: LocalFrame
    images: Tensor  # [V, 3, H, W] float32 in [0, 1]
    fmaps: Tensor  # [V, C, fh, fw] teacher maps of the input views
    cam2world_local: np.ndarray  # [V, 4, 4] float64
    intrinsics: Intrinsics  # of the input views
    stride: int  # pixels per Gaussian block of the reconstruction
    modes: list[str] = field(default_factory=list)

    @classmethod
    def from_frames(cls, frames: list[PosedFrame], teacher: Teacher, config: ReconstructConfig) -> FieldInputs:
        for i, f in enumerate(frames[1:], 1):
            if (f.width, f.height) != (frames[0].width, frames[0].height):
                raise ScorerError(
                    f"frames[{i}] is {f.width}x{f.height} px but frames[0] is {frames[0].width}x{frames[0].height}: "
                    "the field takes its input views at one size; resize the frames to one size (their intrinsics "
                    "scale with them), or score with 'rgb'"
                )
        rec = reconstruct(frames, config)
        images = torch.from_numpy(np.stack([f.image for f in frames])).permute(0, 3, 1, 2).float() / 255.0
        fmaps = _features(teacher, frames, images)
        poses = np.stack([rec.local_frame.pose_to_local(f.cam2world) for f in frames])
        return cls(
            rec.splats,
            rec.local_frame,
            images,
            fmaps,
            poses,
            frames[0].intrinsics,
            config.stride_for(frames[0].width),
            rec.modes,
        )

    def geometry(self) -> tuple[Tensor, Tensor, Tensor]:
        """Per Gaussian: geometry cues ``[N, 8]``, direction to its source camera ``[N, 3]``
        (local frame, unit) and its stride-grid pixel ``[N, 2]`` (row, column) as long."""
        sp = self.splats
        src = np.clip(sp.source_frame, 0, len(self.cam2world_local) - 1)
        cam = self.cam2world_local[src]  # [N, 4, 4]
        rot, centre = cam[:, :3, :3], cam[:, :3, 3]
        to_point = sp.means.astype(np.float64) - centre
        dist = np.maximum(np.linalg.norm(to_point, axis=1), 1e-6)
        ray_cam = np.einsum("nji,nj->ni", rot, to_point / dist[:, None])  # R^T d
        normal_cam = np.einsum("nji,nj->ni", rot, sp.normals.astype(np.float64))
        size = sp.log_scales[:, :2].mean(1) - np.log(dist)  # angular size (log)
        geom = np.concatenate([1.0 / (1.0 + dist[:, None]), normal_cam, ray_cam, (size[:, None] + 5.0) / 2.0], 1)
        h, w = self.images.shape[-2:]
        hs, ws = max(1, h // self.stride), max(1, w // self.stride)
        rows = np.clip(sp.source_pixel[:, 1] // self.stride, 0, hs - 1)
        cols = np.clip(sp.source_pixel[:, 0] // self.stride, 0, ws - 1)
        pix = torch.from_numpy(np.stack([src, rows, cols], 1).astype(np.int64))
        return (
            torch.from_numpy(geom.astype(np.float32)),
            torch.from_numpy((-to_point / dist[:, None]).astype(np.float32)),
            pix,
        )

    def grid(self) -> tuple[int, int]:
        h, w = self.images.shape[-2:]
        return max(1, h // self.stride), max(1, w // self.stride)


#: Teacher maps of recent input images, keyed by teacher and image content: a planner rebuilds its
#: field from the same frames plus a new one, and only the new one needs the teacher.
_FEATURE_CACHE_SIZE = 64
_feature_cache: OrderedDict[tuple[str, tuple, bytes], Tensor] = OrderedDict()
_feature_lock = threading.Lock()


def _image_key(teacher: Teacher, image: np.ndarray) -> tuple[str, tuple, bytes]:
    return teacher.name, image.shape, hashlib.blake2b(np.ascontiguousarray(image).data, digest_size=16).digest()


def _features(teacher: Teacher, frames: list[PosedFrame], images: Tensor) -> Tensor:  # -> [V, C, fh, fw]
    """``teacher.features(images)``, each image's map computed once per process (while it stays
    among the last ``_FEATURE_CACHE_SIZE``; a blake2b of a 128 x 96 image costs ~10 us, the map
    ~3 ms). Maps are computed one image at a time, so a map is the same whichever batch asked."""
    keys = [_image_key(teacher, f.image) for f in frames]
    with _feature_lock:
        maps = [_feature_cache.get(k) for k in keys]
    with torch.no_grad():
        for i, key in enumerate(keys):
            if maps[i] is None:
                maps[i] = teacher.features(images[i : i + 1])[0]
                with _feature_lock:
                    _feature_cache[key] = maps[i]
                    while len(_feature_cache) > _FEATURE_CACHE_SIZE:
                        _feature_cache.popitem(last=False)
    with _feature_lock:
        for key in keys:
            if key in _feature_cache:
                _feature_cache.move_to_end(key)
    return torch.stack(maps)


def clear_feature_cache() -> None:
    """Forget the cached teacher maps (benchmarks timing a build from scratch)."""
    with _feature_lock:
        _feature_cache.clear()


def embed_inputs(model: FieldModel, inputs: FieldInputs) -> Gaussians:
    """The Gaussians of ``inputs`` carrying ``features = [teacher map (C), embedding (D)]`` and,
    in the colour slot, the unit direction to their source camera (3): the field renders no
    colour, so the rasterizer accumulates C + D + 3 values per pixel, not 3 unused colours more
    (differentiable w.r.t. the model's parameters)."""
    sp = inputs.splats
    d = model.config.embed_dim
    if len(sp) == 0:
        return _empty_gaussians(model.feature_channels + d)
    geom, to_src, pix = inputs.geometry()
    feats = model.encode_views(inputs.images, inputs.fmaps, inputs.grid())  # [V, E + C, hs, ws]
    per_g = feats[pix[:, 0], :, pix[:, 1], pix[:, 2]]  # [N, E + C]; the last C: the teacher map, in units
    emb = model.embed_gaussians(per_g, geom)
    g = sp.to_gaussians()
    g.features = torch.cat([per_g[:, -model.feature_channels :], emb], 1)  # [N, C + D]
    g.colors = to_src  # [N, 3], rendered over a black background: the same sum as a feature
    return g


def _empty_gaussians(channels: int) -> Gaussians:
    z = torch.zeros
    return Gaussians(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 3), z(0, channels))


@functools.lru_cache(maxsize=8)
def _unit_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> Tensor:  # [H, W, 3]
    """Unit camera-frame rays through the pixel centres, float32, computed once per camera: every
    render of a search is at the same intrinsics (read-only: the cache hands out one tensor)."""
    with autograd_on():  # a normal tensor also when first asked for under inference_mode (stage 2 saves it)
        k = Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
        rays = torch.from_numpy(k.pixel_directions().astype(np.float32))
        return rays / rays.norm(dim=-1, keepdim=True)


def render_maps(
    model: FieldModel,
    gaussians: Gaussians,
    local: LocalFrame | None,
    cam2world: Tensor,  # [B, 4, 4] float64 world
    intrinsics: Intrinsics,
) -> tuple[Tensor, Tensor]:  # [B, C, fh, fw], [B] coverage
    """Teacher-shaped maps at world poses and their coverage (mean alpha)."""
    pooled, coverage = render_pooled(model, gaussians, local, cam2world, intrinsics)
    return model.decode_pooled(pooled), coverage


def render_pooled(
    model: FieldModel,
    gaussians: Gaussians,
    local: LocalFrame | None,
    cam2world: Tensor,  # [B, 4, 4] float64 world
    intrinsics: Intrinsics,
) -> tuple[Tensor, Tensor]:  # [B, C + D + 1 (+ 2), 2fh, 2fw], [B] coverage
    """The decoder's pooled input at world poses (:meth:`FieldModel.pool_input`) and the coverage
    (mean alpha): :func:`render_maps` without the decoder."""
    k = intrinsics
    b = cam2world.shape[0]
    d = model.feature_channels + model.config.embed_dim
    if len(gaussians) == 0:
        zero = cam2world.sum().float() * 0.0  # keep the graph to the poses
        f32 = dict(dtype=torch.float32)
        emb = torch.zeros(b, d, k.height, k.width, **f32) + zero
        src = torch.zeros(b, 3, k.height, k.width, **f32) + zero
        alpha = torch.zeros(b, k.height, k.width, **f32) + zero
        depth = torch.zeros(b, k.height, k.width, **f32)
    else:
        w2c = local_world2cam(cam2world, local)
        out = rasterize(gaussians, w2c, torch.from_numpy(k.K), k.width, k.height, validate=False)
        emb, src, alpha, depth = out.features, out.rgb, out.alpha, out.depth  # src: see embed_inputs
    cond = None
    if model.config.condition:
        rays = _unit_rays(k.width, k.height, k.fx, k.fy, k.cx, k.cy)  # [H, W, 3] camera frame
        rot = cam2world[:, :3, :3].float()  # [B, 3, 3]: local and world axes agree
        ray_w = torch.einsum("bij,hwj->bihw", rot, rays)  # [B, 3, H, W]
        # sqrt of a channel sum, not Tensor.norm(dim=1): torch's CPU norm over a strided channel axis
        # is ~50x slower here (docs/benchmarks.md, figures behind code comments)
        # (eps inside the root: its gradient at an empty pixel, src = 0, stays finite)
        src_dir = src / ((src * src).sum(1, keepdim=True) + _EPS * _EPS).sqrt()
        cos = -(ray_w * src_dir).sum(1) * alpha  # [B, H, W]: 1 = seen from where the target looks
        inv_depth = alpha / (1.0 + depth.clamp_min(0.0))
        cond = torch.stack([cos, inv_depth], 1)
    return model.pool_input(emb, alpha, cond), alpha.detach().mean((1, 2)).clamp(0.0, 1.0).to(torch.float64)


#: Input views' maps a view's unseen cells are filled from at most (evenly spread over the inputs):
#: the head runs once per fill, and a planner's field holds up to 24 frames.
MAX_UNSEEN_FILLS = 8


def expected_terms(teacher: Teacher, maps: Tensor, alpha: Tensor, fills: Tensor) -> dict[str, Tensor]:
    """The teacher's terms of ``maps [B, C, fh, fw]`` averaged over plausible content of the cells
    the inputs did not see: per input view ``v``, ``alpha * maps + (1 - alpha) * fills[v]``
    (``alpha [B, 1, fh, fw]``, the cells' rendered alpha; ``fills [V, C, fh, fw]``, the input
    views' teacher maps: what the scene holds at that place in a frame where the inputs looked).

    Why: the field's map of an unseen cell is the decoder's smooth guess, which the head reads as
    empty frame edges, a clean horizon and a subject clear of the border; the views a search picks
    are those whose unseen cells flatter them most (the field over-rated the 24 best stage-1
    candidates by +0.058 of score on dev scenes, +0.016 with the true map in the unseen cells).
    The head is not linear, so the score of a mean guess is not the mean score of the contents it
    stands for: scoring each plausible content and averaging is. Fully seen views (alpha 1) score
    as before. The score is differentiable with respect to the maps and the alpha, the other
    terms are detached (:meth:`Teacher.explain_scores`)."""
    v = fills.shape[0]
    if v > MAX_UNSEEN_FILLS:
        fills = fills[torch.linspace(0, v - 1, MAX_UNSEEN_FILLS).round().long()]
        v = MAX_UNSEEN_FILLS
    b = maps.shape[0]
    blended = alpha[:, None] * maps[:, None] + (1.0 - alpha[:, None]) * fills[None].to(maps.dtype)  # [B, V, C, fh, fw]
    terms = teacher.explain_scores(blended.reshape(b * v, *maps.shape[1:]))
    return {k: t.reshape(b, v).mean(1) for k, t in terms.items()}


# ---------------------------------------------------------------------------------- scorer
class AestheticField(Scorer):
    """The distilled aesthetic field as a :class:`Scorer` (pipeline in the module docstring).

    Build with :meth:`build` (a batch of frames) and grow with :meth:`add_frame`; every change
    bumps :attr:`version`. :meth:`score` takes world-frame poses ``[B, 4, 4]`` float64 and is
    differentiable with respect to them.
    """

    name = "field"
    differentiable = True

    def __init__(
        self,
        model: FieldModel,
        teacher: Teacher,
        intrinsics: Intrinsics | None,
        config: ScorerConfig | None = None,
    ):
        if teacher.name != model.teacher_name:
            raise ModelError(
                f"the field model was distilled from teacher {model.teacher_name!r}, not {teacher.name!r}; "
                f"pass teacher=get_teacher({model.teacher_name!r}) or a model trained for {teacher.name!r}"
            )
        self.model = model.eval()
        self.model.requires_grad_(False)
        self.teacher = teacher
        self.config = config or ScorerConfig()
        self.intrinsics = render_intrinsics(
            intrinsics or Intrinsics.from_fov(128, 96, 60.0), self.config.render_width_px
        )
        self.version = 0
        self._frames: list[PosedFrame] = []  # the frames behind the current map (bounded: see add_frame)
        self._inputs: FieldInputs | None = None
        self._gaussians = _empty_gaussians(model.feature_channels + model.config.embed_dim)

    # ------------------------------------------------------------------ construction
    @classmethod
    def load_default(cls, teacher: Teacher | None = None, config: ScorerConfig | None = None) -> AestheticField:
        """An empty field with the shipped model (add frames with :meth:`add_frame`)."""
        model = shared_model()
        with autograd_on():  # the teacher's tensors normal, also under a caller's inference_mode
            return cls(model, teacher or get_teacher(model.teacher_name), None, config)

    @classmethod
    def build(
        cls,
        frames: list[PosedFrame],
        config: ScorerConfig | None = None,
        model: FieldModel | str | Path | None = None,
        teacher: Teacher | None = None,
    ) -> AestheticField:
        """A field of ``frames`` (may be empty) with ``model`` (default: the shipped checkpoint)."""
        if model is None or model in (DEFAULT_CHECKPOINT, NOCOND_CHECKPOINT):
            model = shared_model(model)  # the packaged weights, loaded once per process
        elif not isinstance(model, FieldModel):
            model = load_model(model)
        frames = list(frames)
        for i, f in enumerate(frames):
            if not isinstance(f, PosedFrame):
                raise ScorerError(f"AestheticField.build: frames[{i}] is a {type(f).__name__}, not a PosedFrame")
        from aes_planner.images import downscale_frame

        frames = [downscale_frame(f) for f in frames]  # to what the field can see
        with autograd_on():  # the teacher's tensors normal, also under a caller's inference_mode
            fld = cls(
                model, teacher or get_teacher(model.teacher_name), frames[0].intrinsics if frames else None, config
            )
        if frames:
            fld._rebuild(frames)
        return fld

    @classmethod
    def from_inputs(
        cls, inputs: FieldInputs, model: FieldModel, teacher: Teacher, config: ScorerConfig | None = None
    ) -> AestheticField:
        """A field of precomputed :class:`FieldInputs` (training and evaluation caches)."""
        fld = cls(model, teacher, inputs.intrinsics, config)
        fld._set_inputs(inputs)
        return fld

    def add_frame(self, frame: PosedFrame) -> None:
        """Add one posed frame. The map is rebuilt from the frames that still own Gaussians plus
        the new one, so memory stays bounded by the reconstruction budget, not by the stream."""
        if not isinstance(frame, PosedFrame):
            raise ScorerError(f"AestheticField.add_frame takes a PosedFrame, got {type(frame).__name__}")
        from aes_planner.images import downscale_frame

        frame = downscale_frame(frame)  # to what the field can see (aes_planner.images.MAX_WORKING_SIDE_PX)
        if self._inputs is None:
            self.intrinsics = render_intrinsics(frame.intrinsics, self.config.render_width_px)
        self._rebuild([*self._frames, frame])

    def _rebuild(self, frames: list[PosedFrame]) -> None:
        # The field reads colour from the images, not from the splats: skip the colour passes
        # of reconstruction (sharpening, refitting; ~20 % of its time).
        cfg = replace(self.config.reconstruct_config(), sharpen_iterations=0, refit_iterations=0)
        with autograd_on():  # normal tensors under a caller's inference_mode: the search differentiates through them
            inputs = FieldInputs.from_frames(frames, self.teacher, cfg)
            # keep only the frames that still own Gaussians (renumbering provenance)
            used = np.unique(inputs.splats.source_frame)
            used = used[used >= 0]
            if len(used) < len(frames):
                remap = np.full(len(frames), -1, np.int64)
                remap[used] = np.arange(len(used))
                inputs.splats.source_frame = remap[inputs.splats.source_frame].astype(np.int32)
                inputs.images, inputs.fmaps = inputs.images[used], inputs.fmaps[used]
                inputs.cam2world_local = inputs.cam2world_local[used]
                frames = [frames[i] for i in used]
            self._frames = frames
            self._set_inputs(inputs)

    def _set_inputs(self, inputs: FieldInputs) -> None:
        self._inputs = inputs
        with torch.no_grad():
            self._gaussians = embed_inputs(self.model, inputs)
        self.version += 1

    # ------------------------------------------------------------------ state
    @property
    def gaussians(self) -> Gaussians:
        return self._gaussians

    @property
    def inputs(self) -> FieldInputs | None:
        """The reconstruction and input views behind the current map (None before any frame)."""
        return self._inputs

    @property
    def local_frame(self) -> LocalFrame | None:
        return None if self._inputs is None else self._inputs.local_frame

    def __len__(self) -> int:
        return len(self._gaussians)

    # ------------------------------------------------------------------ scoring
    def render_maps(self, cam2world: Tensor) -> tuple[Tensor, Tensor]:  # [B, 4, 4] -> [B, C, fh, fw], [B]
        poses = check_poses(cam2world, "AestheticField")
        return render_maps(self.model, self._gaussians, self.local_frame, poses, self.intrinsics)

    def score(self, cam2world: Tensor) -> ScoreOutput:  # [B, 4, 4] float64 world
        poses = check_poses(cam2world, "AestheticField")
        pooled, coverage = render_pooled(self.model, self._gaussians, self.local_frame, poses, self.intrinsics)
        return self._explain(self.model.decode_pooled(pooled), coverage, pooled)

    def _explain(self, maps: Tensor, coverage: Tensor, pooled: Tensor) -> ScoreOutput:
        """Terms of ``maps [B, C, fh, fw]`` (``pooled``: the decoder's input they came from, for
        the cells' alpha), with the unseen cells as ``config.unseen_cells`` says."""
        fills = None if self._inputs is None else self._inputs.fmaps  # [V, C, fh, fw]
        if self.config.unseen_cells == "decoder" or fills is None or len(fills) == 0 or len(maps) == 0:
            terms = self.teacher.explain_scores(maps)  # the score differentiable, the terms reported
        else:
            terms = expected_terms(self.teacher, maps, self.model.cell_alpha(pooled), fills)
        return ScoreOutput(terms["score"], coverage, {k: v.detach() for k, v in terms.items()})

    def score_where(self, cam2world, batch_size, which):
        """:meth:`Scorer.score_where`: every pose rendered once (its coverage and the splatted
        map's screen), the decoder run only on the poses ``which`` picks, batch by batch. The
        explore pass needs the score of its partly covered views only; the decoder was ~2/3 of
        the pass (docs/benchmarks.md, "perf-2, fifth round")."""
        who = "AestheticField.score_where"
        poses = check_poses(cam2world, who)
        if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
            raise ScorerError(f"{who}: batch_size must be an integer >= 1, got {batch_size!r}")
        if len(self._gaussians) == 0:  # nothing rendered: no decoder to leave out
            return super().score_where(poses, batch_size, which)
        outs: list[ScoreOutput] = []
        exact: list[Tensor] = []
        with torch.no_grad():
            for start in range(0, poses.shape[0], batch_size):
                chunk = poses[start : start + batch_size]
                pooled, coverage = render_pooled(self.model, self._gaussians, self.local_frame, chunk, self.intrinsics)
                pick = torch.as_tensor(which(coverage), dtype=torch.bool)  # [b]
                if tuple(pick.shape) != (len(chunk),):
                    raise ScorerError(
                        f"{who}: which must return [b] = [{len(chunk)}] booleans, got {tuple(pick.shape)}"
                    )
                parts = [(rows, self._explain(maps(pooled[rows]), coverage[rows], pooled[rows]))  # decoded or screened
                         for rows, maps in ((pick, self.model.decode_pooled), (~pick, self.model.splat_maps))
                         if bool(rows.any())]  # fmt: skip
                first = parts[0][1]
                out = ScoreOutput(first.score.new_empty(len(chunk)), coverage,
                                  {k: v.new_empty(len(chunk)) for k, v in first.terms.items()})  # fmt: skip
                for rows, part in parts:
                    out.score[rows] = part.score
                    for k, v in out.terms.items():
                        v[rows] = part.terms[k]
                outs.append(out)
                exact.append(pick)
        terms = {k: torch.cat([o.terms[k] for o in outs]) for k in outs[0].terms}
        merged = ScoreOutput(torch.cat([o.score for o in outs]), torch.cat([o.coverage for o in outs]), terms)
        return merged, torch.cat(exact)

    def score_screened(self, cam2world, batch_size, keep, rank, eligible=None):
        """:meth:`Scorer.score_screened`, screened by the splatted teacher map (the ``splat``
        baseline: the decoder left out, its input pooled once): every pose is rendered once, the
        ``keep`` best by ``rank`` of the screen are decoded, the rest never are. The decoder is
        ~40 % of a suggestion and the screen agrees with it (Spearman 0.79-0.95 over a search's
        stage-1 candidates, docs/benchmarks.md), so stage 1 decodes a quarter of its poses."""
        who = "AestheticField.score_screened"
        poses = check_poses(cam2world, who)
        n = poses.shape[0]
        for name, v in (("keep", keep), ("batch_size", batch_size)):
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ScorerError(f"{who}: {name} must be an integer >= 1, got {v!r}")
        ok = torch.ones(n, dtype=torch.bool) if eligible is None else torch.as_tensor(eligible, dtype=torch.bool)
        if tuple(ok.shape) != (n,):
            raise ScorerError(f"{who}: eligible must be [B] = [{n}] booleans, got shape {tuple(ok.shape)}")
        if keep >= n or len(self._gaussians) == 0:  # nothing to leave out
            return super().score_screened(poses, batch_size, keep, rank, eligible)
        screens: list[ScoreOutput] = []
        kept_idx = torch.zeros(0, dtype=torch.long)  # [k] the best so far, by (eligible, rank)
        kept_rank = torch.zeros(0, dtype=torch.float64)  # [k]
        kept_slot = torch.zeros(0, dtype=torch.long)  # [k] the row of held that holds each one's pooled input
        held: Tensor | None = None  # [keep, C + D + 1 (+ 2), 2fh, 2fw]: only the kept stay in memory
        with torch.no_grad():
            for start in range(0, n, batch_size):
                chunk = poses[start : start + batch_size]
                pooled, coverage = render_pooled(self.model, self._gaussians, self.local_frame, chunk, self.intrinsics)
                screen = self._explain(self.model.splat_maps(pooled), coverage, pooled)
                screens.append(screen)
                idx = torch.cat([kept_idx, torch.arange(start, start + len(chunk))])
                r = torch.cat([kept_rank, torch.nan_to_num(rank(screen).double(), nan=-math.inf)])
                order = torch.argsort(r, descending=True, stable=True)
                order = order[torch.argsort((~ok[idx[order]]).to(torch.uint8), stable=True)][:keep]  # eligible first
                # only the poses of this batch that join the kept are copied, into rows that dropped out
                # (the kept's pooled inputs concatenated with each batch and reindexed: 13-20 ms a suggestion, 1 thread)
                if held is None:
                    held = torch.empty((keep, *pooled.shape[1:]), dtype=pooled.dtype, memory_format=torch.channels_last)
                old = order < len(kept_idx)  # [k'] kept before
                free = torch.ones(keep, dtype=torch.bool)
                free[kept_slot[order[old]]] = False
                slot = torch.empty_like(order)
                slot[old] = kept_slot[order[old]]
                slot[~old] = torch.nonzero(free).flatten()[: int((~old).sum())]
                held[slot[~old]] = pooled[order[~old] - len(kept_idx)]
                kept_idx, kept_rank, kept_slot = idx[order], r[order], slot
            kept_pooled = held[kept_slot]  # [k, ...] in rank order, as the decoder's batches take them
            decoded = [
                self._explain(self.model.decode_pooled(part), torch.zeros(0), part)
                for part in (kept_pooled[s : s + batch_size] for s in range(0, len(kept_idx), batch_size))
            ]
        score = torch.cat([o.score for o in screens])
        coverage = torch.cat([o.coverage for o in screens])
        terms = {k: torch.cat([o.terms[k] for o in screens]) for k in screens[0].terms}
        score[kept_idx] = torch.cat([o.score for o in decoded]).to(score.dtype)
        for k in terms:
            terms[k][kept_idx] = torch.cat([o.terms[k] for o in decoded]).to(terms[k].dtype)
        exact = torch.zeros(n, dtype=torch.bool)
        exact[kept_idx] = True
        return ScoreOutput(score, coverage, terms), exact
