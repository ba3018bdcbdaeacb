"""Synthetic compositions whose right answer is known: subjects, horizons, clutter.

Used by the known-answer tests, the ``teachers`` benchmark, and as the fallback image set for
measuring the evaluator's correlation with a teacher where no simulator is at hand. Images are
``[3, H, W]`` float tensors in ``[0, 1]``; coordinates are in frame units (0 = left/top,
1 = right/bottom); shapes are anti-aliased over about one pixel so that nothing depends on
where a pixel boundary falls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

__all__ = ["canvas", "draw_disc", "draw_box", "draw_horizon", "add_clutter", "random_composition"]

Colour = Sequence[float]


def _axis(n: int, lo: float, hi: float) -> tuple[slice, np.ndarray]:
    """Pixels along one axis that a span [lo, hi] (frame units) touches, with their centres."""
    a, b = max(0, int(math.floor(lo * n)) - 1), min(n, int(math.ceil(hi * n)) + 1)
    return slice(a, max(a, b)), (np.arange(a, max(a, b), dtype=np.float32) + 0.5) / n


def _paint(
    img: Tensor, rows: slice, cols: slice, coverage: np.ndarray, colour: Colour
) -> Tensor:  # [3, H, W] -> [3, H, W]
    """A copy of ``img`` with ``colour`` blended in over the window by ``coverage`` in [0, 1]."""
    out = img.clone()
    view = out.numpy()[:, rows, cols]
    a = np.clip(coverage, 0.0, 1.0)[None].astype(np.float32)
    c = np.asarray(colour, np.float32).reshape(3, 1, 1)
    view[...] = view * (1 - a) + c * a
    return out


def canvas(h: int, w: int, colour: Colour = (0.55, 0.55, 0.55)) -> Tensor:  # -> [3, H, W]
    """A uniform image."""
    return torch.as_tensor(colour, dtype=torch.float32).view(3, 1, 1).expand(3, h, w).clone()


def draw_disc(img: Tensor, cx: float, cy: float, radius: float, colour: Colour) -> Tensor:  # [3, H, W] -> [3, H, W]
    """A disc centred at ``(cx, cy)`` with ``radius`` in units of the frame height."""
    h, w = img.shape[-2:]
    rows, y = _axis(h, cy - radius, cy + radius)
    cols, x = _axis(w, cx - radius * h / w, cx + radius * h / w)
    d = np.sqrt(((x[None] - cx) * w / h) ** 2 + (y[:, None] - cy) ** 2)  # in frame heights
    return _paint(img, rows, cols, (radius - d) * h + 0.5, colour)


def draw_box(
    img: Tensor, x0: float, y0: float, x1: float, y1: float, colour: Colour
) -> Tensor:  # [3, H, W] -> [3, H, W]
    """An axis-aligned box between frame corners ``(x0, y0)`` and ``(x1, y1)``."""
    h, w = img.shape[-2:]
    rows, y = _axis(h, y0, y1)
    cols, x = _axis(w, x0, x1)
    cov_x = np.clip((x - x0) * w + 0.5, 0, 1) * np.clip((x1 - x) * w + 0.5, 0, 1)
    cov_y = np.clip((y - y0) * h + 0.5, 0, 1) * np.clip((y1 - y) * h + 0.5, 0, 1)
    return _paint(img, rows, cols, cov_y[:, None] * cov_x[None], colour)


def draw_horizon(
    img: Tensor, y: float, tilt_deg: float = 0.0, sky: Colour = (0.62, 0.75, 0.92), ground: Colour = (0.35, 0.45, 0.25)
) -> Tensor:  # [3, H, W] -> [3, H, W]
    """Sky above and ground below a straight line through ``(0.5, y)`` tilted by ``tilt_deg``."""
    h, w = img.shape[-2:]
    rows, yy = _axis(h, 0.0, 1.0)
    cols, xx = _axis(w, 0.0, 1.0)
    line = y + math.tan(math.radians(tilt_deg)) * (xx[None] - 0.5) * w / h
    below = (yy[:, None] - line) * h + 0.5
    img = _paint(img, rows, cols, np.ones_like(below), sky)
    return _paint(img, rows, cols, below, ground)


def add_clutter(
    img: Tensor, count: int, rng: np.random.Generator, size: float = 0.06
) -> Tensor:  # [3, H, W] -> [3, H, W]
    """``count`` small boxes of random colour scattered over the whole frame."""
    for _ in range(count):
        x, y = rng.uniform(0, 1, 2)
        s = size * rng.uniform(0.5, 1.5, 2)
        img = draw_box(img, x - s[0] / 2, y - s[1] / 2, x + s[0] / 2, y + s[1] / 2, rng.uniform(0, 1, 3))
    return img


def random_composition(rng: np.random.Generator, h: int = 96, w: int = 128) -> Tensor:  # -> [3, H, W]
    """A random scene: background or horizon (possibly tilted), 0-3 subjects, some clutter.

    Placements are drawn uniformly, so the set spans good and bad framings alike.
    """
    if rng.uniform() < 0.6:
        img = draw_horizon(
            canvas(h, w),
            rng.uniform(0.1, 0.9),
            rng.normal(0, 4.0),
            sky=rng.uniform(0.4, 1.0, 3),
            ground=rng.uniform(0.0, 0.6, 3),
        )
    else:
        img = canvas(h, w, rng.uniform(0.1, 0.9, 3))
    for _ in range(rng.integers(0, 4)):
        cx, cy = rng.uniform(-0.05, 1.05, 2)
        r = float(np.exp(rng.uniform(math.log(0.03), math.log(0.35))))
        if rng.uniform() < 0.5:
            img = draw_disc(img, cx, cy, r, rng.uniform(0, 1, 3))
        else:
            img = draw_box(img, cx - r * h / w, cy - r, cx + r * h / w, cy + 1.5 * r, rng.uniform(0, 1, 3))
    if rng.uniform() < 0.4:
        img = add_clutter(img, int(rng.integers(5, 60)), rng)
    return img
