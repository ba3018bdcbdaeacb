"""Exact ray casting of a :class:`~aes_planner.sim.scene.Scene`: RGB, z-depth and instance ids.

Vectorised numpy, float64 inside, independent of any Gaussian code. How a frame is made:

1. **Rays.** One ray per pixel through its centre ``(i + 0.5, j + 0.5)`` (conventions of
   :mod:`aes_planner.geometry`), or ``s x s`` rays per pixel on a regular sub-pixel grid with
   ``supersample = s``. Rays are cast in the camera frame with direction ``(x, y, 1)``, so the
   ray parameter *is* the z-depth, and every object is first moved into the camera frame in
   float64 (scenes 1e5 m from the origin keep millimetre precision).
2. **Visibility.** Each bounded object is projected to a pixel rectangle (its oriented box
   clipped to the near plane, narrowed by its bounding sphere's tangent cone); only rays in
   that rectangle are intersected with it, and objects behind the camera are skipped.
   Objects covering many pixels are intersected one at a time (ray directions broadcast from
   a row and a column); the many small ones in one batch per shape kind. Infinite planes
   test every ray. Hits nearer than :data:`NEAR_M` or farther than :data:`FAR_M` do not count.
3. **Shading.** Lambert: ``colour = albedo * (sum of ambient + sum of directional
   max(0, n . l) * visible + emission)``, clipped to ``[0, 1]``, no gamma. Normals face the
   viewer (surfaces are two-sided; from inside a box or sphere you see its inner walls).
   Shadow rays to each directional light with ``shadows: true`` are cast exactly: the hit
   points are sorted along an axis across the light, so each object only tests the slice of
   points whose parallel shadow rays can reach it (see :func:`_occluded`).
4. **Misses** take the sky gradient colour of their world direction.

**Anti-aliasing.** With ``supersample = s`` the RGB of a pixel is the mean of its ``s x s``
samples. Depth and instance ids are always those of the ray through the pixel centre, exactly
as with ``supersample = 1`` (for odd ``s`` that ray is the centre sample; for even ``s`` it is
cast in addition), so ground truth does not change with anti-aliasing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.geometry import Intrinsics, validate_cam2world
from aes_planner.sim.scene import Scene
from aes_planner.sim.shapes import SHAPES
from aes_planner.sim.spec import AmbientLightSpec, DirectionalLightSpec, SkySpec, frame_from_axis
from aes_planner.sim.texture import sample_image

__all__ = ["FAR_M", "NEAR_M", "RenderError", "RenderOutput", "render"]

NEAR_M = 1e-6  # hits nearer than this (z-depth) are ignored: a camera on a surface sees past it
FAR_M = 1e6  # hits farther than this count as misses (sky): the horizon of an infinite plane
_SHADOW_OFFSET = 1e-6  # shadow rays start this far off the surface, times (1 + depth in metres)
MAX_SUPERSAMPLE = 8


class RenderError(AesPlannerError, ValueError):
    """Render arguments that make no image (bad supersample, wrong scene type)."""


@dataclass(frozen=True)
class RenderOutput:
    """One rendered view.

    * ``rgb``: ``[H, W, 3]`` uint8.
    * ``depth_m``: ``[H, W]`` float32 z-depth in metres, ``0`` where the ray hits nothing.
    * ``instance_id``: ``[H, W]`` int32, ``0`` for sky, ``k`` for ``scene.objects[k - 1]``.
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    instance_id: np.ndarray


_BATCH_BELOW = 2048  # an object with fewer candidate rays than this is intersected in a batch
_SHADE_BATCH_BELOW = 256  # an object with fewer visible samples than this is shaded in a batch
# corners of the unit cube and its 12 edges (pairs of corners one sign apart)
_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if np.abs(_CORNERS[i] - _CORNERS[j]).sum() == 2])


class _Placed:
    """The scene's objects moved into one camera's frame (float64): ``rotations [M, 3, 3]``
    (local -> camera), ``centres [M, 3]`` and the camera origin in each local frame ``[M, 3]``."""

    def __init__(self, scene: Scene, cam2world: np.ndarray):
        self.r_w2c = cam2world[:3, :3].T
        self.rotations = self.r_w2c @ scene.rotations  # [M, 3, 3]
        self.rot9 = self.rotations.reshape(-1, 9)  # row-major: rot[i, j] = rot9[3 i + j]
        self.centres = (scene.centres - cam2world[:3, 3]) @ self.r_w2c.T  # [M, 3]
        self.origins_local = -np.einsum("mji,mj->mi", self.rotations, self.centres)  # [M, 3]

    def to_local(self, obj: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Camera-frame points ``[3, K]`` -> the local frames of objects ``obj [K]``."""
        rot = self.rot9.T.take(obj, axis=1)  # [9, K]
        p = points - self.centres.T.take(obj, axis=1)
        return np.stack([rot[j] * p[0] + rot[3 + j] * p[1] + rot[6 + j] * p[2] for j in range(3)])

    def to_camera(self, obj: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        """Local vectors ``[3, K]`` of objects ``obj [K]`` -> camera frame."""
        rot = self.rot9.T.take(obj, axis=1)
        return np.stack(
            [rot[3 * i] * vectors[0] + rot[3 * i + 1] * vectors[1] + rot[3 * i + 2] * vectors[2] for i in range(3)]
        )


def _ray_grid(intrinsics: Intrinsics, supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """Image-plane coordinates (z = 1) of the sample columns ``[W*s]`` and rows ``[H*s]``."""
    offsets = (np.arange(supersample) + 0.5) / supersample  # the middle one is exactly 0.5 for odd s
    u = (np.arange(intrinsics.width)[:, None] + offsets).ravel()
    v = (np.arange(intrinsics.height)[:, None] + offsets).ravel()
    return (u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy


def _projected_bounds(scene: Scene, placed: _Placed) -> tuple[np.ndarray, ...]:
    """Bounds ``x_lo, x_hi, y_lo, y_hi [M]`` of each bounded object on the image plane (z = 1),
    from its oriented box (``dims`` as half sizes) clipped to ``z >= NEAR_M``, narrowed by the
    exact tangent bounds of its bounding sphere when that lies in front. Empty (lo > hi) when
    nothing is in front; unbounded objects get infinite bounds."""
    corners = placed.centres[:, None, :] + np.einsum(
        "mij,mkj->mki", placed.rotations, _CORNERS[None] * scene.dims[:, None, :]
    )
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]  # [M, 12, 3]
    za, zb = a[..., 2], b[..., 2]
    crosses = (za > NEAR_M) != (zb > NEAR_M)
    f = np.where(crosses, (NEAR_M - za) / np.where(crosses, zb - za, 1.0), 0.0)
    clipped = a + f[..., None] * (b - a)
    clipped[..., 2] = NEAR_M
    points = np.concatenate([corners, clipped], axis=1)  # [M, 20, 3]: the vertices of box & {z >= near}
    valid = np.concatenate([corners[..., 2] > NEAR_M, crosses], axis=1)
    bounds = []
    for axis in (0, 1):
        ratio = points[..., axis] / np.where(valid, points[..., 2], 1.0)
        bounds += [np.where(valid, ratio, np.inf).min(axis=1), np.where(valid, ratio, -np.inf).max(axis=1)]
    x_lo, x_hi, y_lo, y_hi = bounds
    # a sphere in front of the camera: its tangent cone is tighter for round objects
    c, r = placed.centres, scene.bound_radius
    front = np.isfinite(r) & (c[:, 2] > r * (1 + 1e-9) + NEAR_M)
    den = np.where(front, c[:, 2] ** 2 - r**2, 1.0)
    tangent = []
    for lateral in (c[:, 0], c[:, 1]):
        k = np.sqrt(np.maximum(lateral**2 + c[:, 2] ** 2 - r**2, 0.0))
        tangent += [
            np.where(front, (lateral * c[:, 2] - r * k) / den, -np.inf),
            np.where(front, (lateral * c[:, 2] + r * k) / den, np.inf),
        ]
    x_lo, y_lo = np.maximum(x_lo, tangent[0]), np.maximum(y_lo, tangent[2])
    x_hi, y_hi = np.minimum(x_hi, tangent[1]), np.minimum(y_hi, tangent[3])
    unbounded = ~np.isfinite(r)
    x_lo[unbounded] = y_lo[unbounded] = -np.inf
    x_hi[unbounded] = y_hi[unbounded] = np.inf
    margin = lambda v, sign: v + sign * 1e-9 * (1 + np.abs(np.where(np.isfinite(v), v, 0.0)))  # noqa: E731
    return margin(x_lo, -1), margin(x_hi, 1), margin(y_lo, -1), margin(y_hi, 1)


def _cast(scene: Scene, placed: _Placed, xs: np.ndarray, ys: np.ndarray):
    """Nearest hit per ray: z-depth ``[h, w]`` (inf for a miss) and ids ``[h, w]``.

    Each object is tested only on the pixel rectangle of its projected bounds. Objects covering
    many pixels are intersected one by one (ray directions broadcast from a row and a column);
    the many small ones together, one call per shape kind over all (object, pixel) pairs.
    """
    h, w = len(ys), len(xs)
    depth = np.full((h, w), np.inf)
    ids = np.zeros((h, w), np.int32)
    if not len(scene.kind):
        return depth, ids
    x_lo, x_hi, y_lo, y_hi = _projected_bounds(scene, placed)
    c0, c1 = np.searchsorted(xs, x_lo, "left"), np.searchsorted(xs, x_hi, "right")
    r0, r1 = np.searchsorted(ys, y_lo, "left"), np.searchsorted(ys, y_hi, "right")
    area = np.maximum(r1 - r0, 0) * np.maximum(c1 - c0, 0)
    x_row, y_col = xs[None, :], ys[:, None]
    for k in np.nonzero(area >= _BATCH_BELOW)[0]:
        rot = placed.rotations[k]
        x, y = x_row[:, c0[k] : c1[k]], y_col[r0[k] : r1[k]]
        direction = tuple(rot[0, j] * x + (rot[1, j] * y + rot[2, j]) for j in range(3))  # local, [h, w] each
        t = SHAPES[scene.kind[k]].intersect(placed.origins_local[k], direction, NEAR_M, scene.dims[k])
        sub = depth[r0[k] : r1[k], c0[k] : c1[k]]
        closer = t < sub
        np.copyto(sub, t, where=closer)
        np.copyto(ids[r0[k] : r1[k], c0[k] : c1[k]], k + 1, where=closer)

    small = np.nonzero((area > 0) & (area < _BATCH_BELOW))[0]
    if len(small):
        n = area[small]
        obj = np.repeat(small, n)
        j = np.arange(len(obj)) - np.repeat(np.cumsum(n) - n, n)
        width = np.repeat(c1[small] - c0[small], n)
        row = np.repeat(r0[small], n) + j // width
        col = np.repeat(c0[small], n) + j % width
        x, y = xs.take(col), ys.take(row)
        t = np.empty(len(obj))
        for code, sel in _groups(scene.kind.take(obj)):
            o = obj.take(sel)
            rot = placed.rot9.T.take(o, axis=1)
            xo, yo = x.take(sel), y.take(sel)
            d = tuple(rot[j] * xo + rot[3 + j] * yo + rot[6 + j] for j in range(3))
            t[sel] = SHAPES[code].intersect(
                placed.origins_local.T.take(o, axis=1), d, NEAR_M, scene.dims.T.take(o, axis=1)
            )
        pix = row * w + col
        flat_depth, flat_ids = depth.reshape(-1), ids.reshape(-1)
        np.minimum.at(flat_depth, pix, t)
        win = (t == flat_depth.take(pix)) & np.isfinite(t)
        flat_ids[pix[win]] = obj[win] + 1

    far = depth >= FAR_M
    depth[far] = np.inf
    ids[far] = 0
    return depth, ids


def _groups(labels: np.ndarray):
    """``(label, indices)`` for each label present in the small non-negative ints ``labels [K]``."""
    for label in np.nonzero(np.bincount(labels))[0]:
        yield int(label), np.nonzero(labels == label)[0]


def _sort_by(keys: np.ndarray) -> np.ndarray:
    """Stable order of small non-negative integer ``keys`` (radix sort when they fit 16 bits)."""
    if len(keys) and keys.max() < 32768:
        return np.argsort(keys.astype(np.int16), kind="stable")
    return np.argsort(keys, kind="stable")


def _occluded(scene: Scene, placed: _Placed, origins: np.ndarray, toward: np.ndarray) -> np.ndarray:
    """Whether rays from ``origins [3, K]`` along the unit ``toward [3]`` hit anything: ``[K]``.

    The rays are parallel. Project the origins onto a plane across them (axes ``e1, e2``) and
    sort them along ``e1`` (in 32k bins, a radix sort). An object can only block the origins
    whose ``e1`` coordinate lies within its support (its oriented box's half width along
    ``e1``, capped by its bounding radius): a contiguous slice of that order, cut down by its
    support along ``e2`` and by whether it lies ahead along the rays. Objects with many
    candidates go first, one by one, each skipping the rays already blocked; the rest are
    tested together, one batch per shape kind.
    """
    n_rays = origins.shape[1]
    if not n_rays or not len(scene.kind):
        return np.zeros(n_rays, bool)
    basis = frame_from_axis(toward)
    axes = np.stack([basis[:, 0], basis[:, 1], toward])  # [3 (e1, e2, toward), 3]
    a = axes[0] @ origins
    a_min, scale = a.min(), 32000.0 / max(a.max() - a.min(), 1e-12)
    order = _sort_by(((a - a_min) * scale).astype(np.int64))
    sorted_origins = origins.take(order, axis=1)
    a_s, b_s, s_s = axes @ sorted_origins  # [K] each, in sorted order
    bins = ((a_s - a_min) * scale).astype(np.int64)
    blocked = np.zeros(n_rays, bool)  # in sorted order

    c_a, c_b, c_s = axes @ placed.centres.T  # [M] each
    local_axes = np.einsum("xi,mij->mxj", axes, placed.rotations)  # [M, 3 axes, 3 local]
    support = np.minimum(np.einsum("mxj,mj->mx", np.abs(local_axes), scene.dims), scene.bound_radius[:, None])
    support = support * (1 + 1e-9) + 1e-12
    support[~np.isfinite(scene.bound_radius)] = np.inf
    r_a, r_b, r_s = support.T
    lo = np.searchsorted(bins, np.floor(np.clip((c_a - r_a - a_min) * scale, -1, 32001)), "left")
    hi = np.searchsorted(bins, np.floor(np.clip((c_a + r_a - a_min) * scale, -1, 32001)), "right")
    count = hi - lo

    def test_one(k: int) -> None:
        run = slice(lo[k], hi[k])
        near = ~blocked[run] & (np.abs(b_s[run] - c_b[k]) <= r_b[k]) & (s_s[run] <= c_s[k] + r_s[k])
        rot = placed.rotations[k]
        if near.mean() > 0.5:  # most of the run: test it whole rather than gather
            o_local = rot.T @ (sorted_origins[:, run] - placed.centres[k][:, None])
            t = SHAPES[scene.kind[k]].intersect(o_local, toward @ rot, 0.0, scene.dims[k])
            blocked[run] |= near & (t < FAR_M)
            return
        idx = np.nonzero(near)[0] + lo[k]
        o_local = rot.T @ (sorted_origins.take(idx, axis=1) - placed.centres[k][:, None])
        t = SHAPES[scene.kind[k]].intersect(o_local, toward @ rot, 0.0, scene.dims[k])
        blocked[idx[t < FAR_M]] = True

    def test_many(obj: np.ndarray, idx: np.ndarray) -> None:
        near = (
            ~blocked.take(idx)
            & (np.abs(b_s.take(idx) - c_b.take(obj)) <= r_b.take(obj))
            & (s_s.take(idx) <= c_s.take(obj) + r_s.take(obj))
        )
        obj, idx = obj[near], idx[near]
        t = np.empty(len(idx))
        for code, sel in _groups(scene.kind.take(obj)):
            o = obj.take(sel)
            o_local = placed.to_local(o, sorted_origins.take(idx.take(sel), axis=1))
            rot = placed.rot9.T.take(o, axis=1)
            d_local = tuple(rot[j] * toward[0] + rot[3 + j] * toward[1] + rot[6 + j] * toward[2] for j in range(3))
            t[sel] = SHAPES[code].intersect(o_local, d_local, 0.0, scene.dims.T.take(o, axis=1))
        blocked[idx[t < FAR_M]] = True

    big = np.nonzero(count >= _BATCH_BELOW)[0]
    for k in big[np.argsort(-count[big], kind="stable")]:
        test_one(k)
    small = np.nonzero((count > 0) & (count < _BATCH_BELOW))[0]
    if len(small):
        n = count[small]
        test_many(np.repeat(small, n), _ranges(lo[small], hi[small]))
    occluded = np.empty(n_rays, bool)
    occluded[order] = blocked
    return occluded


def _ranges(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The concatenation of ``arange(starts[i], ends[i])`` over ``i``, vectorised."""
    n = np.maximum(ends - starts, 0)
    return np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(starts, n)


def _surfaces(scene: Scene, placed: _Placed, obj: np.ndarray, points: np.ndarray):
    """Normals ``[3, K]`` (camera frame, facing the viewer), albedo ``[3, K]`` and emission
    ``[K]`` of hit ``points [3, K]`` (camera frame) on objects ``obj [K]``, sorted by object.

    Objects with many samples are handled one at a time on their contiguous run; the rest in
    one batch per shape kind.
    """
    counts = np.bincount(obj, minlength=len(scene.kind))
    starts = np.cumsum(counts) - counts
    normal = np.empty_like(points)
    u, v = np.empty(len(obj)), np.empty(len(obj))
    alone = counts >= _SHADE_BATCH_BELOW
    alone[list(scene.textures)] = True
    for k in np.nonzero(alone & (counts > 0))[0]:
        run = slice(starts[k], starts[k] + counts[k])
        rot = placed.rotations[k]
        local = rot.T @ (points[:, run] - placed.centres[k][:, None])
        normal_local, u[run], v[run] = SHAPES[scene.kind[k]].surface(local, scene.dims[k])
        normal[:, run] = rot @ normal_local
    batched = np.nonzero(~alone.take(obj))[0]
    for code, sel in _groups(scene.kind.take(obj.take(batched))):
        sel = batched.take(sel)
        o = obj.take(sel)
        normal_local, u[sel], v[sel] = SHAPES[code].surface(
            placed.to_local(o, points.take(sel, axis=1)), scene.dims.T.take(o, axis=1)
        )
        normal[:, sel] = placed.to_camera(o, normal_local)
    normal *= np.where(np.einsum("ij,ij->j", normal, points) > 0, -1.0, 1.0)

    albedo = scene.materials.colour(obj, u, v)
    for k, image in scene.textures.items():
        run = slice(starts[k], starts[k] + counts[k])
        if counts[k]:
            sc, tc, wrap = SHAPES[scene.kind[k]].image_coords(
                u[run], v[run], scene.objects[k].material.tile_m, scene.dims[k]
            )
            albedo[:, run] = sample_image(image, sc, tc, wrap).T
    return normal, albedo, scene.materials.emission.take(obj)


def _shade(scene: Scene, placed: _Placed, depth, ids, xs, ys) -> tuple[np.ndarray, np.ndarray]:
    """Colours ``[3, K]`` of the hit samples and their flat indices ``[K]`` into the image."""
    index = np.flatnonzero(ids)
    obj = ids.reshape(-1).take(index) - 1
    order = _sort_by(obj)
    index, obj = index.take(order), obj.take(order)
    rows, cols = np.divmod(index, len(xs))
    t = depth.reshape(-1).take(index)
    points = np.stack([xs.take(cols) * t, ys.take(rows) * t, t])  # camera frame [3, K]
    normal, albedo, emission = _surfaces(scene, placed, obj, points)

    light = np.zeros((3, len(index))) + emission
    for spec in scene.lights:
        colour = np.asarray(spec.colour)[:, None] * spec.intensity
        if isinstance(spec, AmbientLightSpec):
            light += colour
        elif isinstance(spec, DirectionalLightSpec):
            toward = -(placed.r_w2c @ np.asarray(spec.direction, dtype=np.float64))
            toward /= np.linalg.norm(toward)
            lambert = np.maximum(toward @ normal, 0.0)
            if spec.shadows:
                lit = np.nonzero(lambert > 0)[0]
                offset = _SHADOW_OFFSET * (1.0 + t.take(lit))
                origins = points.take(lit, axis=1) + normal.take(lit, axis=1) * offset
                lambert[lit[_occluded(scene, placed, origins, toward)]] = 0.0
            light += colour * lambert
    return albedo * light, index


def _sky(sky: SkySpec, cam2world: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sky colours ``[3, K]`` of camera rays ``(x, y, 1)`` ``[K]``: by world elevation, linear
    in the angle from ``horizon`` to ``zenith``; ``nadir`` below the horizon."""
    d = cam2world[:3, :3] @ np.stack([x, y, np.ones_like(x)])  # [3, K]
    sin_elev = d[2] / np.sqrt(np.einsum("ik,ik->k", d, d))
    w = np.arcsin(np.clip(sin_elev, 0.0, 1.0)) / (math.pi / 2)
    horizon, zenith, nadir = (np.asarray(c, dtype=np.float64)[:, None] for c in (sky.horizon, sky.zenith, sky.nadir))
    return np.where(sin_elev < 0, nadir, horizon * (1 - w) + zenith * w)


def render(scene: Scene, cam2world: np.ndarray, intrinsics: Intrinsics, supersample: int = 1) -> RenderOutput:
    """Render ``scene`` from ``cam2world [4, 4]`` (OpenCV camera axes) with ``intrinsics``.

    ``supersample = s`` averages ``s x s`` RGB samples per pixel (1 to 8); depth and ids stay
    those of the pixel-centre ray. Outputs are always finite. See the module docstring.
    """
    if not isinstance(scene, Scene):
        raise RenderError(
            f"render needs a Scene, got {type(scene).__name__}; build one with aes_planner.sim.load_scene()"
        )
    if not isinstance(intrinsics, Intrinsics):
        raise RenderError(f"intrinsics must be an aes_planner.geometry.Intrinsics, got {type(intrinsics).__name__}")
    if (
        isinstance(supersample, bool)
        or not isinstance(supersample, (int, np.integer))
        or not 1 <= supersample <= MAX_SUPERSAMPLE
    ):
        raise RenderError(f"supersample must be an integer in [1, {MAX_SUPERSAMPLE}], got {supersample!r}")
    s = int(supersample)
    cam2world = validate_cam2world(cam2world)
    placed = _Placed(scene, cam2world)
    h, w = intrinsics.height, intrinsics.width
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        xs, ys = _ray_grid(intrinsics, s)
        depth, ids = _cast(scene, placed, xs, ys)
        rgb = np.empty((3, len(ys) * len(xs)))  # channel planes: 1-D scatters are cheap
        colour, index = _shade(scene, placed, depth, ids, xs, ys)
        miss = np.flatnonzero(ids == 0)
        rows, cols = np.divmod(miss, len(xs))
        sky = _sky(scene.sky, cam2world, xs.take(cols), ys.take(rows))
        for c in range(3):
            rgb[c, index] = colour[c]
            rgb[c, miss] = sky[c]
        rgb = rgb.reshape(3, h, s, w, s).mean(axis=(2, 4)) if s > 1 else rgb.reshape(3, h, w)
        if s % 2:
            depth, ids = depth[s // 2 :: s, s // 2 :: s], ids[s // 2 :: s, s // 2 :: s]
        else:
            depth, ids = _cast(scene, placed, *_ray_grid(intrinsics, 1))
    rgb = np.nan_to_num(rgb, nan=0.0, posinf=1.0, neginf=0.0)  # no NaN is ever cast to uint8
    rgb8 = np.ascontiguousarray(np.rint(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8).transpose(1, 2, 0))
    depth32 = np.where(ids > 0, depth, 0.0).astype(np.float32)
    return RenderOutput(rgb=rgb8, depth_m=depth32, instance_id=np.ascontiguousarray(ids, dtype=np.int32))
