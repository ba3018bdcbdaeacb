"""Autograd for the package's own gradients, whatever the caller's grad mode."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def autograd_on() -> Iterator[None]:
    """Autograd on for the block, also inside a caller's ``torch.no_grad()`` or
    ``torch.inference_mode()``: for the package's own gradients (the reconstruction's blending
    weights, the search's pose refinement), which are part of its results, not of the caller's
    training. Tensors made in the block are normal tensors."""
    with torch.inference_mode(False), torch.enable_grad():
        yield
