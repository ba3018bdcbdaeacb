"""Surface colour: procedural patterns and image textures, evaluated at surface coordinates.

Everything is deterministic and vectorised over hit points: surface coordinates ``u, v [K]``
in metres (from :mod:`aes_planner.sim.shapes`) and per-point material parameters in, colours
``[K, 3]`` in ``[0, 1]`` out. :class:`MaterialTable` holds the parameters of all of a scene's
materials as arrays, so one call colours the hits of every object with the same pattern kind.
Value noise hashes its integer lattice with a fixed 64-bit mix, so a seed gives the same
texture on every machine.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from aes_planner.config import ConfigError
from aes_planner.images import ImageError, imread_bounded
from aes_planner.sim.spec import PATTERN_KINDS, MaterialSpec

__all__ = ["MaterialTable", "load_image", "pattern_weight", "sample_image", "value_noise"]

_MASK64 = (1 << 64) - 1
NO_PATTERN = -1


def _hash01(i: np.ndarray, salt: int) -> np.ndarray:
    """Uniform numbers in ``[0, 1)`` from integers ``i [K]`` and a ``salt``: splitmix64, so
    every input bit reaches every output bit, the same on every machine."""
    h = i.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15) ^ np.uint64(salt & _MASK64)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


_LATTICE = 256  # the noise repeats every 256 lattice cells


@functools.lru_cache(maxsize=256)
def _lattice_tables(seed: int, octave: int) -> tuple[np.ndarray, np.ndarray]:
    """A permutation of ``0..255`` and 256 lattice values for one seed and octave (Perlin's
    scheme: value at ``(ix, iy)`` is ``values[perm[(perm[ix] + iy) % 256]]``)."""
    salt = (seed * 0x165667B19E3779F9 + (octave + 1) * 0x27D4EB2F165667C5) & _MASK64
    cells = np.arange(_LATTICE)
    perm = np.argsort(_hash01(cells, salt), kind="stable")
    return perm, _hash01(cells, salt ^ 0x5BD1E995)


def value_noise(x: np.ndarray, y: np.ndarray, octaves, seed) -> np.ndarray:
    """Smooth value noise in ``[0, 1]`` at ``x, y [K]``: lattice spacing 1 for the first octave,
    halved per octave with half the amplitude. ``octaves`` and ``seed`` are ints or ``[K]``."""
    octaves = np.broadcast_to(np.asarray(octaves, dtype=np.int64), np.shape(x))
    seed = np.asarray(seed, dtype=np.int64)
    if seed.size and seed.min() == seed.max():  # one seed (the common case): no per-point tables
        seeds, base = seed.reshape(-1)[:1], 0
    else:
        seeds, which = np.unique(np.broadcast_to(seed, np.shape(x)), return_inverse=True)
        base = which.reshape(np.shape(x)) * _LATTICE
    total = np.zeros(np.shape(x))
    norm = np.zeros(np.shape(x))
    amplitude = 1.0
    for octave in range(int(octaves.max(initial=1))):
        tables = [_lattice_tables(int(sd), octave) for sd in seeds]
        perm = np.concatenate([p for p, _ in tables])
        values = np.concatenate([v for _, v in tables])
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        sx, sy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
        ix, iy = x0.astype(np.int64), y0.astype(np.int64)
        if np.isscalar(base):  # one seed: index the tables directly
            px0, px1 = perm.take(ix & 255), perm.take((ix + 1) & 255)
            corner = lambda px, dy: values.take(perm.take((px + iy + dy) & 255))  # noqa: E731, B023 (called within this iteration)
        else:
            px0, px1 = perm.take(base + (ix & 255)), perm.take(base + ((ix + 1) & 255))
            corner = lambda px, dy: values.take(base + perm.take(base + ((px + iy + dy) & 255)))  # noqa: E731, B023 (called within this iteration)
        top = corner(px0, 0) * (1 - sx) + corner(px1, 0) * sx
        bottom = corner(px0, 1) * (1 - sx) + corner(px1, 1) * sx
        weight = np.where(octaves > octave, amplitude, 0.0)
        total += weight * (top * (1 - sy) + bottom * sy)
        norm += weight
        amplitude *= 0.5
        x, y = x * 2.0, y * 2.0
    return total / norm


def pattern_weight(kind: str, u, v, scale_m, angle_rad, duty=0.5, octaves=3, seed=0) -> np.ndarray:
    """How much of ``colour2`` a pattern puts at ``u, v [K]`` (metres): ``[K]`` in ``[0, 1]``.

    Parameters are numbers or per-point arrays ``[K]`` (see :class:`~aes_planner.sim.spec.PatternSpec`).
    """
    ca, sa = np.cos(angle_rad), np.sin(angle_rad)
    pu = (u * ca + v * sa) / scale_m
    pv = (v * ca - u * sa) / scale_m
    if kind == "checker":
        return ((np.floor(pu) + np.floor(pv)).astype(np.int64) & 1).astype(np.float64)
    if kind == "stripes":
        return (pu - np.floor(pu) < duty).astype(np.float64)
    if kind == "noise":
        return value_noise(pu, pv, octaves, seed)
    if kind == "gradient":
        return np.clip(pu + 0.5, 0.0, 1.0)
    raise ValueError(f"unknown pattern kind {kind!r}; expected one of {list(PATTERN_KINDS)}")


class MaterialTable:
    """The materials of a scene's objects as arrays ``[M, ...]`` (index = object index)."""

    def __init__(self, materials: Sequence[MaterialSpec]):
        m = len(materials)
        self.albedo = np.array([mat.albedo for mat in materials], dtype=np.float64).reshape(m, 3)
        self.emission = np.array([mat.emission for mat in materials], dtype=np.float64)
        patterns = [mat.pattern for mat in materials]
        self.kind = np.array(
            [NO_PATTERN if p is None else PATTERN_KINDS.index(p.kind) for p in patterns], dtype=np.int64
        )
        self.colour2 = np.array([p.colour2 if p else (0.0, 0.0, 0.0) for p in patterns], dtype=np.float64).reshape(m, 3)
        self.scale_m = np.array([p.scale_m if p else 1.0 for p in patterns], dtype=np.float64)
        self.angle_rad = np.array([math.radians(p.angle_deg) if p else 0.0 for p in patterns], dtype=np.float64)
        self.duty = np.array([p.duty if p else 0.5 for p in patterns], dtype=np.float64)
        self.octaves = np.array([p.octaves if p else 1 for p in patterns], dtype=np.int64)
        self.seed = np.array([p.seed if p else 0 for p in patterns], dtype=np.int64)

    def colour(self, obj: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Albedo ``[3, K]`` of the hits on objects ``obj [K]`` at ``u, v [K]`` (patterns
        applied; image textures are the caller's, see :func:`sample_image`)."""
        colour = self.albedo.T.take(obj, axis=1)
        kinds = self.kind.take(obj)
        for code in np.nonzero(np.bincount(kinds + 1))[0] - 1:
            if code == NO_PATTERN:
                continue
            sel = np.nonzero(kinds == code)[0]
            o = obj.take(sel)
            w = pattern_weight(
                PATTERN_KINDS[code],
                u.take(sel),
                v.take(sel),
                self.scale_m.take(o),
                self.angle_rad.take(o),
                self.duty.take(o),
                self.octaves.take(o),
                self.seed.take(o),
            )
            colour[:, sel] = colour.take(sel, axis=1) * (1.0 - w) + self.colour2.T.take(o, axis=1) * w
        return colour


def load_image(path: Path, key: str) -> np.ndarray:
    """An image file as RGB float32 ``[h, w, 3]`` in ``[0, 1]``; errors name the scene ``key``."""
    if not path.is_file():
        raise ConfigError(key, f"image file not found: {path} (paths are relative to the scene file)")
    try:
        bgr = imread_bounded(path, cv2.IMREAD_COLOR, str(path))
    except ImageError as exc:
        raise ConfigError(key, f"cannot read it as an image; use PNG or JPEG ({exc})") from None
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0


def sample_image(image: np.ndarray, s: np.ndarray, t: np.ndarray, wrap: bool) -> np.ndarray:
    """Bilinear lookup of ``image [h, w, 3]`` at ``(s, t) [K]`` in image widths/heights
    (``(0, 0)`` the top-left corner); repeats the image when ``wrap``, else clamps to its edge."""
    h, w = image.shape[:2]
    x, y = s * w - 0.5, t * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if wrap:
        xs, ys = (np.mod(x0, w), np.mod(x0 + 1, w)), (np.mod(y0, h), np.mod(y0 + 1, h))
    else:
        xs, ys = (np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)), (np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1))
    top = image[ys[0], xs[0]] * (1 - fx) + image[ys[0], xs[1]] * fx
    bottom = image[ys[1], xs[0]] * (1 - fx) + image[ys[1], xs[1]] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float64)
