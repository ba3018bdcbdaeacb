"""The ``suggest`` report: input views on top, then one column per suggestion and one row per
renderer (the field's/RGB reconstruction's view, the ground truth for simulator folders)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch

from aes_planner.search.pipeline import SearchResult, Suggestion

__all__ = ["render_with", "suggestion_label", "write_report"]

PAD = 4
LABEL_H = 14


def suggestion_label(i: int, s: Suggestion, score: float | None = None) -> str:
    """``#i pan .. tilt .. s=..``: ``score`` (a row's own score of the view) or else the search's."""
    if s.pan_rad is not None:
        where = f"pan {math.degrees(s.pan_rad):.0f} tilt {math.degrees(s.tilt_rad):.0f}"
    else:
        where = f"yaw {math.degrees(s.yaw_rad):.0f} pitch {math.degrees(s.pitch_rad):.0f}"
    return f"#{i + 1} {where} s={s.score if score is None else score:.2f}"


def render_with(scorer) -> Callable[[np.ndarray], np.ndarray] | None:
    """A function poses ``[B, 4, 4]`` -> RGB ``[B, H, W, 3]`` uint8 from a scorer's ``render`` (RGB,
    as ``RGBScorer.render``) or, failing that, its ``render_maps`` (the field's rendered teacher
    feature map, first three channels in false colour); ``None`` when it has neither."""
    render = getattr(scorer, "render", None)
    maps = getattr(scorer, "render_maps", None)
    if render is None and maps is not None:

        def false_colour(poses: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                fmap = maps(torch.as_tensor(poses, dtype=torch.float64))[0][:, :3].float()  # [B, <=3, h, w]
            if fmap.shape[1] < 3:
                fmap = torch.cat([fmap, fmap[:, -1:].expand(-1, 3 - fmap.shape[1], -1, -1)], 1)
            lo = fmap.amin(dim=(2, 3), keepdim=True)
            hi = fmap.amax(dim=(2, 3), keepdim=True)
            norm = (fmap - lo) / (hi - lo).clamp_min(1e-6)
            return (norm.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)

        return false_colour
    if render is None:
        return None

    def fn(poses: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            out = render(torch.as_tensor(poses, dtype=torch.float64))
        rgb = out[0] if isinstance(out, tuple) else out
        if not isinstance(rgb, torch.Tensor) or rgb.dim() != 4 or rgb.shape[1] != 3:
            raise TypeError("not an RGB render")
        return (rgb.permute(0, 2, 3, 1).clamp(0, 1).numpy() * 255).round().astype(np.uint8)

    return fn


def _tile(image: np.ndarray, size: tuple[int, int], label: str) -> np.ndarray:  # RGB uint8 -> BGR tile
    w, h = size
    img = cv2.resize(image, (w, h), interpolation=cv2.INTER_NEAREST if image.shape[1] < w else cv2.INTER_AREA)
    tile = np.full((h + LABEL_H, w, 3), 255, np.uint8)
    tile[LABEL_H:] = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    cv2.putText(tile, label[: max(4, w // 6)], (2, LABEL_H - 3), cv2.FONT_HERSHEY_PLAIN, 0.8, (0, 0, 0), 1, cv2.LINE_AA)
    return tile


#: Outline colours (RGB): the kept subject green, an avoided region red.
COLOURS = {"keep": (40, 200, 60), "avoid": (220, 40, 40)}
#: The 12 edges of a box whose corners are numbered as :attr:`Subject.corners_m` (bit 2: x, 1: y, 0: z).
BOX_EDGES = [(a, a | b) for a in range(8) for b in (1, 2, 4) if not a & b]


def _outline_box(image: np.ndarray, box, colour) -> np.ndarray:  # [H, W, 3] uint8 -> a copy, outlined
    out = np.ascontiguousarray(image).copy()
    t = max(1, round(max(out.shape[:2]) / 160))
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    cv2.rectangle(out, (x0, y0), (max(x0, x1 - 1), max(y0, y1 - 1)), colour, t, cv2.LINE_AA)
    return out


def _outline_subjects(image: np.ndarray, framing, cam2world: np.ndarray) -> np.ndarray:
    """``image`` of the view at ``cam2world`` with the kept subjects' (and avoided regions') 3D
    boxes drawn as wireframes, projected with the framing's camera (scaled to the image)."""
    from aes_planner.search.framing import NEAR_M, project_corners

    out = np.ascontiguousarray(image).copy()
    h, w = out.shape[:2]
    t = max(1, round(max(h, w) / 160))
    pose = torch.as_tensor(np.asarray(cam2world, dtype=np.float64)[None])
    for kind, subjects in (("keep", framing.keep), ("avoid", framing.avoid)):
        for s in subjects:
            corners = torch.as_tensor(s.corners_m[None])  # [1, 8, 3]
            u, v, z = (a[0, 0].numpy() for a in project_corners(corners, pose, framing.intrinsics))
            px = np.stack([u * w, v * h], -1)
            for a, b in BOX_EDGES:
                if z[a] > NEAR_M and z[b] > NEAR_M and np.isfinite(px[[a, b]]).all():
                    pa = tuple(int(round(c)) for c in np.clip(px[a], -4 * w, 5 * w))
                    pb = tuple(int(round(c)) for c in np.clip(px[b], -4 * w, 5 * w))
                    cv2.line(out, pa, pb, COLOURS[kind], t, cv2.LINE_AA)
    return out


def _row(tiles: list[np.ndarray], width: int) -> np.ndarray:
    row = np.hstack([np.pad(t, ((PAD, PAD), (PAD, PAD), (0, 0)), constant_values=255) for t in tiles])
    if row.shape[1] < width:
        row = np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0)), constant_values=255)
    return row


def write_report(
    path: str | Path,
    input_images: Sequence[np.ndarray],
    result: SearchResult,
    renderers: dict[str, Callable[[np.ndarray], np.ndarray]],
    tile_width: int = 192,
    scores: dict[str, Sequence[float]] | None = None,
    outlines: dict | None = None,
    labels: dict[str, Sequence[str]] | None = None,
) -> Path:
    """Write the report PNG; ``renderers`` maps a row name to poses -> ``[B, H, W, 3]`` uint8;
    ``scores`` a row name to that row's own score of each suggestion (e.g. the teacher's on the
    ground truth), shown in its labels instead of the search's score. ``outlines``
    (``suggest --keep/--avoid``): ``input_boxes`` [(input index, "keep"|"avoid", (x0, y0, x1, y1)
    in that image's pixels)] drawn on the inputs, and ``framing`` (a
    :class:`~aes_planner.search.framing.Framing`) whose subjects' 3D boxes are drawn on every
    suggested view (keep green, avoid red). ``labels``: a row name to its tiles' own labels, for a row
    that does not show the suggested views themselves (``suggest`` on photos: the photo each
    suggestion is said from); such a row gets no subject outlines."""
    scores = scores or {}
    labels = labels or {}
    outlines = outlines or {}
    input_images = list(input_images)
    for i, kind, box in outlines.get("input_boxes", []):
        input_images[i] = _outline_box(input_images[i], box, COLOURS[kind])
    h0, w0 = input_images[0].shape[:2]
    size = (tile_width, max(8, int(round(tile_width * h0 / w0))))
    poses = np.stack([s.cam2world for s in result.suggestions])
    rows = [[_tile(img, size, f"input {i + 1}") for i, img in enumerate(input_images)]]
    for name, fn in renderers.items():
        try:
            images = fn(poses)
        except (TypeError, ValueError, RuntimeError):
            continue
        if name in labels:
            rows.append([_tile(img, size, f"{name}: {text}") for img, text in zip(images, labels[name])])
            continue
        if outlines.get("framing") is not None:
            images = [
                _outline_subjects(img, outlines["framing"], s.cam2world) for img, s in zip(images, result.suggestions)
            ]
        rows.append(
            [
                _tile(img, size, f"{name} {suggestion_label(i, s, scores[name][i] if name in scores else None)}")
                for i, (img, s) in enumerate(zip(images, result.suggestions))
            ]
        )
    width = max(len(r) for r in rows) * (size[0] + 2 * PAD)
    sheet = np.vstack([_row(r, width) for r in rows])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from aes_planner.images import write_image

    return write_image(path, sheet, "the report")
