"""Agreement between predicted and true scores: PLCC, SRCC, smoothness (numpy only)."""

from __future__ import annotations

import numpy as np

__all__ = ["plcc", "srcc", "tv_ratio"]


def plcc(pred, true) -> float:
    """Pearson's linear correlation; 0 when either side is constant."""
    p, t = np.asarray(pred, np.float64).ravel(), np.asarray(true, np.float64).ravel()
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
    """Spearman's rank correlation (Pearson's of the ranks, ties averaged)."""
    return plcc(_ranks(np.asarray(pred, np.float64).ravel()), _ranks(np.asarray(true, np.float64).ravel()))


def tv_ratio(pred, true) -> float:
    """Total variation of ``pred`` along the sequence over that of ``true`` (1 = as smooth as
    the truth, below 1 = smoother); inf-free: 0 / 0 gives 1."""
    tp = float(np.abs(np.diff(np.asarray(pred, np.float64))).sum())
    tt = float(np.abs(np.diff(np.asarray(true, np.float64))).sum())
    if tt <= 1e-18:
        return 1.0 if tp <= 1e-18 else float("inf")
    return tp / tt
