"""Primitives as the renderer sees them: ray intersection, normals and surface coordinates.

Each primitive lives in its own local frame, placed in the world by a rotation ``[3, 3]``
(local -> world) and a centre ``[3]``, and sized by ``dims [3]``. Every formula here is for the
primitive at the origin in its canonical orientation:

==========  ===============================================  ==========================
kind        local shape                                      ``dims``
==========  ===============================================  ==========================
box         ``|x| <= a, |y| <= b, |z| <= c``                 half sizes ``(a, b, c)``
sphere      ``|p| = r``                                      ``(r, r, r)``
cylinder    ``x^2 + y^2 <= r^2, |z| <= h``, capped, axis z   ``(r, r, h)``
plane       ``z = 0``, normal local z, infinite              ``(0, 0, 0)``
quad        ``x = 0, |y| <= a, |z| <= b``, normal local x    ``(0, a, b)``
==========  ===============================================  ==========================

The functions are static and fully broadcasting, so one call serves one object and an image
of rays (``dims [3]``) or many objects at once with gathered parameters (``dims [3, K]``).
Rays are components ``o = (ox, oy, oz)``, ``d = (dx, dy, dz)`` that broadcast together;
directions need not be unit length (``t`` is in units of ``|d|``). ``intersect`` returns the
smallest ``t > t_min``, or ``inf`` for a miss, never NaN.

Surface coordinates ``(u, v)`` are metres along the surface; patterns and tiled images are
drawn in them (per primitive in ``sim/README.md``).
"""

from __future__ import annotations

import numpy as np

from aes_planner.sim import spec as S

__all__ = ["Box", "Cylinder", "Plane", "Quad", "Shape", "SHAPES", "shape_of"]


def _quadratic_roots(a, b_half, c):
    """Roots of ``a t^2 + 2 b_half t + c = 0`` (numerically stable form): ``(t_small,
    t_large, real)``. Entries without real roots hold garbage; select them out with ``real``."""
    disc = b_half * b_half - a * c
    q = -(b_half + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b_half))
    t1 = q / a
    t2 = c / q
    return np.fmin(t1, t2), np.fmax(t1, t2), disc >= 0.0


def _first_positive(t_small, t_large, ok, t_min):
    """The nearer root beyond ``t_min`` where ``ok``, else inf."""
    t = np.where(t_small > t_min, t_small, t_large)
    return np.where(ok & (t > t_min), t, np.inf)


def _unit_axis(p: np.ndarray, axis: int) -> np.ndarray:
    n = np.zeros_like(p)
    n[axis] = 1.0
    return n


def _sign(x: np.ndarray) -> np.ndarray:
    return np.where(x >= 0, 1.0, -1.0)


class Shape:
    """One primitive kind: static functions over local-frame rays and points."""

    kind = ""
    bounded = True

    @staticmethod
    def bound_radius(dims: np.ndarray) -> float:
        """Radius of a sphere about the local origin that holds the primitive."""
        return float(np.linalg.norm(dims))

    @staticmethod
    def intersect(o, d, t_min: float, dims):
        raise NotImplementedError

    @staticmethod
    def surface(p: np.ndarray, dims: np.ndarray):
        """Local hit points ``[3, K]`` -> outward normals ``[3, K]`` and ``u, v [K]`` (metres)."""
        raise NotImplementedError

    @staticmethod
    def image_coords(u: np.ndarray, v: np.ndarray, tile_m: float | None, dims: np.ndarray):
        """Surface coordinates -> image coordinates ``(s, t)`` in image widths/heights and
        whether the image repeats: upright squares of ``tile_m`` metres (default 1 m)."""
        tile = tile_m or 1.0
        return u / tile, -v / tile, True


class Box(Shape):
    kind = "box"

    @staticmethod
    def intersect(o, d, t_min, dims):
        t_near, t_far = -np.inf, np.inf
        for k in range(3):
            half = dims[k]
            inv = 1.0 / d[k]  # +-inf for a ray parallel to the slab
            t1 = (-half - o[k]) * inv
            t2 = (half - o[k]) * inv  # NaN only on the slab's boundary plane: fmin/fmax skip it
            t_near = np.fmax(t_near, np.fmin(t1, t2))
            t_far = np.fmin(t_far, np.fmax(t1, t2))
        return _first_positive(t_near, t_far, t_far >= t_near, t_min)

    @staticmethod
    def surface(p, dims):
        x, y, z = p
        qx, qy, qz = np.abs(x) / dims[0], np.abs(y) / dims[1], np.abs(z) / dims[2]
        on_x = (qx >= qy) & (qx >= qz)  # the face: where p is deepest into its slab
        on_z = ~on_x & (qz > qy)
        on_y = ~on_x & ~on_z
        sx, sy, sz = _sign(x), _sign(y), _sign(z)
        normal = np.stack([np.where(on_x, sx, 0.0), np.where(on_y, sy, 0.0), np.where(on_z, sz, 0.0)])
        # side faces read upright from outside (u to the viewer's right, v up); top/bottom (x, y)
        u = np.where(on_x, sx * y, np.where(on_y, -sy * x, x))
        v = np.where(on_z, y, z)
        return normal, u, v


class Sphere(Shape):
    kind = "sphere"

    @staticmethod
    def bound_radius(dims):
        return float(dims[0])

    @staticmethod
    def intersect(o, d, t_min, dims):
        r = dims[0]
        a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2]
        c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r
        t_small, t_large, real = _quadratic_roots(a, b, c)
        return _first_positive(t_small, t_large, real, t_min)

    @staticmethod
    def surface(p, dims):
        r = dims[0]
        u = r * np.arctan2(p[1], p[0])
        v = r * np.arcsin(np.clip(p[2] / r, -1.0, 1.0))
        return p / r, u, v


class Cylinder(Shape):
    kind = "cylinder"

    @staticmethod
    def bound_radius(dims):
        return float(np.hypot(dims[0], dims[2]))

    @staticmethod
    def intersect(o, d, t_min, dims):
        r, hh = dims[0], dims[2]
        a = d[0] * d[0] + d[1] * d[1]
        b = o[0] * d[0] + o[1] * d[1]
        c = o[0] * o[0] + o[1] * o[1] - r * r
        t_small, t_large, real = _quadratic_roots(a, b, c)  # a == 0 (along the axis): infinite roots, cut below
        best = np.inf
        for t in (t_small, t_large):
            z = o[2] + t * d[2]
            best = np.fmin(best, np.where(real & (t > t_min) & (np.abs(z) <= hh), t, np.inf))
        inv = 1.0 / d[2]
        for cap in (-hh, hh):
            t = (cap - o[2]) * inv
            x, y = o[0] + t * d[0], o[1] + t * d[1]
            best = np.fmin(best, np.where((t > t_min) & (x * x + y * y <= r * r), t, np.inf))
        return best

    @staticmethod
    def surface(p, dims):
        r, hh = dims[0], dims[2]
        x, y, z = p
        rho = np.hypot(x, y)
        on_cap = np.abs(np.abs(z) - hh) / hh < np.abs(rho - r) / r
        inv_rho = np.where(on_cap | (rho == 0), 0.0, 1.0 / np.where(rho > 0, rho, 1.0))
        normal = np.stack([x * inv_rho, y * inv_rho, np.where(on_cap, _sign(z), 0.0)])
        u = np.where(on_cap, x, r * np.arctan2(y, x))
        v = np.where(on_cap, y, z)
        return normal, u, v


class Plane(Shape):
    kind = "plane"
    bounded = False

    @staticmethod
    def bound_radius(dims):
        return float("inf")

    @staticmethod
    def intersect(o, d, t_min, dims):
        t = -o[2] / d[2]  # +-inf or NaN for rays in or parallel to the plane
        return np.where(t > t_min, t, np.inf)

    @staticmethod
    def surface(p, dims):
        return _unit_axis(p, 2), p[0], p[1]


class Quad(Shape):
    kind = "quad"

    @staticmethod
    def intersect(o, d, t_min, dims):
        t = -o[0] / d[0]
        y, z = o[1] + t * d[1], o[2] + t * d[2]
        return np.where((t > t_min) & (np.abs(y) <= dims[1]) & (np.abs(z) <= dims[2]), t, np.inf)

    @staticmethod
    def surface(p, dims):
        return _unit_axis(p, 0), p[1], p[2]

    @staticmethod
    def image_coords(u, v, tile_m, dims):
        if tile_m is not None:
            return Shape.image_coords(u, v, tile_m, dims)
        # stretched: image column 0 on the viewer's left (local -y), row 0 at the top
        half_w, half_h = dims[1], dims[2]
        return (u + half_w) / (2 * half_w), (half_h - v) / (2 * half_h), False


SHAPES: list[type[Shape]] = [Box, Sphere, Cylinder, Plane, Quad]


def shape_of(obj) -> tuple[type[Shape], np.ndarray, np.ndarray]:
    """The shape kind, local-origin position ``[3]`` (world) and ``dims [3]`` of an object spec."""
    if isinstance(obj, S.BoxSpec):
        return Box, np.asarray(obj.centre_m, dtype=np.float64), 0.5 * np.asarray(obj.size_m, dtype=np.float64)
    if isinstance(obj, S.SphereSpec):
        return Sphere, np.asarray(obj.centre_m, dtype=np.float64), np.full(3, float(obj.radius_m))
    if isinstance(obj, S.CylinderSpec):
        dims = np.array([obj.radius_m, obj.radius_m, 0.5 * obj.height_m], dtype=np.float64)
        return Cylinder, np.asarray(obj.centre_m, dtype=np.float64), dims
    if isinstance(obj, S.PlaneSpec):
        return Plane, np.asarray(obj.point_m, dtype=np.float64), np.zeros(3)
    if isinstance(obj, S.QuadSpec):
        return (
            Quad,
            np.asarray(obj.centre_m, dtype=np.float64),
            np.array([0.0, 0.5 * obj.size_m[0], 0.5 * obj.size_m[1]]),
        )
    raise TypeError(f"not an object spec: {type(obj).__name__}")
