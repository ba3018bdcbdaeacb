"""An independent composition evaluator, for measurement only (the role SAMPNet plays in the paper).

It never guides a search: it checks whether what a teacher rewards is also what a differently
built judge rewards. So it shares no code and few ideas' implementations with the composition
teacher, and it is not differentiable:

* saliency from OpenCV-contrib's spectral residual (frequency domain) on luminance and on an
  opponent-colour channel, instead of spatial centre-surround differences;
* the **subject** as a discrete object: the largest connected component of the binarised saliency
  map (Otsu), with its bounding box, centroid and area, instead of a soft mass distribution;
* **lines** as segments from OpenCV's line segment detector, instead of a pooled structure tensor;
* **composition patterns** in the spirit of SAMPNet's: rule of thirds, centre with symmetry,
  horizontal and vertical lines on thirds, diagonals; the best-fitting pattern counts;
* **checks**: subject touching the border, tilted near-horizontal lines, subject size, clutter
  (salient components and Canny edge density), and emptiness (edge density and colourfulness).

``evaluate(images) -> scores`` in ``[0, 1]``; :meth:`CompositionEvaluator.explain` gives the
parts. :func:`correlation` measures a teacher's agreement with it (PLCC and SRCC).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

from aes_planner.config import require
from aes_planner.metrics import plcc, srcc
from aes_planner.teachers.base import Teacher, TeacherError

__all__ = ["EvaluatorConfig", "CompositionEvaluator", "correlation", "PATTERNS"]

PATTERNS = ("thirds", "centre_symmetry", "horizontal", "vertical", "diagonal")


@dataclass(frozen=True)
class EvaluatorConfig:
    """``size``: side of the square working image (px). ``min_line``: shortest line segment that
    counts, as a share of the working image side."""

    size: int = 128
    min_line: float = 0.3

    def __post_init__(self):
        require(
            isinstance(self.size, int) and 32 <= self.size <= 1024,
            "size",
            f"must be an integer in [32, 1024], got {self.size!r}",
        )
        require(0.05 <= self.min_line <= 1.0, "min_line", f"must be in [0.05, 1], got {self.min_line}")


def _to_uint8_rgb(image: Tensor | np.ndarray) -> np.ndarray:  # [3, H, W] float or [H, W, 3] -> [H, W, 3] uint8
    if isinstance(image, Tensor):
        if image.dim() != 3 or image.shape[0] != 3:
            raise TeacherError(f"evaluator: expected an image [3, H, W], got {tuple(image.shape)}")
        image = image.detach().float().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise TeacherError(f"evaluator: expected an RGB image [H, W, 3], got {arr.shape}")
    if arr.dtype != np.uint8:
        arr = (np.clip(np.nan_to_num(arr.astype(np.float32)), 0, 1) * 255 + 0.5).astype(np.uint8)
    return arr


def _gauss(x: float, mu: float, sigma: float) -> float:
    return math.exp(-((x - mu) ** 2) / (2 * sigma * sigma))


class CompositionEvaluator:
    """OpenCV-based composition judge; see the module docstring. Not a :class:`Teacher`."""

    def __init__(self, config: EvaluatorConfig | None = None):
        self.config = config or EvaluatorConfig()
        self._sr = cv2.saliency.StaticSaliencySpectralResidual_create()
        self._lsd = cv2.createLineSegmentDetector()

    # ------------------------------------------------------------------ evidence
    def _saliency(self, rgb: np.ndarray) -> np.ndarray:  # [s, s, 3] uint8 -> [s, s] float32 in [0, 1]
        f = rgb.astype(np.float32) / 255.0
        lum = 0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2]
        chroma = np.abs(f[..., 0] - f[..., 1]) + np.abs(0.5 * (f[..., 0] + f[..., 1]) - f[..., 2])
        total = np.zeros(lum.shape, np.float32)
        for channel in (lum, chroma):
            if float(channel.std()) < 1e-3:
                continue
            ok, sal = self._sr.computeSaliency((channel * 255).astype(np.uint8))
            if ok:
                total += np.nan_to_num(sal.astype(np.float32))
        total = cv2.GaussianBlur(total, (0, 0), self.config.size / 64)
        peak = float(total.max())
        return total / peak if peak > 1e-6 else total

    def _subject(self, sal: np.ndarray) -> dict[str, float] | None:
        """Largest-saliency connected component of the Otsu-binarised map, in frame units."""
        if float(sal.max()) < 1e-6:
            return None
        u8 = (sal * 255).astype(np.uint8)
        _, binary = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        n, labels, stats, cents = cv2.connectedComponentsWithStats(binary, connectivity=8)
        if n <= 1:
            return None
        mass = np.array([sal[labels == i].sum() for i in range(1, n)])
        i = int(mass.argmax()) + 1
        s = self.config.size
        x, y, w, h, area = stats[i]
        return dict(
            cx=float(cents[i][0] + 0.5) / s,
            cy=float(cents[i][1] + 0.5) / s,
            area=float(area) / (s * s),
            touches=float((x <= 0) + (y <= 0) + (x + w >= s) + (y + h >= s)),
            components=float(sum(1 for m in mass if m > 0.2 * mass.max())),
        )

    def _lines(
        self, gray: np.ndarray
    ) -> np.ndarray:  # -> [N, 3]: (angle_deg in (-90, 90], length, mid_y, mid_x) frame units
        segs = self._lsd.detect(gray)[0]
        s = self.config.size
        if segs is None:
            return np.zeros((0, 4))
        segs = segs.reshape(-1, 4).astype(np.float64)
        dx, dy = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
        length = np.hypot(dx, dy) / s
        angle = np.degrees(np.arctan2(dy, dx))
        angle = (angle + 90.0) % 180.0 - 90.0  # a segment has no direction
        keep = length >= self.config.min_line
        mid_y = (segs[:, 1] + segs[:, 3]) / (2 * s)
        mid_x = (segs[:, 0] + segs[:, 2]) / (2 * s)
        return np.stack([angle, length, mid_y, mid_x], 1)[keep]

    # ---------------------------------------------------------------- judgement
    def explain_one(self, image: Tensor | np.ndarray) -> dict[str, float]:
        """Patterns, checks and the score of one image ([3, H, W] float or [H, W, 3])."""
        s = self.config.size
        rgb = cv2.resize(_to_uint8_rgb(image), (s, s), interpolation=cv2.INTER_AREA)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        sal = self._saliency(rgb)
        subject = self._subject(sal)
        lines = self._lines(gray)
        edges = cv2.Canny(cv2.GaussianBlur(gray, (3, 3), 0), 50, 150)
        edge_density = float((edges > 0).mean())
        f = rgb.astype(np.float32)
        rg, yb = f[..., 0] - f[..., 1], 0.5 * (f[..., 0] + f[..., 1]) - f[..., 2]
        colourfulness = float(np.hypot(rg.std(), yb.std()) + 0.3 * np.hypot(rg.mean(), yb.mean())) / 255.0

        horiz = lines[np.abs(lines[:, 0]) < 12.0] if len(lines) else lines
        vert = lines[np.abs(lines[:, 0]) > 78.0] if len(lines) else lines
        diag = lines[(np.abs(lines[:, 0]) > 25.0) & (np.abs(lines[:, 0]) < 65.0)] if len(lines) else lines

        def on_thirds(values: np.ndarray, lengths: np.ndarray) -> float:
            if not len(values):
                return 0.0
            fit = np.maximum(np.exp(-((values - 1 / 3) ** 2) / 0.005), np.exp(-((values - 2 / 3) ** 2) / 0.005))
            return float(np.max(fit * np.minimum(1.0, lengths / 0.6)))

        patterns = dict.fromkeys(PATTERNS, 0.0)
        sym = 1.0 - float(np.abs(gray.astype(np.float32) - gray[:, ::-1]).mean()) / 64.0
        patterns["horizontal"] = on_thirds(horiz[:, 2], horiz[:, 1]) if len(horiz) else 0.0
        patterns["vertical"] = on_thirds(vert[:, 3], vert[:, 1]) if len(vert) else 0.0
        patterns["diagonal"] = float(np.max(np.minimum(1.0, diag[:, 1] / 0.8))) if len(diag) else 0.0
        if subject is not None:
            d = min(math.hypot(subject["cx"] - a, subject["cy"] - b) for a in (1 / 3, 2 / 3) for b in (1 / 3, 2 / 3))
            patterns["thirds"] = _gauss(d, 0.0, 0.07)
            patterns["centre_symmetry"] = _gauss(math.hypot(subject["cx"] - 0.5, subject["cy"] - 0.5), 0, 0.07) * max(
                0.0, sym
            )
        pattern = max(patterns.values())

        checks = {}
        if subject is not None:
            checks["not_cut"] = 1.0 - 0.3 * subject["touches"]
            a = max(subject["area"], 1e-4)
            checks["size"] = 1.0 if 0.03 <= a <= 0.35 else _gauss(math.log(a / (0.03 if a < 0.03 else 0.35)), 0, 0.7)
            checks["focus"] = 1.0 / subject["components"]
        else:
            checks["not_cut"], checks["size"], checks["focus"] = 1.0, 0.0, 0.0
        tilts = np.abs(horiz[:, 0]) if len(horiz) else np.zeros(0)
        if len(tilts):
            worst = float(tilts[np.argmax(horiz[:, 1])])  # the longest near-horizontal line
            checks["level"] = 1.0 if worst < 0.75 else _gauss(worst, 0.75, 3.0)
        else:
            checks["level"] = 1.0
        checks["uncluttered"] = 1.0 if edge_density < 0.08 else max(0.0, 1.0 - (edge_density - 0.08) / 0.2)
        interest = min(1.0, edge_density / 0.008) * 0.7 + min(1.0, colourfulness / 0.15) * 0.3
        quality = float(np.prod(list(checks.values()))) ** (1.0 / len(checks))
        score = interest * (0.4 + 0.6 * pattern) * quality
        return {"score": score, **{f"pattern_{k}": v for k, v in patterns.items()}, **checks, "interest": interest}

    def explain(
        self, images: Tensor | Sequence[Tensor | np.ndarray]
    ) -> dict[str, np.ndarray]:  # [N, 3, H, W] -> {name: [N]}
        rows = [self.explain_one(img) for img in images]
        if not rows:
            raise TeacherError("evaluator: no images given")
        return {k: np.array([r[k] for r in rows]) for k in rows[0]}

    def evaluate(self, images: Tensor | Sequence[Tensor | np.ndarray]) -> np.ndarray:  # [N, 3, H, W] -> [N]
        """Scores in ``[0, 1]``, higher is better."""
        return self.explain(images)["score"]


def correlation(
    teacher: Teacher,
    images: Tensor | Iterable[Tensor],
    evaluator: CompositionEvaluator | None = None,
    batch_size: int = 32,
) -> dict[str, float]:
    """PLCC and SRCC between ``teacher.score`` and the evaluator over ``images``.

    ``images``: ``[N, 3, H, W]`` or an iterable of ``[3, H, W]`` tensors in ``[0, 1]`` (sizes may
    differ between items of an iterable). Returns ``{"plcc", "srcc", "n"}``.
    """
    evaluator = evaluator or CompositionEvaluator()
    items = list(images)
    if len(items) < 3:
        raise TeacherError(f"correlation needs at least 3 images, got {len(items)}")
    t_scores: list[float] = []
    with torch.no_grad():
        i = 0
        while i < len(items):
            j = i + 1
            while j < len(items) and j - i < batch_size and items[j].shape == items[i].shape:
                j += 1
            t_scores += teacher.score(torch.stack(items[i:j])).double().tolist()
            i = j
    e_scores = evaluator.evaluate(items)
    return {"plcc": plcc(t_scores, e_scores), "srcc": srcc(t_scores, e_scores), "n": float(len(items))}
