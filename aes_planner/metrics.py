"""Agreement between two score sequences: PLCC, SRCC, smoothness (numpy only). The one home of
these measures: the field's evaluation and training, the teachers' evaluator and the benchmarks
all call them.

**Constant input.** A correlation with a constant sequence is undefined (scipy returns NaN); here
it is **0.0**: no agreement is measured, and a predictor that says the same for every view earns
nothing. Means over scenes stay finite.
"""

from __future__ import annotations

import numpy as np

from aes_planner.errors import AesPlannerError

__all__ = ["MetricsError", "plcc", "srcc", "tv_ratio"]


class MetricsError(AesPlannerError, ValueError):
    """Two score sequences that cannot be compared (different lengths, fewer than two values)."""


def _pair(a, b, what: str) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    if a.shape != b.shape or a.size < 2:
        raise MetricsError(f"{what} needs two equal-length sequences of >= 2 values, got {a.size} and {b.size}")
    return a, b


def plcc(pred, true) -> float:
    """Pearson's linear correlation; 0.0 when either side is constant (module docstring)."""
    p, t = _pair(pred, true, "plcc")
    p, t = p - p.mean(), t - t.mean()
    den = np.sqrt((p * p).sum() * (t * t).sum())
    return float((p * t).sum() / den) if den > 1e-18 else 0.0


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks with ties averaged (as scipy.stats.rankdata)."""
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x), np.float64)
    ranks[order] = np.arange(len(x), dtype=np.float64)
    _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=ranks)
    return sums[inv] / counts[inv]


def srcc(pred, true) -> float:
    """Spearman's rank correlation (Pearson's of the ranks, ties averaged); 0.0 when either side
    is constant."""
    p, t = _pair(pred, true, "srcc")
    return plcc(_ranks(p), _ranks(t))


def tv_ratio(pred, true) -> float:
    """Total variation of ``pred`` along the sequence over that of ``true`` (1 = as smooth as
    the truth, below 1 = smoother); inf-free: 0 / 0 gives 1."""
    tp = float(np.abs(np.diff(np.asarray(pred, np.float64))).sum())
    tt = float(np.abs(np.diff(np.asarray(true, np.float64))).sum())
    if tt <= 1e-18:
        return 1.0 if tp <= 1e-18 else float("inf")
    return tp / tt
