"""Surface splats: one flat Gaussian per pixel block of a depth map, and the record they live in.

Construction (one frame, a z-depth map ``D`` in its camera):

1. Unproject every pixel centre: ``P = D * K^-1 [u + 0.5, v + 0.5, 1]`` (camera frame).
2. Find depth edges in inverse depth ``q = 1 / D``: a plane has a constant step in ``q`` from
   pixel to pixel, so a step is an *edge* when it exceeds ``edge_rel * q`` and ``edge_ratio``
   times the smaller of the steps beside it. Slanted floors stay continuous; an object in front of
   a wall does not get a "rubber sheet" to it.
3. Tangents ``a = dP/du``, ``b = dP/dv`` by central differences that never cross an edge
   (one-sided at edges, a fronto-parallel fallback for isolated pixels); the normal is
   ``a x b`` turned towards the camera.
4. One splat per ``stride x stride`` block, at the block's centre pixel: its covariance is
   ``(scale_factor * stride)^2 (a a^T + b b^T)`` in the surface plane plus a thin
   ``flatness`` part along the normal, so on screen it covers its block whatever the slant;
   its colour is the mean of the block's pixels that lie on the same surface.
5. Bookkeeping for merging: ``footprint_m`` (square root of the block's area on the surface),
   ``score = confidence / footprint_m`` (how well it was observed), ``samples = 1`` and the
   block's place in the frame's quadtree (``level = 0``, ``block = (row, column)``).

:class:`SplatSet` holds splats as numpy arrays (struct of arrays, means in the local frame) and
becomes a :class:`~aes_planner.gaussians.Gaussians` with :meth:`SplatSet.to_gaussians`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np
import torch

from aes_planner.gaussians import Gaussians
from aes_planner.gaussians.numerics import BLUR_PX2
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import matrix_to_quat

__all__ = [
    "SplatParams",
    "SplatSet",
    "depth_edges",
    "fill_inverse_depth",
    "ray_sphere_depth",
    "sharpen_colors",
    "splats_from_depth",
]

_TINY = 1e-12
MIN_SIGMA_PX = 0.2  # a splat never shrinks below this on screen in its own view


# Rows per torch call in rotations_to_quats: the conversion's [rows, 4, 4] candidates stay under
# torch's parallel grain (32768 elements), so it never wakes torch's OpenMP pool, whose threads
# then spin beside the other work (12k rotations, load ~10: 12.7 ms CPU in one call, 3.3 ms in
# chunks, bit-identical; docs/benchmarks.md, "perf-2, fourth round").
QUAT_CHUNK_ROWS = 2048


def rotations_to_quats(rotations: np.ndarray) -> np.ndarray:  # [M, 3, 3] float64 -> [M, 4] float32
    """:func:`~aes_planner.geometry.poses.matrix_to_quat` in chunks of ``QUAT_CHUNK_ROWS``."""
    parts = [matrix_to_quat(rotations[i : i + QUAT_CHUNK_ROWS]) for i in range(0, len(rotations), QUAT_CHUNK_ROWS)]
    return (np.concatenate(parts) if parts else np.zeros((0, 4))).astype(np.float32)


@dataclass
class SplatSet:
    """Splats as numpy arrays (``M`` rows), means in the reconstruction's local frame."""

    means: np.ndarray  # [M, 3] float32, metres
    quats: np.ndarray  # [M, 4] float32, wxyz
    log_scales: np.ndarray  # [M, 3] float32
    opacities: np.ndarray  # [M] float32 in [0, 1]
    colors: np.ndarray  # [M, 3] float32 in [0, 1]
    normals: np.ndarray  # [M, 3] float32, unit, towards the observing camera
    footprint_m: np.ndarray  # [M] float32, sqrt of the surface area the splat stands for
    score: np.ndarray  # [M] float32, confidence / footprint: larger = better observed
    samples: np.ndarray  # [M] float32, stride blocks it stands for (1 when built, summed when merged)
    source_frame: np.ndarray  # [M] int32
    source_pixel: np.ndarray  # [M, 2] int32, (column, row)
    level: np.ndarray  # [M] int16, quadtree level: the splat stands for 2^level x 2^level stride blocks
    block: np.ndarray  # [M, 2] int32, (row, column) of its block at that level in its frame
    stride: np.ndarray  # [M] int16, pixels per level-0 block in its frame
    edge_px: np.ndarray  # [M] float32, distance (pixels of its frame) to the nearest depth edge or hole
    border_px: np.ndarray  # [M] float32, distance (pixels) from its centre to its frame's border

    @classmethod
    def empty(cls) -> SplatSet:
        f = lambda *s: np.zeros(s, np.float32)  # noqa: E731
        i = lambda *s: np.zeros(s, np.int32)  # noqa: E731
        return cls(
            f(0, 3),
            f(0, 4),
            f(0, 3),
            f(0),
            f(0, 3),
            f(0, 3),
            f(0),
            f(0),
            f(0),
            i(0),
            i(0, 2),
            np.zeros(0, np.int16),
            i(0, 2),
            np.zeros(0, np.int16),
            f(0),
            f(0),
        )

    def __len__(self) -> int:
        return self.means.shape[0]

    def select(self, index: np.ndarray) -> SplatSet:
        """Rows by boolean mask ``[M]`` or integer indices."""
        return SplatSet(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    @staticmethod
    def cat(parts: list[SplatSet]) -> SplatSet:
        parts = [p for p in parts if len(p)]
        if not parts:
            return SplatSet.empty()
        if len(parts) == 1:
            return parts[0]
        return SplatSet(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(SplatSet)})

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, f.name).nbytes for f in fields(self))

    def to_gaussians(self, device: str | torch.device = "cpu") -> Gaussians:
        """The rasterizer's container (no feature channels: the aesthetic field adds them)."""
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
        return Gaussians(
            means=t(self.means),
            quats=t(self.quats),
            log_scales=t(self.log_scales),
            opacities=t(self.opacities),
            colors=t(self.colors),
            features=None,
            source_frame=t(self.source_frame),
            source_pixel=t(self.source_pixel),
        )


@dataclass(frozen=True)
class SplatParams:
    """The per-frame construction knobs: a view of
    :class:`~aes_planner.reconstruct.ReconstructConfig` (no defaults of its own; build it with
    :meth:`from_config`)."""

    stride: int
    scale_factor: float
    flatness: float
    max_stretch: float
    opacity: float
    edge_rel: float
    edge_ratio: float

    @classmethod
    def from_config(cls, config, stride: int) -> SplatParams:
        """The knobs of ``config`` (a ``ReconstructConfig``) for blocks of ``stride`` pixels."""
        return cls(
            stride=stride,
            scale_factor=config.scale_factor,
            flatness=config.flatness,
            max_stretch=config.max_stretch,
            opacity=config.opacity,
            edge_rel=config.edge_rel,
            edge_ratio=config.edge_ratio,
        )


def ray_sphere_depth(
    intrinsics: Intrinsics,
    cam2world: np.ndarray,  # [4, 4] float64, local frame
    centre_m: np.ndarray,  # [3] sphere centre, local frame
    radius_m: float,
) -> np.ndarray:
    """Z-depth ``[H, W]`` (float64) at which each pixel's ray meets the sphere; 0 where it never
    does (a camera outside the sphere looking away from it)."""
    rays_cam = intrinsics.pixel_directions()  # [H, W, 3], z = 1
    norm = np.linalg.norm(rays_cam, axis=-1)
    d = (rays_cam / norm[..., None]) @ cam2world[:3, :3].T  # unit, world
    oc = cam2world[:3, 3] - np.asarray(centre_m, np.float64)
    b = d @ oc
    c = float(oc @ oc) - radius_m**2
    disc = b * b - c
    t = -b + np.sqrt(np.maximum(disc, 0.0))  # the far root: from inside, the only positive one
    ok = (disc >= 0) & (t > 0)
    return np.where(ok, t / norm, 0.0)


def depth_edges(depth_m: np.ndarray, edge_rel: float, edge_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth discontinuities between neighbouring pixels of ``depth_m [H, W]`` (0 = unknown).

    Returns ``(cut_h [H, W-1], cut_v [H-1, W])``: True where the pair ``(x, x+1)`` (or
    ``(y, y+1)``) must not be joined (an edge or an unknown pixel).
    """
    d = np.asarray(depth_m, np.float64)
    valid = d > 0
    q = np.where(valid, 1.0 / np.where(valid, d, 1.0), 0.0)

    def along(qa: np.ndarray, va: np.ndarray) -> np.ndarray:  # steps along the last axis
        step = qa[..., 1:] - qa[..., :-1]  # [..., W-1]
        ok = va[..., 1:] & va[..., :-1]
        mag = np.where(ok, np.abs(step), np.inf)
        left = np.concatenate([np.full(mag.shape[:-1] + (1,), np.inf), mag[..., :-1]], -1)
        right = np.concatenate([mag[..., 1:], np.full(mag.shape[:-1] + (1,), np.inf)], -1)
        beside = np.minimum(left, right)
        scale = np.maximum(qa[..., 1:], qa[..., :-1])
        big = np.abs(step) > edge_rel * scale
        isolated = ~np.isfinite(beside) | (np.abs(step) > edge_ratio * beside)
        return ~ok | (big & isolated)

    return along(q, valid), along(q.T, valid.T).T


def _edge_distance(cut_h: np.ndarray, cut_v: np.ndarray) -> np.ndarray:
    """Distance (pixels, float32 ``[H, W]``) from each pixel to the nearest pixel on either side
    of a cut (a depth edge or an unknown neighbour); large everywhere when there is none."""
    h, w = cut_h.shape[0], cut_v.shape[1]
    on_edge = np.zeros((h, w), bool)
    on_edge[:, 1:] |= cut_h
    on_edge[:, :-1] |= cut_h
    on_edge[1:] |= cut_v
    on_edge[:-1] |= cut_v
    if not on_edge.any():
        return np.full((h, w), float(h + w), np.float32)
    return cv2.distanceTransform((~on_edge).astype(np.uint8), cv2.DIST_L2, 3).astype(np.float32)


def _tangent(
    p: np.ndarray, cut: np.ndarray, axis: int, rr: np.ndarray, cc: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:  # [H, W, 3], [H, W-1] or [H-1, W], [M], [M] -> [M, 3], [M]
    """Derivative of the point map ``p [H, W, 3]`` along ``axis`` (1 = u, 0 = v) at the pixels
    ``(rr, cc)``, central where both sides are joined, one-sided where one is; ``ok`` False where
    neither. Only the block centres use it: computed there, not over the whole image."""
    h, w = p.shape[:2]
    step = (0, 1) if axis == 1 else (1, 0)
    last = (w if axis == 1 else h) - 1
    pos = cc if axis == 1 else rr
    has_f, has_b = pos < last, pos > 0
    # the neighbour's index clipped into the image; a clipped side is not joined
    rf, cf = np.minimum(rr + step[0], h - 1), np.minimum(cc + step[1], w - 1)
    rb, cb = np.maximum(rr - step[0], 0), np.maximum(cc - step[1], 0)
    here = p[rr, cc]
    fwd = np.where(has_f[:, None], p[rf, cf] - here, 0.0)
    bwd = np.where(has_b[:, None], here - p[rb, cb], 0.0)
    if cut.size:
        joined_f = has_f & ~cut[np.minimum(rr, cut.shape[0] - 1), np.minimum(cc, cut.shape[1] - 1)]
        joined_b = has_b & ~cut[rb, cb]
    else:  # one pixel across this axis: no neighbours
        joined_f = joined_b = np.zeros(rr.shape, bool)
    both = joined_f & joined_b
    out = np.where(both[:, None], 0.5 * (fwd + bwd), np.where(joined_f[:, None], fwd, bwd))
    return out, joined_f | joined_b


def _block_view(a: np.ndarray, s: int, hb: int, wb: int) -> np.ndarray:
    """``a [H, W, ...]`` cropped to ``hb*s x wb*s`` -> ``[hb, wb, s*s, ...]``."""
    a = a[: hb * s, : wb * s]
    rest = a.shape[2:]
    a = a.reshape(hb, s, wb, s, *rest)
    a = np.moveaxis(a, 2, 1)  # [hb, wb, s, s, ...]
    return a.reshape(hb, wb, s * s, *rest)


def splats_from_depth(
    image: np.ndarray,  # [H, W, 3] uint8 RGB
    depth_m: np.ndarray,  # [H, W] z-depth, 0 = unknown
    intrinsics: Intrinsics,
    cam2world: np.ndarray,  # [4, 4] float64, local frame
    params: SplatParams,
    frame_index: int,
    confidence: np.ndarray | None = None,  # [H, W] in [0, 1]; None = 1 everywhere
) -> SplatSet:
    """Splats for one frame (construction in the module docstring)."""
    h, w = depth_m.shape
    s = max(1, min(params.stride, h, w))
    hb, wb = h // s, w // s
    d = np.asarray(depth_m, np.float64)
    valid = d > 0
    if hb == 0 or wb == 0 or not valid.any():
        return SplatSet.empty()
    conf = np.ones((h, w)) if confidence is None else np.clip(np.asarray(confidence, np.float64), 0.0, 1.0)

    rays = intrinsics.pixel_directions()  # [H, W, 3]
    p = rays * d[..., None]  # [H, W, 3] camera frame
    cut_h, cut_v = depth_edges(d, params.edge_rel, params.edge_ratio)
    edge_dist = _edge_distance(cut_h, cut_v)
    # the block-centre pixel of every stride block
    rows = np.arange(hb) * s + s // 2
    cols = np.arange(wb) * s + s // 2
    rr, cc = np.meshgrid(rows, cols, indexing="ij")  # [hb, wb]
    keep = valid[rr, cc] & (conf[rr, cc] > 0)
    rr, cc = rr[keep], cc[keep]
    if rr.size == 0:
        return SplatSet.empty()
    pc, dc = p[rr, cc], d[rr, cc]  # [M, 3], [M]
    ac, ok_a = _tangent(p, cut_h, 1, rr, cc)  # [M, 3], [M]
    bc, ok_b = _tangent(p, cut_v, 0, rr, cc)
    # fronto-parallel fallback where a pixel has no joined neighbour along an axis
    zero = np.zeros_like(dc)
    ac = np.where(ok_a[:, None], ac, np.stack([dc / intrinsics.fx, zero, zero], -1))
    bc = np.where(ok_b[:, None], bc, np.stack([zero, dc / intrinsics.fy, zero], -1))

    # colour: mean of the block's pixels on the same surface as the centre (plane prediction)
    img = image.astype(np.float64) / 255.0
    if s == 1:
        color = img[rr, cc]
    else:
        bi, bj = rr // s, cc // s
        blk_d = _block_view(d, s, hb, wb)[bi, bj]  # [M, s*s]
        blk_c = _block_view(img, s, hb, wb)[bi, bj]  # [M, s*s, 3]
        off = np.arange(s) - s // 2
        dv, du = np.meshgrid(off, off, indexing="ij")
        du, dv = du.reshape(-1), dv.reshape(-1)
        # z of the tangent plane through the centre at each block pixel (first order)
        z_pred = dc[:, None] + du[None] * ac[:, None, 2] + dv[None] * bc[:, None, 2]
        same = (blk_d > 0) & (np.abs(blk_d - z_pred) <= 2 * params.edge_rel * dc[:, None] * max(1, s // 2))
        wsum = same.sum(1, keepdims=True)
        color = np.where(wsum > 0, (blk_c * same[..., None]).sum(1) / np.maximum(wsum, 1), img[rr, cc])

    # clamp grazing elongation to max_stretch blocks
    fp = dc / np.sqrt(intrinsics.fx * intrinsics.fy)  # [M] fronto footprint of one pixel
    for t in (ac, bc):
        n_t = np.linalg.norm(t, axis=1)
        t *= (np.minimum(n_t, params.max_stretch * fp) / np.maximum(n_t, _TINY))[:, None]
    normal = np.cross(ac, bc)
    area = np.linalg.norm(normal, axis=1)
    normal = normal / np.maximum(area, _TINY)[:, None]
    normal *= np.where((normal * pc).sum(1) > 0, -1.0, 1.0)[:, None]  # towards the camera

    # in-plane 2x2 covariance in a tangent basis, diagonalised in closed form
    t1 = ac / np.maximum(np.linalg.norm(ac, axis=1), _TINY)[:, None]
    t1 = t1 - (t1 * normal).sum(1, keepdims=True) * normal
    t1 /= np.maximum(np.linalg.norm(t1, axis=1), _TINY)[:, None]
    t2 = np.cross(normal, t1)
    m = np.stack([(ac * t1).sum(1), (bc * t1).sum(1), (ac * t2).sum(1), (bc * t2).sum(1)], 1)  # rows of A
    cp = m[:, 0] ** 2 + m[:, 1] ** 2
    cq = m[:, 2] ** 2 + m[:, 3] ** 2
    cr = m[:, 0] * m[:, 2] + m[:, 1] * m[:, 3]
    theta = 0.5 * np.arctan2(2 * cr, cp - cq)
    half = np.sqrt(((cp - cq) / 2) ** 2 + cr**2)
    lam1 = np.maximum((cp + cq) / 2 + half, _TINY)
    lam2 = np.maximum((cp + cq) / 2 - half, 1e-4 * lam1)
    cos, sin = np.cos(theta)[:, None], np.sin(theta)[:, None]
    e1 = cos * t1 + sin * t2
    e2 = -sin * t1 + cos * t2
    # on screen: scale_factor * stride pixels in all, of which the rasterizer adds BLUR_PX2
    k = np.sqrt(max((params.scale_factor * s) ** 2 - BLUR_PX2, MIN_SIGMA_PX**2))
    sig1, sig2 = k * np.sqrt(lam1), k * np.sqrt(lam2)
    sig3 = params.flatness * sig2
    rot_cam = np.stack([e1, e2, normal], axis=-1)  # [M, 3, 3] columns
    r_c2w = np.asarray(cam2world[:3, :3], np.float64)
    rot_world = r_c2w @ rot_cam
    means = pc @ r_c2w.T + cam2world[:3, 3]

    footprint = s * np.sqrt(np.maximum(area, _TINY))
    cc_conf = conf[rr, cc]
    return SplatSet(
        means=means.astype(np.float32),
        quats=rotations_to_quats(rot_world),
        log_scales=np.log(np.stack([sig1, sig2, sig3], 1)).astype(np.float32),
        opacities=np.full(rr.size, params.opacity, np.float32),
        colors=color.astype(np.float32),
        normals=(normal @ r_c2w.T).astype(np.float32),
        footprint_m=footprint.astype(np.float32),
        score=(cc_conf / footprint).astype(np.float32),
        samples=np.ones(rr.size, np.float32),
        source_frame=np.full(rr.size, frame_index, np.int32),
        source_pixel=np.stack([cc, rr], 1).astype(np.int32),
        level=np.zeros(rr.size, np.int16),
        block=np.stack([rr // s, cc // s], 1).astype(np.int32),
        stride=np.full(rr.size, s, np.int16),
        edge_px=edge_dist[rr, cc],
        border_px=np.minimum(np.minimum(rr, h - 1 - rr), np.minimum(cc, w - 1 - cc)).astype(np.float32) + 0.5,
    )


def sharpen_colors(
    splats: SplatSet,
    image: np.ndarray,  # [H, W, 3] uint8, the frame the splats came from
    intrinsics: Intrinsics,
    cam2world: np.ndarray,  # [4, 4] float64, local frame
    stride: int,
    iterations: int,
) -> SplatSet:
    """Correct splat colours so that rendering them at their own view gives back ``image``.

    Overlapping splats blend their neighbours in (the rasterizer's 0.3 px^2 blur alone spreads
    each splat over ~1.1 px): a few Van Cittert steps ``c += block_mean(image - render)`` undo
    most of that blur. Each step is one forward render of the frame's own splats.
    """
    if iterations <= 0 or len(splats) == 0:
        return splats
    from aes_planner.gaussians import rasterize

    h, w = image.shape[:2]
    s = max(1, min(stride, h, w))
    hb, wb = h // s, w // s
    target = image.astype(np.float32) / 255.0
    w2c = torch.from_numpy(np.linalg.inv(cam2world))
    k = torch.from_numpy(intrinsics.K)
    bi = splats.source_pixel[:, 1] // s
    bj = splats.source_pixel[:, 0] // s
    colors = splats.colors.copy()
    for _ in range(iterations):
        g = SplatSet(**{**splats.__dict__, "colors": colors}).to_gaussians()
        out = rasterize(g, w2c, k, w, h, validate=False)
        rendered = out.rgb[0].permute(1, 2, 0).numpy()
        resid = _block_view(target - rendered, s, hb, wb).mean(axis=2)  # [hb, wb, 3]
        colors = colors + resid[bi, bj]
    return SplatSet(**{**splats.__dict__, "colors": colors.astype(np.float32)})


def fill_inverse_depth(depth_m: np.ndarray) -> np.ndarray:  # [H, W], 0 = unknown
    """Fill unknown pixels by push-pull interpolation of inverse depth (a smooth membrane over
    the holes, planar where the known border is); all-unknown stays all zero."""
    d = np.asarray(depth_m, np.float64)
    known = d > 0
    if known.all() or not known.any():
        return d.copy()
    q = np.where(known, 1.0 / np.where(known, d, 1.0), 0.0)
    levels = [(q, known.astype(np.float64))]
    while min(levels[-1][0].shape) > 1:
        qv, wv = levels[-1]
        h, w = qv.shape
        h2, w2 = (h + 1) // 2, (w + 1) // 2
        pad = ((0, 2 * h2 - h), (0, 2 * w2 - w))
        qs = np.pad(qv * wv, pad).reshape(h2, 2, w2, 2).sum((1, 3))
        ws = np.pad(wv, pad).reshape(h2, 2, w2, 2).sum((1, 3))
        levels.append((np.where(ws > 0, qs / np.maximum(ws, 1e-12), 0.0), np.minimum(ws, 1.0)))
    filled = levels[-1][0]
    for qv, wv in reversed(levels[:-1]):
        h, w = qv.shape
        up = np.repeat(np.repeat(filled, 2, 0), 2, 1)[:h, :w]
        filled = wv * qv + (1 - wv) * up
    out = np.where(known, d, 1.0 / np.maximum(filled, 1e-9))
    return np.where(filled > 0, out, 0.0)
