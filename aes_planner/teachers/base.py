"""The ``Teacher`` interface: a 2D aesthetic model split into a feature trunk and a scoring head.

The split is the paper's (section 3.1): the aesthetic field is trained to render the teacher's
intermediate feature map at novel views, and the teacher's remaining layers (the *head*) score
the rendered map. Everything downstream relies on four facts of every teacher:

* ``features(images)`` maps images ``[B, 3, H, W]`` (float RGB in ``[0, 1]``, any ``H x W``)
  to a map ``[B, feature_channels, *feature_size]`` at the teacher's fixed resolution;
* ``head(fmap)`` maps such a map to one score per image, ``[B]``;
* ``score(images) == head(features(images))``;
* both halves are differentiable: the search backpropagates through ``head`` into camera poses,
  and RGB-scoring baselines backpropagate through ``score`` into the image.

Teachers are frozen: their parameters never require gradients and they stay in eval mode (no
dropout, whatever ``.train()`` is called with). Inputs are checked at the boundary; values
outside ``[0, 1]`` are clamped, NaN and inf are refused.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import Tensor, nn

from aes_planner.errors import AesPlannerError

__all__ = ["Teacher", "TeacherError", "WeightsError", "check_images", "check_feature_map"]


class TeacherError(AesPlannerError, ValueError):
    """A teacher was asked for something it cannot do: wrong input shape, unknown name..."""


class WeightsError(TeacherError):
    """A teacher's weights are missing, unreadable, or do not fit its architecture."""


def check_images(images: Tensor, who: str) -> Tensor:  # [B, 3, H, W] -> [B, 3, H, W]
    """Validate an image batch and return it as floating point clamped to ``[0, 1]``.

    Raises :class:`TeacherError` naming ``who`` for a wrong rank, channel count, empty size,
    integer dtype or non-finite values.
    """
    if not isinstance(images, Tensor):
        raise TeacherError(f"{who}: expected a torch.Tensor [B, 3, H, W], got {type(images).__name__}")
    if images.dim() != 4 or images.shape[1] != 3:
        raise TeacherError(
            f"{who}: expected images [B, 3, H, W] (RGB, channels first), got shape {tuple(images.shape)}; "
            "add a batch dimension with images[None] or move channels with .permute(0, 3, 1, 2)"
        )
    if images.shape[0] == 0 or images.shape[2] == 0 or images.shape[3] == 0:
        raise TeacherError(f"{who}: empty image batch of shape {tuple(images.shape)}")
    if not images.is_floating_point():
        raise TeacherError(
            f"{who}: expected float images in [0, 1], got dtype {images.dtype}; convert uint8 with images.float() / 255"
        )
    if not bool(torch.isfinite(images).all()):
        raise TeacherError(f"{who}: images contain NaN or inf; check the renderer or the file")
    return images.clamp(0.0, 1.0)


def check_feature_map(fmap: Tensor, channels: int, size: tuple[int, int], who: str) -> None:
    """Raise :class:`TeacherError` unless ``fmap`` is ``[B, channels, *size]``."""
    if not isinstance(fmap, Tensor) or fmap.dim() != 4 or tuple(fmap.shape[1:]) != (channels, *size):
        shape = tuple(fmap.shape) if isinstance(fmap, Tensor) else type(fmap).__name__
        raise TeacherError(
            f"{who}: expected a feature map [B, {channels}, {size[0]}, {size[1]}], got {shape}; "
            "render the field at the teacher's feature_size with feature_channels channels"
        )


class Teacher(nn.Module, ABC):
    """A frozen 2D aesthetic model split into ``features`` (trunk) and ``head``.

    Subclasses set :attr:`name`, :attr:`feature_channels` and :attr:`feature_size`, implement
    :meth:`features` and :meth:`head`, and may override :meth:`explain` to return more terms
    than the score. Call :meth:`freeze` at the end of ``__init__``.
    """

    #: Registry name (``get_teacher(name)``, ``--teacher NAME``).
    name: str = "teacher"
    #: Channels ``C`` of the feature map.
    feature_channels: int
    #: ``(h, w)`` of the feature map, fixed whatever the input size.
    feature_size: tuple[int, int]
    #: What the score means, one line (shown by the CLI).
    score_range: str = "unbounded; higher is better"

    def freeze(self) -> Teacher:
        """No parameter gradients, eval mode; returns ``self``."""
        self.requires_grad_(False)
        return super().train(False)

    def train(self, mode: bool = True) -> Teacher:
        # A teacher is never trained here: keep dropout off even inside a module being trained.
        return super().train(False)

    @abstractmethod
    def features(self, images: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1] -> [B, C, h, w]
        """The feature map the field distils, at :attr:`feature_size`."""

    @abstractmethod
    def head(self, fmap: Tensor) -> Tensor:  # [B, C, h, w] -> [B]
        """Scores of feature maps (real ones or rendered by the field)."""

    def score(self, images: Tensor) -> Tensor:  # [B, 3, H, W] -> [B]
        """``head(features(images))``."""
        return self.head(self.features(images))

    def explain_map(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, C, h, w] -> {name: [B]}
        """Named terms behind the score of each feature map; always includes ``"score"``.

        Teachers whose head is a black box (VEN) return the score alone.
        """
        return {"score": self.head(fmap)}

    def explain_scores(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, C, h, w] -> {name: [B]}
        """:meth:`explain_map` where only ``"score"`` carries a gradient (the other terms detached):
        what a search reads, which ascends the score and reports the terms. Teachers may compute
        it faster than :meth:`explain_map` (the composition teacher: one compiled kernel)."""
        terms = self.explain_map(fmap)
        return {k: (v if k == "score" else v.detach()) for k, v in terms.items()}

    def warm(self) -> float | None:
        """Compile (or load from a cache) whatever the teacher compiles before its first use, so
        that a planner's first suggestion does not wait for it; seconds taken, or None when there
        is nothing to compile (the default)."""
        return None

    def explain(self, images: Tensor) -> dict[str, Tensor]:  # [B, 3, H, W] -> {name: [B]}
        """Named terms behind each image's score; always includes ``"score"``."""
        return self.explain_map(self.features(images))

    def forward(self, images: Tensor) -> Tensor:  # [B, 3, H, W] -> [B]
        return self.score(images)

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, feature_map=[{self.feature_channels}, {self.feature_size[0]}, {self.feature_size[1]}]"
        )
