"""Comparing recovered camera poses with known ones: the similarity (Umeyama) that best maps one
set of camera centres onto another, and the rotation / centre errors left after it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PoseErrors", "pose_errors", "umeyama"]


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale ``s``, rotation ``R [3, 3]`` and translation ``t [3]`` minimising
    ``sum |dst_i - (s R src_i + t)|^2`` (Umeyama 1991) for points ``src, dst [N, 3]``, N >= 3."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two [N, 3] point sets with N >= 3, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0])
    r = u @ d @ vt
    var = (a**2).sum() / len(src)
    s = float(np.trace(np.diag(sig) @ d) / var) if var > 0 else 1.0
    return s, r, mu_d - s * r @ mu_s


@dataclass
class PoseErrors:
    """Per camera: the rotation error (degrees) and the centre error as a fraction of the true
    cameras' spread (their largest distance apart), after the similarity ``scale, rotation, translation``."""

    rotation_deg: np.ndarray  # [N]
    centre_frac: np.ndarray  # [N]
    scale: float
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]
    spread: float

    def to_true(self, cam2world: np.ndarray) -> np.ndarray:
        """A cam2world [4, 4] of the estimated frame mapped into the true frame by the similarity."""
        m = np.array(cam2world, np.float64)
        m[:3, 3] = self.scale * self.rotation @ m[:3, 3] + self.translation
        m[:3, :3] = self.rotation @ m[:3, :3]
        return m

    def to_json(self) -> dict:
        return {
            "rotation_deg_max": float(self.rotation_deg.max()),
            "rotation_deg_median": float(np.median(self.rotation_deg)),
            "centre_pct_of_spread_max": float(100 * self.centre_frac.max()),
            "centre_pct_of_spread_median": float(100 * np.median(self.centre_frac)),
        }


def pose_errors(estimated: np.ndarray, truth: np.ndarray) -> PoseErrors:
    """Errors of cam2world ``estimated [N, 4, 4]`` against ``truth [N, 4, 4]`` (same cameras, same
    order) after the similarity mapping the estimated centres onto the true ones."""
    est, tru = np.asarray(estimated, np.float64), np.asarray(truth, np.float64)
    s, r, t = umeyama(est[:, :3, 3], tru[:, :3, 3])
    centres = (s * (r @ est[:, :3, 3].T)).T + t
    spread = float(np.max(np.linalg.norm(tru[:, None, :3, 3] - tru[None, :, :3, 3], axis=-1)))
    rel = np.einsum("nji,njk->nik", r @ est[:, :3, :3], tru[:, :3, :3])  # [N, 3, 3] (R est)^T truth
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return PoseErrors(
        np.degrees(np.arccos(cos)),
        np.linalg.norm(centres - tru[:, :3, 3], axis=1) / max(spread, 1e-12),
        s,
        r,
        t,
        spread,
    )
