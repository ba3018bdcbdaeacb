"""VEN, the View Evaluation Net of "Good View Hunting" (Wei et al., CVPR 2018): the paper's teacher.

Architecture, exactly as released: torchvision's VGG-16 ``features`` (13 conv3x3+ReLU, 5 max
pools; no batch norm), no average pool, then ``classifier = Sequential(Linear(25088, 1024),
ReLU, Dropout, Linear(1024, 512), ReLU, Dropout, Linear(512, 1))``: one unbounded score per
image, trained with a pairwise ranking loss (only differences between scores mean something).

Split (the paper's layer-23 map): ``features()`` runs the preprocessing and ``features[:24]``
(up to and including pool4), giving ``[B, 512, 14, 14]`` for a 224x224 input; ``head()`` runs
``features[24:]`` (conv5 block and pool5), flattens and applies the classifier.

Preprocessing (the original evaluation transform): resize to 224x224 with bilinear
interpolation, aspect not kept (antialiased when shrinking, like PIL's ``BILINEAR``), then
ImageNet mean/std normalisation. A 224x224 input is not resampled at all, so it scores exactly
what the original network computes.

Weights are the user's file (nothing here downloads them); see :data:`WEIGHTS_ADVICE`. Files
are read with ``torch.load(weights_only=True)`` and nothing else: no file is ever unpickled with
code of its choosing. The released checkpoint was pickled by an old PyTorch next to its tensors
(training extras such as numpy scalars or an ``argparse.Namespace``), which a weights-only load
refuses; :func:`_read_checkpoint` then names each such class and lets the weights-only loader
build an inert placeholder in its place (a class of ours that stores nothing and runs nothing),
so the released file loads as it is. Modules torch blocks outright (``os``, ``subprocess``, ...)
are refused: a weights file never needs them. ``aes-planner teachers convert-ven SRC DST``
writes the bare state dict (smaller, no placeholders) for those who prefer that.
"""

from __future__ import annotations

import hashlib
import logging
import pickle
import re
import struct
import warnings
import zipfile
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from aes_planner.teachers.base import Teacher, TeacherError, WeightsError, check_feature_map, check_images
from aes_planner.teachers.torchfile import DeclaredSizeError, check_declared_sizes

log = logging.getLogger(__name__)

__all__ = ["VENTeacher", "VENNet", "vgg16_features", "load_ven_state_dict", "convert_checkpoint", "WEIGHTS_ADVICE"]

#: What to tell a user who has no VEN weights.
WEIGHTS_ADVICE = (
    "VEN needs its released weights, which are not bundled and cannot be downloaded by this package. "
    "Get the checkpoint (EvaluationNet.pth.tar) from the authors' repository "
    "https://github.com/zijunwei/ViewEvaluationNet (its ReadMe links the pre-trained model on Google Drive), then pass it with "
    "`--weights PATH` (CLI) or get_teacher('ven', weights=PATH) (Python). "
    "Without weights, use the default `--teacher composition`, which needs none."
)

#: torchvision's VGG-16 configuration "D": conv widths, "M" = 2x2 max pool.
_VGG16_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")
#: Index of the first layer after pool4 in ``features`` (the paper's split: ``features[:24]``).
SPLIT = 24
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
INPUT_SIZE = 224
# Stripped in this order, so DataParallel wrappers inside or outside the Siamese net go too.
_PREFIXES = ("module.", "single_pass_net.", "module.")


def vgg16_features() -> nn.Sequential:
    """VGG-16 ``features`` with torchvision's module indices (conv at 0, 2, 5, 7, 10, ... 28).

    So that state-dict keys read ``features.0.weight`` ... ``features.28.bias`` as in
    torchvision and in the VEN checkpoint. ReLUs are not in-place: the trunk's output is
    rendered and compared by the field, and in-place ops would get in autograd's way.
    """
    layers: list[nn.Module] = []
    c_in = 3
    for v in _VGG16_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(c_in, int(v), kernel_size=3, padding=1), nn.ReLU()]
            c_in = int(v)
    return nn.Sequential(*layers)


def _ven_classifier() -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(512 * 7 * 7, 1024),
        nn.ReLU(),
        nn.Dropout(),
        nn.Linear(1024, 512),
        nn.ReLU(),
        nn.Dropout(),
        nn.Linear(512, 1),
    )


class VENNet(nn.Module):
    """The original single-pass network (``single_pass_net`` of the release), unsplit.

    Its state-dict keys are the checkpoint's: ``features.0.weight`` ... ``classifier.6.bias``.
    ``forward`` takes preprocessed ``[B, 3, 224, 224]`` input, as the original did.
    """

    def __init__(self) -> None:
        super().__init__()
        self.features = vgg16_features()
        self.classifier = _ven_classifier()

    def forward(self, x: Tensor) -> Tensor:  # [B, 3, 224, 224] normalised -> [B, 1]
        x = self.features(x)
        return self.classifier(torch.flatten(x, 1))


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class _Inert:
    """Stands in for a class a checkpoint pickled beyond its tensors: stores nothing, runs nothing."""

    pickled_global = "?"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        pass

    def __repr__(self) -> str:
        return f"<{self.pickled_global}, not loaded>"


_MAX_PLACEHOLDERS = 64  # distinct classes a checkpoint may pickle besides tensors
_UNSUPPORTED = re.compile(r"Unsupported global: GLOBAL ([\w.]+)")
_BLOCKED = re.compile(r"unsupported GLOBAL ([\w.]+) whose module ([\w.]+) is blocked")
_BAD_FILE = (
    RuntimeError,
    EOFError,
    OSError,
    ValueError,
    zipfile.BadZipFile,
    KeyError,
    AttributeError,
    TypeError,
    IndexError,
    struct.error,
    OverflowError,
    NotImplementedError,
    MemoryError,
    RecursionError,
    AssertionError,  # torch's own checks of a damaged file (``saved_id must be a tuple``)
)
#: Largest magnitude a VEN weight may have. Trained VGG-16 / VEN weights stay below about 10; a
#: file with 1e30 in it is not VEN's weights, and would make every score overflow to NaN.
MAX_ABS_WEIGHT = 1e3


def _placeholder(name: str) -> tuple[type, str]:
    return type("Inert_" + name.replace(".", "_"), (_Inert,), {"pickled_global": name}), name


def _read_checkpoint(path: Path) -> Any:
    """``torch.load(path, weights_only=True)``, with inert placeholders (:class:`_Inert`) for
    the classes a checkpoint pickles besides tensors, and errors that say what to do."""
    if path.is_dir():
        raise WeightsError(f"{path} is a folder, not a readable PyTorch checkpoint; give the weights file itself")
    if not path.is_file():
        raise WeightsError(f"VEN weights file {path} does not exist. " + WEIGHTS_ADVICE)
    try:  # torch.load allocates what the file declares before it reads: check the declarations first
        check_declared_sizes(path)
    except DeclaredSizeError as exc:
        raise WeightsError(
            f"{path} is not a readable PyTorch checkpoint ({exc}); re-download it. " + WEIGHTS_ADVICE
        ) from None
    except _BAD_FILE as exc:
        raise WeightsError(
            f"{path} is not a readable PyTorch checkpoint (truncated or corrupt: {str(exc)[:160]}); re-download it. "
            + WEIGHTS_ADVICE
        ) from None
    names: list[str] = []
    while True:
        try:
            with torch.serialization.safe_globals([_placeholder(n) for n in names]), warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # torch's notes on odd pickle protocols of broken files
                obj = torch.load(path, map_location="cpu", weights_only=True)
            break
        except pickle.UnpicklingError as exc:
            text = str(exc)
            blocked = _BLOCKED.search(text)
            if blocked:
                raise WeightsError(
                    f"{path} references {blocked.group(1)} (module {blocked.group(2)}), which a weights file never "
                    "needs; it is not loaded. Get the checkpoint from its original source. " + WEIGHTS_ADVICE
                ) from None
            found = _UNSUPPORTED.search(text)
            if found is None or found.group(1) in names or len(names) >= _MAX_PLACEHOLDERS:
                raise WeightsError(
                    f"{path} is not a readable PyTorch checkpoint ({text.splitlines()[0]}); "
                    "re-download it. " + WEIGHTS_ADVICE
                ) from None
            names.append(found.group(1))
        except _BAD_FILE as exc:
            raise WeightsError(
                f"{path} is not a readable PyTorch checkpoint (truncated or corrupt: {str(exc)[:160]}); re-download it. "
                + WEIGHTS_ADVICE
            ) from None
    if names:
        log.info(
            "%s: %d pickled classes besides tensors read as inert placeholders: %s", path, len(names), ", ".join(names)
        )
    return obj


def _extract_state_dict(obj: Any, source: str) -> OrderedDict[str, Tensor]:
    """The VEN state dict from a released checkpoint or a plain state dict, prefixes stripped."""
    if isinstance(obj, nn.Module):
        obj = obj.state_dict()
    if isinstance(obj, Mapping) and "state_dict" in obj and isinstance(obj["state_dict"], Mapping):
        obj = obj["state_dict"]
    if not isinstance(obj, Mapping):
        raise WeightsError(f"{source}: expected a state dict or {{'state_dict': ...}}, got {type(obj).__name__}")
    out: OrderedDict[str, Tensor] = OrderedDict()
    for key, value in obj.items():
        name = str(key)
        for prefix in _PREFIXES:
            if name.startswith(prefix):
                name = name[len(prefix) :]
        if not isinstance(value, Tensor):
            raise WeightsError(
                f"{source}: entry {key!r} is a {type(value).__name__}, not a tensor; is this a VEN checkpoint?"
            )
        out[name] = value
    return out


def load_ven_state_dict(weights: str | Path | Mapping[str, Any]) -> OrderedDict[str, Tensor]:
    """Read VEN weights (released ``{'state_dict': {'single_pass_net.*'}}`` layout or a plain
    ``features.* / classifier.*`` state dict) from a file or a mapping, prefixes stripped."""
    if isinstance(weights, (str, Path)):
        path = Path(weights).expanduser()
        return _extract_state_dict(_read_checkpoint(path), str(path))
    return _extract_state_dict(weights, "weights")


def convert_checkpoint(src: str | Path, dst: str | Path) -> Path:
    """Write the VEN state dict of ``src`` (any layout :func:`load_ven_state_dict` reads) to
    ``dst`` as bare tensors: smaller, and free of the placeholders the released file needs.

    ``src`` is read like any weights file (weights-only, nothing executed); the SHA-256 of both
    files is logged so that the source can be compared with the published one.
    """
    src, dst = Path(src).expanduser(), Path(dst).expanduser()
    log.info("reading %s (sha256 %s)", src, _sha256(src) if src.is_file() else "missing")
    if dst.is_dir():  # checked before the (slow) load
        raise WeightsError(f"{dst} is a folder; give the file to write, e.g. {dst / 'ven_weights.pt'}")
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WeightsError(f"{dst}: cannot write the converted weights ({exc.strerror or exc})") from None
    state = load_ven_state_dict(src)
    VENTeacher(state)  # refuse to write weights that do not fit
    try:
        torch.save({k: v.detach().clone().contiguous() for k, v in state.items()}, dst)
    except (OSError, RuntimeError) as exc:
        raise WeightsError(f"{dst}: cannot write the converted weights ({str(exc).strip()[:160]})") from None
    log.info("wrote %s (%d tensors, sha256 %s)", dst, len(state), _sha256(dst))
    return dst


class VENTeacher(Teacher):
    """VEN with the original architecture, preprocessing and checkpoint layout (module docstring).

    ``weights``: a path to the user's checkpoint or a state dict (see
    :func:`load_ven_state_dict`). Refused when missing: :data:`WEIGHTS_ADVICE`. For tests and
    benchmarks, :meth:`random` builds one with random weights (its scores mean nothing).
    """

    name = "ven"
    score_range = "unbounded (ranking score: compare views of one scene, not across scenes)"
    feature_channels = 512
    feature_size = (14, 14)

    def __init__(self, weights: str | Path | Mapping[str, Any] | None = None, *, _random: bool = False):
        super().__init__()
        self.register_buffer(
            "_mean", torch.tensor(IMAGENET_MEAN, dtype=torch.float32).view(1, 3, 1, 1), persistent=False
        )
        self.register_buffer("_std", torch.tensor(IMAGENET_STD, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)
        if weights is None and not _random:
            raise WeightsError(WEIGHTS_ADVICE)
        if weights is None:
            self.net = VENNet()
        else:
            state = load_ven_state_dict(weights)
            with torch.device("meta"):  # shapes only: no time spent on an initialisation we overwrite
                self.net = VENNet()
            self._load(state)
        self.float()  # float32 whatever torch's default dtype
        self.freeze()

    @classmethod
    def random(cls, seed: int = 0) -> VENTeacher:
        """VEN with random weights, for tests and timing: its scores mean nothing."""
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            teacher = cls(_random=True)
            # torchvision's VGG initialisation, so that activations neither vanish nor explode.
            for m in teacher.net.modules():
                if isinstance(m, nn.Conv2d):
                    nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                    nn.init.zeros_(m.bias)
                elif isinstance(m, nn.Linear):
                    nn.init.normal_(m.weight, 0.0, 0.01)
                    nn.init.zeros_(m.bias)
        return teacher

    def _load(self, state: Mapping[str, Tensor]) -> None:
        expected = self.net.state_dict()
        missing = [k for k in expected if k not in state]
        unexpected = [k for k in state if k not in expected]
        if missing or unexpected:
            raise WeightsError(
                "these weights are not VEN's (VGG-16 features + 1024-512-1 classifier): "
                + (f"missing {missing[:4]}{' ...' if len(missing) > 4 else ''}; " if missing else "")
                + (f"unexpected {unexpected[:4]}{' ...' if len(unexpected) > 4 else ''}" if unexpected else "")
            )
        for k, v in expected.items():
            if tuple(state[k].shape) != tuple(v.shape):
                raise WeightsError(f"VEN weight {k} has shape {tuple(state[k].shape)}, expected {tuple(v.shape)}")
            if not state[k].is_floating_point() or not torch.isfinite(state[k]).all():
                raise WeightsError(f"VEN weight {k} is not finite floating point: the file is damaged; re-download it")
            peak = float(state[k].detach().abs().max()) if state[k].numel() else 0.0
            if peak > MAX_ABS_WEIGHT:
                raise WeightsError(
                    f"VEN weight {k} holds values up to {peak:.3g}; trained VEN weights stay below {MAX_ABS_WEIGHT:g}, "
                    "so this file is damaged or not VEN's. " + WEIGHTS_ADVICE
                )
        tensors = {k: state[k].detach().to(device="cpu", dtype=torch.float32, copy=True).contiguous() for k in expected}
        self.net.load_state_dict(tensors, strict=True, assign=True)

    def preprocess(self, images: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1] -> [B, 3, 224, 224]
        """The original evaluation transform: bilinear resize to 224x224, ImageNet normalisation."""
        images = check_images(images, "VEN").to(self._mean.dtype)
        if tuple(images.shape[-2:]) != (INPUT_SIZE, INPUT_SIZE):
            images = F.interpolate(
                images, size=(INPUT_SIZE, INPUT_SIZE), mode="bilinear", align_corners=False, antialias=True
            )
        # Contiguous NCHW: a channels-last input would change the conv kernels, and their rounding.
        return ((images - self._mean) / self._std).contiguous()

    def features(self, images: Tensor) -> Tensor:  # [B, 3, H, W] -> [B, 512, 14, 14]
        return self.net.features[:SPLIT](self.preprocess(images))

    def head(self, fmap: Tensor) -> Tensor:  # [B, 512, 14, 14] -> [B]
        check_feature_map(fmap, self.feature_channels, self.feature_size, "VEN head")
        x = self.net.features[SPLIT:](fmap)
        score = self.net.classifier(torch.flatten(x, 1))[:, 0]
        if not torch.isfinite(score.detach()).all():
            raise TeacherError(
                "VEN gave a non-finite score (the activations overflowed float32): the weights or the feature "
                "map hold values far beyond trained ones; check the weights file"
            )
        return score
