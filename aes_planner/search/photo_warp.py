"""Views scored on the input photos warped into them.

A turn of the camera on the spot maps a photo onto the new view exactly (the homography
``K R K^-1``); a short step nearly so, through the plane at the subject's distance. Where the
photos cover a candidate view, its image made of them is a faithful picture of that view, and
the teacher scores it as it would score the view itself (on the dev scenes of
``docs/results/framing_photo_rank_dev.md`` and ``docs/guides/photos.md`` this ranks nearby views
far better than the field or renders of the reconstruction). A pan-tilt rig turns its camera
about a pivot a few centimetres behind the lens, so for a rig the warp is nearly exact.

:func:`photo_composite` builds one view's image (used by :mod:`aes_planner.photos.refine`);
:func:`warped_photo_scores` scores many views.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from aes_planner.geometry.camera import Intrinsics

__all__ = ["photo_composite", "plane_homography", "warped_photo_scores"]

log = logging.getLogger(__name__)


def plane_homography(k: np.ndarray, src_c2w: np.ndarray, dst_c2w: np.ndarray, normal_w, offset_w) -> np.ndarray | None:
    """Pixel homography ``[3, 3]`` from camera ``src`` to camera ``dst`` induced by the world plane
    ``normal_w . X = offset_w`` (None when the plane is behind ``src``); ``normal_w`` None: the plane
    at infinity (exact for a turn on the spot)."""
    r = dst_c2w[:3, :3].T @ src_c2w[:3, :3]  # [3, 3] src camera -> dst camera
    m = r
    if normal_w is not None:
        n = src_c2w[:3, :3].T @ normal_w  # the plane's normal in src camera axes
        d = float(offset_w - normal_w @ src_c2w[:3, 3])  # its distance from src's centre
        if d <= 1e-9:
            return None
        t = dst_c2w[:3, :3].T @ (src_c2w[:3, 3] - dst_c2w[:3, 3])
        m = r + np.outer(t, n) / d
    return k @ m @ np.linalg.inv(k)


def photo_composite(
    images: list[np.ndarray],
    photos_c2w: np.ndarray,
    k: np.ndarray,
    target_c2w: np.ndarray,
    order: list[int],
    plane: tuple[np.ndarray, float] | None,
    fill: np.ndarray | None = None,
) -> tuple[np.ndarray, float, float]:
    """The image at ``target_c2w [4, 4]`` made of the photos (``images`` [H, W, 3] uint8, all one
    size, camera matrix ``k`` at that size) warped into it through ``plane`` (``(normal_w,
    offset_w)``, None: at infinity), in ``order`` (first wins); the part no photo covers is taken
    from ``fill`` ([H, W, 3] uint8, e.g. a render of the reconstruction) or, without one, filled
    from its surroundings. Returns the image [H, W, 3] uint8, the share the photos covered and the
    share the first photo in ``order`` covered."""
    import cv2

    h, w = images[0].shape[:2]
    out = np.zeros((h, w, 3), np.uint8)
    have = np.zeros((h, w), np.uint8)
    first = 0.0
    ones = np.full((h, w), 255, np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    for j in order:
        hom = plane_homography(k, photos_c2w[j], target_c2w, *(plane if plane is not None else (None, 0.0)))
        if hom is None:
            continue
        # the valid part shrunk by a pixel: bilinear samples at the border mix in the black outside
        valid = cv2.erode(cv2.warpPerspective(ones, hom, (w, h), flags=cv2.INTER_NEAREST), kernel)
        new = cv2.bitwise_and(valid, cv2.bitwise_not(have))  # [h, w] 255 where this photo fills a gap
        n_new = cv2.countNonZero(new)
        if j == order[0]:
            first = n_new / new.size
        if n_new == 0:
            continue
        warped = cv2.warpPerspective(images[j], hom, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        cv2.copyTo(warped, new, out)
        cv2.bitwise_or(have, new, have)
        if cv2.countNonZero(have) == have.size:
            break
    cover = cv2.countNonZero(have) / have.size
    if cover < 1.0 and fill is not None:
        cv2.copyTo(np.ascontiguousarray(fill), cv2.bitwise_not(have), out)
    elif cover < 1.0:
        out = cv2.inpaint(out, cv2.bitwise_not(have), 3, cv2.INPAINT_TELEA)
    return out, cover, first


def warped_photo_scores(
    teacher,
    images: list[np.ndarray],
    photos_c2w: np.ndarray,
    intrinsics: Intrinsics,
    views_c2w: np.ndarray,
    subject_m: np.ndarray | None,
    width_px: int = 160,
    min_cover: float = 0.0,
    batch: int = 32,
    fill=None,
) -> tuple[np.ndarray, np.ndarray]:
    """The teacher's score of each view ``views_c2w [C, 4, 4]`` on the photos (``images`` [H, W, 3]
    uint8, one size, taken at ``photos_c2w [N, 4, 4]`` with ``intrinsics``) warped into it, and the
    share of its image they cover. Each view takes the photo nearest in direction first, the others
    filling the rest, through the plane facing it at ``subject_m [3]`` (None: the plane at
    infinity, exact for turns on the spot). Images are ``width_px`` wide; views covered less than
    ``min_cover`` are not scored (NaN). ``fill`` (optional): a function of views ``[B, 4, 4]`` and
    an image size ``(w, h)`` giving the images ``[B, h, w, 3]`` uint8 that fill what the photos do
    not cover (default: filled from the surroundings). Returns scores [C] and covers [C]."""
    import cv2
    import torch

    views_c2w = np.asarray(views_c2w, np.float64)
    photos_c2w = np.asarray(photos_c2w, np.float64)
    scores = np.full(len(views_c2w), np.nan)
    covers = np.zeros(len(views_c2w))
    if not images or len({im.shape for im in images}) != 1 or not len(views_c2w):
        return scores, covers
    h0, w0 = images[0].shape[:2]
    wh = max(8, round(width_px * h0 / w0))
    small = [cv2.resize(im, (width_px, wh), interpolation=cv2.INTER_AREA) for im in images]  # [wh, width_px, 3]
    k = intrinsics.K.astype(np.float64).copy()
    k[0] *= width_px / intrinsics.width
    k[1] *= wh / intrinsics.height
    fwd = photos_c2w[:, :3, 2]  # [N, 3] optical axes
    shots, idx = [], []

    def flush():
        if not shots:
            return
        x = torch.from_numpy(np.stack(shots)).permute(0, 3, 1, 2).float() / 255.0  # [B, 3, wh, width_px]
        with torch.no_grad():
            scores[idx] = teacher.explain_map(teacher.features(x))["score"].double().numpy()
        shots.clear()
        idx.clear()

    fills = None if fill is None else fill(views_c2w, (width_px, wh))  # [C, wh, width_px, 3]
    for i, c2w in enumerate(views_c2w):
        order = [int(j) for j in np.argsort(-(fwd @ c2w[:3, 2]), kind="stable")]
        plane = None
        if subject_m is not None:
            n = np.asarray(subject_m, np.float64) - c2w[:3, 3]
            if np.linalg.norm(n) > 1e-6:
                n = n / np.linalg.norm(n)
                plane = (n, float(n @ subject_m))
        img, covers[i], _ = photo_composite(
            small, photos_c2w, k, c2w, order, plane, None if fills is None else fills[i]
        )
        if covers[i] >= min_cover:
            shots.append(img)
            idx.append(i)
        if len(shots) >= batch:
            flush()
    flush()
    return scores, covers
