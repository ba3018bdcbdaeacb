"""Search spaces: the parameters the search moves, their bounds, and the poses they map to.

* :class:`RigSpace` — a pan-tilt rig: ``params = (pan, tilt)`` in radians, inside the joint limits,
  mapped to cam2world through :class:`~aes_planner.geometry.PanTilt` (tilt offset and lever arm
  included, so the camera centre moves as the joints turn).
* :class:`FreeSpace` — a drone: ``params = (x, y, z, yaw, pitch)`` (the 5-DoF view of
  :mod:`aes_planner.geometry`), position inside the flight box, pitch inside the gimbal's range,
  yaw free (wrapped on output).
* :class:`HandHeldSpace` — a photographer's camera: the same 5 DoF, the position inside the region
  they walked (within the margin of the paths between the photos' cameras,
  :class:`~aes_planner.platform.HandHeldPlatform`), not a box.

Both keep the search inside the feasible set by **projection**: every candidate and every stage-2
step is clamped to the bounds (the Adam state is kept; the clamp is the projection onto the box).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world, wrap_angle
from aes_planner.platform import DroneBox, DronePlatform, HandHeldPlatform, Platform, RigPlatform

__all__ = [
    "FixedPattern",
    "FreeSpace",
    "HandHeldSpace",
    "RigSpace",
    "SearchSpace",
    "kronecker",
    "lattice_places",
    "random_poses",
    "space_for",
]


def _forward_dirs(cam2world: Tensor) -> Tensor:  # [M, 4, 4] -> [M, 3]
    return cam2world[:, :3, 2]


def _angle_matrix(a: Tensor, b: Tensor) -> Tensor:  # [M, 3], [P, 3] unit -> [M, P] radians
    cross = torch.linalg.cross(a[:, None, :].expand(-1, b.shape[0], -1), b[None, :, :].expand(a.shape[0], -1, -1))
    return torch.atan2(cross.norm(dim=-1), a @ b.T)


#: A drone's stage-1 grid (:meth:`FreeSpace.grid`): the ways each lattice place looks around the
#: circle, and the bands of the searched pitch range it looks at.
GRID_YAWS = 8
GRID_PITCHES = 3


def lattice_places(lo, hi, most: int) -> np.ndarray:  # [3], [3] -> [P, 3], P <= most
    """The centres of a lattice of at most ``most`` cells of the box ``lo``-``hi`` (metres): the
    axis with the longest cells splits next, so the cells stay about cubic (a 1.6 x 1.6 x 0.6 m
    box: 9 places 3 x 3 x 1, 18 places 3 x 3 x 2). Ordered x, then y, then z."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    extent = np.maximum(hi - lo, 1e-9)  # [3]
    if most < 1:
        return np.zeros((0, 3))
    counts = np.ones(3, dtype=int)  # [3] cells per axis
    while True:
        i = int(np.argmax(extent / counts))
        if int(np.prod(counts)) // counts[i] * (counts[i] + 1) > most:
            break
        counts[i] += 1
    axes = [lo[i] + extent[i] * (np.arange(counts[i]) + 0.5) / counts[i] for i in range(3)]
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], -1)


def kronecker(n: int, dims: int) -> np.ndarray:  # -> [n, dims] in [0, 1)
    """The points 1..n of the ``dims``-dimensional Kronecker (R-) sequence ``frac(0.5 + i * alpha)``
    (alpha: the powers of the inverse of the root of ``x ** (dims + 1) = x + 1``): spread evenly
    like uniform draws, consecutive points far apart, but fixed (no generator, no seed)."""
    phi = 2.0
    for _ in range(64):  # the generalised golden ratio, by fixed-point iteration
        phi = (1.0 + phi) ** (1.0 / (dims + 1))
    alpha = (1.0 / phi) ** np.arange(1, dims + 1)  # [dims]
    i = np.arange(1, n + 1, dtype=np.float64)[:, None]  # [n, 1]
    return (0.5 + i * alpha[None]) % 1.0


class FixedPattern:
    """What a search draws its stage-1 neighbours and coverage points from when
    ``SearchConfig.fixed_draws``: a stand-in for :class:`numpy.random.Generator` whose
    ``uniform(low, high, size)`` gives the Kronecker sequence (:func:`kronecker`) over the
    flattened leading axes of ``size``, as many axes as its last axis has elements (a drone's
    neighbours take their shifts and turns in one call: :meth:`FreeSpace.neighbours`); ``choice``
    takes evenly spaced indices. The same call gives the same values in every search: which views
    a search scores does not depend on a seed."""

    def uniform(self, low=0.0, high=1.0, size=None):
        shape = (1,) if size is None else ((size,) if isinstance(size, int) else tuple(size))
        dims = shape[-1] if len(shape) > 1 else 1
        n = int(np.prod(shape)) // max(dims, 1)
        u = kronecker(n, dims).reshape(shape)
        out = np.asarray(low) + (np.asarray(high) - np.asarray(low)) * u
        return float(out.reshape(-1)[0]) if size is None else out

    def choice(self, a: int, size: int, replace: bool = False):
        if size > a and not replace:
            raise ValueError(f"cannot take {size} of {a} without replacement")
        return np.floor((np.arange(size) + 0.5) * a / size).astype(int)


def _span(a: float, b: float, step: float) -> np.ndarray:  # -> [n] from a to b, at most step apart
    n = max(2, int(math.floor((b - a) / step)) + 1)
    return np.linspace(a, b, n)


class SearchSpace:
    """Parameters ``[M, D]`` float64 <-> poses; bounds; neighbours; a distance for duplicates."""

    kind: str
    dims: int
    lower: Tensor  # [D]
    upper: Tensor  # [D]

    def __init__(self, platform: Platform, jitter_rad: float, dedup_rad: float):
        self.platform = platform
        self.jitter_rad = jitter_rad
        self.dedup_rad = dedup_rad

    def to_poses(self, params: Tensor) -> Tensor:  # [M, D] -> [M, 4, 4] float64, differentiable
        raise NotImplementedError

    def from_poses(self, cam2world: np.ndarray) -> Tensor:  # [M, 4, 4] -> [M, D], projected into bounds
        raise NotImplementedError

    def project(self, params: Tensor) -> Tensor:  # [M, D] -> [M, D] inside the bounds
        return torch.maximum(torch.minimum(params, self.upper), self.lower)

    def neighbours(self, params: Tensor, n: int, rng: np.random.Generator) -> Tensor:  # [M, D] -> [M * n, D]
        raise NotImplementedError

    def distance(self, a: Tensor, b: Tensor) -> Tensor:  # [M, D], [P, D] -> [M, P], 1 = duplicate threshold
        """Normalised distance between parameter sets: below 1 means 'the same view'."""
        da = _forward_dirs(self.to_poses(a).detach())
        db = _forward_dirs(self.to_poses(b).detach())
        return _angle_matrix(da, db) / self.dedup_rad

    def exhaustive_grid(
        self, step_deg: float, free_step_deg: float, free_positions: tuple[int, int, int]
    ) -> tuple[Tensor, float, np.ndarray]:  # -> grid [G, D], step (rad), pattern steps [D]
        """The oracle's grid over the whole space, its angular step, and the first step of its
        pattern search per parameter (:func:`aes_planner.search.oracle_search`)."""
        raise NotImplementedError

    def grid_axes(self, grid: np.ndarray) -> dict[str, np.ndarray]:  # [G, D] -> named axes
        """The axes of an :meth:`exhaustive_grid` where it is a plain 2-D table (a rig's pan x tilt)."""
        return {}

    def joints(self, params: Tensor) -> tuple[float | None, float | None]:  # [D] -> (pan, tilt) radians
        """The rig's joint angles of ``params`` (None, None where the platform has no joints)."""
        return None, None

    def random(self, n: int, rng: np.random.Generator) -> Tensor:  # -> [n, D] uniform in the bounds
        lo, hi = self.lower.numpy(), self.upper.numpy()
        return torch.as_tensor(rng.uniform(lo, hi, size=(n, self.dims)))

    def grid(self, n: int) -> Tensor:  # -> [G, D], G about n, spread evenly over the whole space
        """Stage-1 candidates independent of the input trajectory (``SearchConfig.grid_points``);
        empty for n <= 0."""
        return torch.zeros(0, self.dims, dtype=torch.float64)

    def spread(self, n: int, rng: np.random.Generator) -> Tensor:  # -> [G, D], about n over the whole space
        """The views ``explore_points`` scores to say what the inputs cover: the :meth:`grid`
        (a rig's pan x tilt), or ``n`` drawn uniformly where the space has none."""
        out = self.grid(n)
        return out if len(out) else self.random(n, rng)


class RigSpace(SearchSpace):
    """Pan and tilt inside the joint limits, through the rig's kinematics."""

    kind = "rig"
    dims = 2

    def __init__(self, platform: Platform, jitter_rad: float, dedup_rad: float):
        super().__init__(platform, jitter_rad, dedup_rad)
        self.kinematics = platform.kinematics
        (plo, phi), (tlo, thi) = self.kinematics.pan_limits_rad, self.kinematics.tilt_limits_rad
        self.lower = torch.tensor([plo, tlo], dtype=torch.float64)
        self.upper = torch.tensor([phi, thi], dtype=torch.float64)

    def to_poses(self, params: Tensor) -> Tensor:  # [M, 2] -> [M, 4, 4]
        return self.kinematics.forward(params[:, 0], params[:, 1])

    def from_poses(self, cam2world: np.ndarray) -> Tensor:  # [M, 4, 4] -> [M, 2]
        out, hint = [], 0.5 * float(self.lower[0] + self.upper[0])
        for pose in np.asarray(cam2world, dtype=np.float64):  # the joints of inverse_direction, clamped
            pan, tilt = self.kinematics.clamp(*self.kinematics.direction_joints(pose[:3, 2], pan_hint_rad=hint))
            out.append((pan, tilt))
            hint = pan
        return self.project(torch.tensor(out, dtype=torch.float64).reshape(-1, 2))

    def joints(self, params: Tensor) -> tuple[float, float]:  # [2] -> (pan, tilt)
        return float(params[0]), float(params[1])

    def exhaustive_grid(self, step_deg, free_step_deg, free_positions):  # pan x tilt, step_deg apart
        lo, hi, step = self.lower.numpy(), self.upper.numpy(), math.radians(step_deg)
        pans, tilts = np.meshgrid(_span(lo[0], hi[0], step), _span(lo[1], hi[1], step), indexing="xy")
        return torch.as_tensor(np.stack([pans.ravel(), tilts.ravel()], -1)), step, np.full(self.dims, step / 2)

    def grid_axes(self, grid: np.ndarray) -> dict[str, np.ndarray]:
        return {"pan_values": np.unique(grid[:, 0]), "tilt_values": np.unique(grid[:, 1])}

    def neighbours(self, params: Tensor, n: int, rng: np.random.Generator) -> Tensor:  # [M, 2] -> [M * n, 2]
        jitter = torch.as_tensor(rng.uniform(-self.jitter_rad, self.jitter_rad, size=(params.shape[0], n, 2)))
        return self.project((params[:, None, :] + jitter).reshape(-1, 2))

    def grid(self, n: int) -> Tensor:  # -> [n_pan * n_tilt, 2], cell centres, about n in all
        if n <= 0:
            return super().grid(n)
        span = (self.upper - self.lower).clamp_min(1e-9)
        n_pan = max(1, round(math.sqrt(n * float(span[0] / span[1]))))
        n_tilt = max(1, round(n / n_pan))
        pans = self.lower[0] + span[0] * (torch.arange(n_pan, dtype=torch.float64) + 0.5) / n_pan
        tilts = self.lower[1] + span[1] * (torch.arange(n_tilt, dtype=torch.float64) + 0.5) / n_tilt
        p, t = torch.meshgrid(pans, tilts, indexing="xy")
        return torch.stack([p.reshape(-1), t.reshape(-1)], -1)


class FreeSpace(SearchSpace):
    """5-DoF views (x, y, z, yaw, pitch): position in the box, pitch in its limits, yaw free."""

    kind = "drone"
    dims = 5

    def __init__(
        self,
        platform: Platform,
        jitter_rad: float,
        dedup_rad: float,
        shift_m: float,
        dedup_m: float,
        pitch_limits_rad: tuple[float, float],
    ):
        super().__init__(platform, jitter_rad, dedup_rad)
        box: DroneBox = platform.free_box()
        self.box = box
        self.shift_m = shift_m
        self.dedup_m = dedup_m
        inf = math.inf
        self.lower = torch.tensor([*box.bounds_min_m, -inf, pitch_limits_rad[0]], dtype=torch.float64)
        self.upper = torch.tensor([*box.bounds_max_m, inf, pitch_limits_rad[1]], dtype=torch.float64)

    def to_poses(self, params: Tensor) -> Tensor:  # [M, 5] -> [M, 4, 4]
        return view_to_cam2world(params)

    def from_poses(self, cam2world: np.ndarray) -> Tensor:  # [M, 4, 4] -> [M, 5]
        views = torch.as_tensor(cam2world_to_view(np.asarray(cam2world, dtype=np.float64)))
        return self.project(views.reshape(-1, 5))

    def project(self, params: Tensor) -> Tensor:  # [M, 5] -> [M, 5]; yaw wrapped
        p = torch.maximum(torch.minimum(params, self.upper), self.lower)
        return torch.cat([p[:, :3], wrap_angle(p[:, 3:4]), p[:, 4:5]], dim=-1)

    def neighbours(self, params: Tensor, n: int, rng: np.random.Generator) -> Tensor:  # [M, 5] -> [M * n, 5]
        m = params.shape[0]
        poses = self.to_poses(params)  # [M, 4, 4]
        right, down = poses[:, :3, 0], poses[:, :3, 1]  # [M, 3] image axes in the world
        if isinstance(rng, FixedPattern):  # one 4-axis pattern: the shifts and the turns not aligned
            u = torch.as_tensor(rng.uniform(-1.0, 1.0, size=(m, n, 4)))  # [M, n, 4]
            shift, jitter = u[..., :2] * self.shift_m, u[..., 2:] * self.jitter_rad
        else:
            shift = torch.as_tensor(rng.uniform(-self.shift_m, self.shift_m, size=(m, n, 2)))
            jitter = torch.as_tensor(rng.uniform(-self.jitter_rad, self.jitter_rad, size=(m, n, 2)))
        pos = params[:, None, :3] + shift[..., :1] * right[:, None] + shift[..., 1:] * down[:, None]  # [M, n, 3]
        ang = params[:, None, 3:] + jitter  # [M, n, 2]
        return self.project(torch.cat([pos, ang], dim=-1).reshape(-1, 5))

    def distance(self, a: Tensor, b: Tensor) -> Tensor:  # [M, 5], [P, 5] -> [M, P]
        angle = super().distance(a, b)
        return angle + torch.cdist(a[:, :3], b[:, :3]) / self.dedup_m

    def exhaustive_grid(self, step_deg, free_step_deg, free_positions):  # box cells x yaw x pitch
        lo, hi, step = self.lower.numpy(), self.upper.numpy(), math.radians(free_step_deg)
        axes = []
        for i, n in enumerate(free_positions):  # cell centres, so no view sits on a wall
            edges = np.linspace(lo[i], hi[i], n + 1)
            axes.append(0.5 * (edges[:-1] + edges[1:]))
        yaws = np.arange(0.0, 2 * math.pi, step) - math.pi
        mesh = np.meshgrid(*axes, yaws, _span(lo[4], hi[4], step), indexing="ij")
        steps = np.full(self.dims, step / 2)
        steps[:3] = (hi[:3] - lo[:3]) / np.asarray(free_positions) / 2
        return torch.as_tensor(np.stack([m.ravel() for m in mesh], -1)), step, steps

    def random(self, n: int, rng: np.random.Generator) -> Tensor:  # [n, 5]
        lo, hi = self.lower.numpy().copy(), self.upper.numpy().copy()
        lo[3], hi[3] = -math.pi, math.pi
        return torch.as_tensor(rng.uniform(lo, hi, size=(n, 5)))

    def spread(self, n: int, rng: np.random.Generator) -> Tensor:  # [n, 5], drawn (what covered_fraction measured)
        return self.random(n, rng)

    def grid(self, n: int) -> Tensor:  # -> [P * GRID_YAWS * GRID_PITCHES, 5], P places, about n views in all
        """Views from places nobody visited: the centres of a lattice of at most ``n / (GRID_YAWS *
        GRID_PITCHES)`` cells of the flight box (:func:`lattice_places`), each place looking ``GRID_YAWS`` ways around the circle and at ``GRID_PITCHES`` pitches
        (the centres of as many equal bands of the searched pitch range). A drone's stage 1 samples
        only along and around the inputs' path, mostly the start's turn (docs/benchmarks.md,
        "Where the drone's search can look"); these compete with those samples, scored by the
        same objective (a view of what nothing saw loses to its coverage penalty)."""
        per_place = GRID_YAWS * GRID_PITCHES
        if n < per_place:
            return super().grid(n)
        lo, hi = self.lower.numpy(), self.upper.numpy()
        places = lattice_places(lo[:3], hi[:3], n // per_place)  # [P, 3]
        yaws = -math.pi + 2.0 * math.pi * (np.arange(GRID_YAWS) + 0.5) / GRID_YAWS
        pitches = lo[4] + (hi[4] - lo[4]) * (np.arange(GRID_PITCHES) + 0.5) / GRID_PITCHES
        p, y, t = np.meshgrid(np.arange(len(places)), yaws, pitches, indexing="ij")
        return torch.as_tensor(np.concatenate([places[p.ravel()], y.reshape(-1, 1), t.reshape(-1, 1)], -1))


class HandHeldSpace(FreeSpace):
    """5-DoF views whose position stays in the region a photographer walked: within the platform's
    margin of the segments between neighbouring photos' cameras (a chain of capsules). The
    projection moves a position outside to the nearest point of the nearest capsule (the exact
    projection onto the union); pitch and yaw as in :class:`FreeSpace`."""

    kind = "handheld"

    def __init__(self, platform: Platform, *args, **kwargs):
        super().__init__(platform, *args, **kwargs)
        centres = torch.as_tensor(platform.centres, dtype=torch.float64)  # [N, 3]
        edges = torch.as_tensor(platform.edges)  # [E, 2]
        self.seg_a, self.seg_b = centres[edges[:, 0]], centres[edges[:, 1]]  # [E, 3]
        self.margin = float(platform.margin_m)

    def _nearest(self, xyz: Tensor) -> tuple[Tensor, Tensor]:  # [M, 3] -> nearest path point [M, 3], distance [M]
        ab = self.seg_b - self.seg_a  # [E, 3]
        t = (((xyz[:, None] - self.seg_a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-18)).clamp(0, 1)  # [M, E]
        q = self.seg_a + t[..., None] * ab  # [M, E, 3]
        d = (xyz[:, None] - q).norm(dim=-1)  # [M, E]
        k = d.argmin(dim=-1)  # [M]
        rows = torch.arange(len(xyz))
        return q[rows, k], d[rows, k]

    def project(self, params: Tensor) -> Tensor:  # [M, 5] -> [M, 5], the position in the walked region
        p = super().project(params)
        q, d = self._nearest(p[:, :3])
        factor = torch.where(d > self.margin, self.margin / d.clamp_min(1e-18), torch.ones_like(d))[:, None]
        return torch.cat([q + (p[:, :3] - q) * factor, p[:, 3:]], dim=-1)

    def grid(self, n: int) -> Tensor:  # [G, 5]: the box's lattice, each place moved into the walked region
        return self.project(super().grid(n))

    def random(self, n: int, rng: np.random.Generator) -> Tensor:  # [n, 5], positions spread over the region
        e = rng.integers(0, len(self.seg_a), n)
        t = torch.as_tensor(rng.uniform(0, 1, n))[:, None]
        on_path = self.seg_a[e] + t * (self.seg_b[e] - self.seg_a[e])  # [n, 3]
        offset = torch.as_tensor(rng.normal(size=(n, 3)))
        offset = (
            offset
            / offset.norm(dim=-1, keepdim=True)
            * self.margin
            * torch.as_tensor(rng.uniform(0, 1, n))[:, None] ** (1 / 3)
        )
        lo, hi = self.lower.numpy(), self.upper.numpy()
        angles = torch.as_tensor(np.stack([rng.uniform(-math.pi, math.pi, n), rng.uniform(lo[4], hi[4], n)], -1))
        return self.project(torch.cat([on_path + offset, angles], dim=-1))


def space_for(platform: Platform, cfg=None) -> SearchSpace:
    """The search space of a platform under a :class:`~aes_planner.search.SearchConfig` (default
    settings when None): a rig's joints (:class:`RigSpace`), a drone's 5-DoF views
    (:class:`FreeSpace`) or a hand-held camera's (:class:`HandHeldSpace`), with the bounds the search
    projects onto."""
    if cfg is None:
        from aes_planner.search.config import SearchConfig

        cfg = SearchConfig()
    hfov = platform.intrinsics.hfov_rad
    if isinstance(platform, RigPlatform):
        return RigSpace(platform, cfg.jitter_fov * hfov, cfg.dedup_fov * hfov)
    if isinstance(platform, HandHeldPlatform):  # the region walked: its bounding box sizes the shifts
        diag = platform.free_box().diagonal_m
        lo_deg, hi_deg = platform.pitch_limits_deg
        return HandHeldSpace(
            platform,
            cfg.jitter_fov * hfov,
            cfg.dedup_fov * hfov,
            cfg.shift_frac * diag,
            cfg.dedup_frac * diag,
            (max(cfg.pitch_limits_rad[0], math.radians(lo_deg)), min(cfg.pitch_limits_rad[1], math.radians(hi_deg))),
        )
    if isinstance(platform, DronePlatform):
        diag = platform.drone.diagonal_m
        return FreeSpace(
            platform,
            cfg.jitter_fov * hfov,
            cfg.dedup_fov * hfov,
            cfg.shift_frac * diag,
            cfg.dedup_frac * diag,
            cfg.pitch_limits_rad,
        )
    raise TypeError(
        f"no search space for a {type(platform).__name__}; expected a RigPlatform, a DronePlatform or a HandHeldPlatform"
    )


def random_poses(platform: Platform, n: int, rng: np.random.Generator, cfg=None) -> np.ndarray:  # -> [n, 4, 4]
    """``n`` feasible poses drawn uniformly over the search space's bounds (rig: the joint ranges;
    drone: the box, any yaw, the searched pitch range): the chance level of every oracle-normalised
    score, the one sampler behind every "mean random" baseline."""
    space = space_for(platform, cfg)
    return space.to_poses(space.random(n, rng)).detach().numpy()
