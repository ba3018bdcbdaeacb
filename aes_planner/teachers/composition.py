"""The composition teacher: a differentiable, weight-free model of framing and composition.

It is the default teacher and what the whole product maximises, so every term is built from
image evidence that a bad view cannot fake cheaply. Two gates decide what a view is worth
before its framing is judged: ``content`` (is there anything to look at: a blank wall, a black
frame or an empty sky score about zero) and ``subject_presence`` (is there a *subject*: a
compact, isolated region of a colour the rest of the frame does not repeat). Bare structure and
regular texture (wall corners, floor boards, a checker floor, a striped cloth) have content but
no subject, so they lose the subject terms and score about half of a framed subject.

**Features** (``features(images) -> [B, 4, 16, 16]``; the analogue of VEN's 14x14 pool4 map,
but 4 channels instead of 512 so that the field renders it cheaply). The image is resampled to a
64x64 working frame (area averaging down, bilinear up; composition is judged in normalised frame
coordinates, so the aspect ratio is not kept) and converted to an opponent colour space
(luminance, red-green, yellow-blue). Per 4x4 cell:

====  ==============  ====================================================================
 ch   name            meaning
====  ==============  ====================================================================
 0    ``saliency``    *distinctive* contrast: centre-surround colour contrast (distance in
                      opponent colour between a fine blur and two coarse surrounds), times
                      the cell colour's distinctiveness in the frame, ``exp(-(area / 0.3 +
                      repeated / 0.0025))``: ``area`` is the share of the frame's cells of a
                      similar colour (a wall, a floor, a sky), ``repeated`` the mean contrast
                      per cell carried by cells of a similar colour at least ~5 cells away (a
                      checker, stripes, tiles or boards repeat their contrast all over the
                      frame; a subject's own outline lies near it). A lone object of its own
                      colour keeps its contrast; large surfaces and repeated patterns lose it
 1    ``edge_xx``     mean ``gx^2`` of the colour gradient (vertical-edge energy)
 2    ``edge_yy``     mean ``gy^2`` (horizontal-edge energy)
 3    ``edge_xy``     mean ``gx*gy``; with 1 and 2 the pooled colour structure tensor, which
                      gives the edge energy at any orientation ``t`` as
                      ``xx*cos^2 t + 2*xy*sin t*cos t + yy*sin^2 t``
====  ==============  ====================================================================

Distinctiveness is global (it compares each cell's colour with the whole frame's, 256 x 256
cell pairs), so it lives in the trunk, not the head; the map keeps its 4 channels.

**Head** (``head(fmap) -> [B]``; about fifty tensor ops on the 16x16 map, no weights). It first
tells objects from lines: the smaller eigenvalue of the structure tensor pooled over 3x3 cells
(*corner energy*, Shi-Tomasi at cell scale) is large where edges of several orientations meet
(objects, corners, foliage) and about zero along straight lines (wall edges, floor boards, a
horizon). *Salient evidence* is saliency times objectness (a squashed corner energy). The
**subject** is that evidence where it is *isolated*: divided by itself plus 10 x the mean
evidence over an annulus 3-6 cells around (a texture's cells are as strong as their surround and
keep about 1/11; a compact object's outline mostly lies inside the annulus' hole).
``subject_presence = 1 - exp(-subject mass / 0.3)``. Each term lies in ``[0, 1]``, higher is
better:

* ``thirds`` -- share of the subject's (squared) mass on the rule-of-thirds template (Gaussians
  at the four power points, half-height ridges along the four third lines). A subject on a
  power point scores about 0.75, a centred one about 0.15, no subject or an even spread 0.27.
* ``balance`` -- the visual-weight centroid (subject and edge energy) lies near the horizontal
  centre (vertical offsets count a quarter as much). A lone subject on a third scores about 0.6.
* ``border`` -- nothing salient cut by the frame: the share of the salient evidence on the
  one-cell frame ring beyond 0.08 decays the term (lines crossing the frame cost nothing).
* ``horizon_placement`` -- the dominant frame-spanning near-horizontal line (horizon, floor or
  table line) lies on a third rather than in the middle.
* ``horizon_level`` -- that line is level (a 2.5 deg tilt costs about 40 %, 5 deg about 85 %).
* ``clutter`` -- clean versus busy: the share of cells with strong edges; 1 for a clean frame
  with a few strong lines, about 0 when edges fill the frame.
* ``subject_size`` -- the subject covers a sensible share of the frame: the area of its
  second-moment ellipse (about its share of the frame), log-normal around 12 %.

and three factors that say how the terms are combined:

* ``content`` -- how much there is to look at: ``1 - exp(-(corner energy / 1e-4 + 0.7 *
  lines))`` where ``lines`` in ``[0, 1]`` measures edge energy; about 0 for a blank wall, a
  black frame or an empty sky, at most 0.5 with straight lines only, above 0.95 with one clear
  object.
* ``subject_presence`` -- whether there is a subject, in ``[0, 1]``: the subject terms
  (``thirds``, ``border``, ``subject_size``) are *earned* in proportion to it, their weights
  staying in the denominator, so a view without a subject scores as if they were 0.
* ``horizon_presence`` -- how strongly a frame-spanning near-horizontal line is present, in
  ``[0, 1]``; the two horizon terms count (weights and all) only in proportion to it.

**Score**, in ``[0, 1]``::

    score = content * sum_k(w_k * g_k * e_k * term_k) / sum_k(w_k * g_k)

with the weights ``w_k`` of :class:`CompositionWeights`, ``g_k = horizon_presence`` for the
horizon terms (else 1) and ``e_k = subject_presence`` for the subject terms (else 1). A
featureless view scores near 0; bare structure and regular texture 0.1-0.45 (median about 0.25
on random rig views of the simulator's scenes); an ordinary view of a subject 0.3-0.65 (median
0.43); a clean subject on a third with a level horizon on the other third about 0.8.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from aes_planner.config import require, require_finite
from aes_planner.teachers.base import Teacher, check_feature_map, check_images

log = logging.getLogger(__name__)

__all__ = ["CompositionConfig", "CompositionWeights", "CompositionTeacher", "TERMS", "CHANNELS"]

#: Feature-map channels, in order.
CHANNELS = ("saliency", "edge_xx", "edge_yy", "edge_xy")
#: Terms of the score, in order (see the module docstring).
TERMS = (
    "thirds",
    "balance",
    "border",
    "horizon_placement",
    "horizon_level",
    "clutter",
    "subject_size",
)
_SUBJECT_TERMS = ("thirds", "border", "subject_size")  # earned in proportion to subject presence
_HORIZON_TERMS = ("horizon_placement", "horizon_level")  # weighted by horizon presence

# Calibration constants of the head (fixed; the tests pin their effect). Energies are per cell
# of the 16x16 map for images in [0, 1].
_EPS = 1e-6
_TINY = 1e-14
_MAP_LIMIT = 1e3  # the head clamps rendered maps to +-this before anything can overflow
_COLOUR_SIGMA = 0.06  # colour kernel of the distinctiveness (opponent units, chroma x _CHROMA_WEIGHT)
_CHROMA_WEIGHT = 2.0
_AREA_SHARE = 0.3  # share of the frame in one colour that divides its saliency by e
_REPEATED_CONTRAST = 0.0025  # mean contrast per cell, in one colour away from a cell, that divides its saliency by e
_DISTINCT_CHUNK = 64  # images per pass of the distinctiveness ([64, 256, 256] floats: 16 MB a temporary)
_FAR = 0.31  # frame units (5 cells of 16): contrast nearer than this is the cell's own object, not a repeat
_SAL_FLOOR = 3e-3  # subject saliency every cell is assumed to have: without a subject, p is uniform
_RING_FLOOR = 1e-3  # the same for the share of the subject on the frame ring
_EDGE_GAIN = 4.0  # structure tensor scale: a hard edge gives cells of about 0.01-0.1
_OBJECT_ENERGY = 1e-3  # cell corner energy at which a cell counts a quarter object-like
_CONTENT_OBJECT = 1e-4  # mean corner energy worth one unit of content evidence
_CONTENT_EDGE_FLOOR = 3e-4  # edge energy below this (a smooth shading ramp) is not content
_CONTENT_EDGE = 5e-4  # mean edge energy above the floor for 63 % of the lines' share
_LINES_CONTENT = 0.7  # lines alone give at most 1 - exp(-0.7) = 0.5 content
_BALANCE_SIGMA = 0.18
_BORDER_FREE = 0.08  # share of the subject on the frame ring that costs nothing
_BORDER_SCALE = 0.08
_BUSY_ENERGY = 0.004  # a cell with this edge energy counts half busy
_CLUTTER_MID, _CLUTTER_WIDTH = 0.35, 0.07
_SIZE_LOG_SIGMA = 1.2
_AREA_GAIN = 1.6  # the squared subject mass sits on outlines and corners: x1.6 ~ share of the frame
_ISOLATION = 10.0  # weight of the surround in the subject's divisive normalisation
_ANNULUS_SIGMAS = (0.19, 0.375)  # frame units (3 and 6 cells of 16): the surround of the isolation
_PRESENCE_MASS = 0.3  # summed subject evidence for 63 % subject presence
_HORIZON_ENERGY = 0.015  # line energy per third of the width for presence 0.63 (a hard level edge: ~0.94)
_HORIZON_SIGMA = 0.06  # of the frame height, around each third


@dataclass(frozen=True)
class CompositionWeights:
    """Weights of the terms in the score (non-negative, at least one positive)."""

    thirds: float = 1.0
    balance: float = 0.5
    border: float = 1.0
    horizon_placement: float = 1.0
    horizon_level: float = 0.75
    clutter: float = 0.75
    subject_size: float = 0.75

    def __post_init__(self):
        for name in TERMS:
            v = getattr(self, name)
            require_finite(v, f"weights.{name}")
            require(v >= 0, f"weights.{name}", f"must be >= 0, got {v}")
        require(sum(getattr(self, n) for n in TERMS) > 0, "weights", "at least one weight must be positive")


@dataclass(frozen=True)
class CompositionConfig:
    """Settings of :class:`CompositionTeacher`.

    ``work_size``: side of the square working frame the image is resampled to (px).
    ``feature_size``: side of the square feature map; must divide ``work_size``.
    ``thirds_sigma``: spread of the power-point Gaussians, in frame units.
    ``tilt_tolerance_deg``: horizon tilt at which ``horizon_level`` falls to ``exp(-1/2)``.
    ``ideal_subject_area``: effective subject area (share of the frame) that scores 1.
    """

    work_size: int = 64
    feature_size: int = 16
    thirds_sigma: float = 0.09
    tilt_tolerance_deg: float = 2.5
    ideal_subject_area: float = 0.12
    weights: CompositionWeights = field(default_factory=CompositionWeights)

    def __post_init__(self):
        require(
            isinstance(self.work_size, int) and self.work_size >= 16,
            "work_size",
            f"must be an integer >= 16, got {self.work_size!r}",
        )
        require(
            isinstance(self.feature_size, int)
            and 3 <= self.feature_size <= self.work_size
            and self.work_size % self.feature_size == 0,
            "feature_size",
            f"must be an integer >= 3 that divides work_size={self.work_size}, got {self.feature_size!r}",
        )
        for name, lo, hi in (
            ("thirds_sigma", 0.01, 0.5),
            ("tilt_tolerance_deg", 0.1, 45.0),
            ("ideal_subject_area", 0.005, 1.0),
        ):
            v = getattr(self, name)
            require_finite(v, name)
            require(lo <= v <= hi, name, f"must be in [{lo}, {hi}], got {v}")


def _gaussian_kernel(sigma: float) -> Tensor:  # -> [K]
    radius = max(1, int(math.ceil(3.0 * sigma)))
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    return (k / k.sum()).float()


def _smoothing_matrix(n: int, kernel: Tensor) -> Tensor:  # [K] -> [n, n]
    """The 1D convolution with ``kernel`` and replicate padding as a matrix: ``y = M @ x``.

    The head works on 16-cell axes, where one small matmul costs far less than pad + conv
    (whose thread-pool start-up dominates at this size)."""
    r = kernel.numel() // 2
    m = torch.zeros(n, n, dtype=torch.float64)
    for i in range(n):
        for j, k in enumerate(kernel.tolist()):
            m[i, min(max(i + j - r, 0), n - 1)] += k
    return m.float()


@dataclass(frozen=True)
class _Tables:
    filters: int  # filters per opponent channel in the separable bank
    radius: int  # px, of the bank's kernels
    buffers: tuple[tuple[str, Tensor], ...]  # (buffer name, constant tensor)


@functools.lru_cache(maxsize=8)
def _constant_tables(n: int, thirds_sigma: float, centre_sigma: float, surround_sigmas: tuple[float, ...]) -> _Tables:
    """The teacher's constant filters and cell matrices for a feature map of ``n`` x ``n`` cells,
    computed once per process and setting: building them took 30-140 ms of every field build
    (a field builds its teacher each time; docs/benchmarks.md, "perf-2, fourth round")."""
    buffers: dict[str, Tensor] = {}
    # Every filter of the working frame in one separable pass per axis: per opponent channel,
    # the centre blur, the surround blurs, and the Sobel derivatives of the centre blur.
    # (Few large convolutions: the thread pool's start-up, not arithmetic, dominates here.)
    blurs = [_gaussian_kernel(sg) for sg in (centre_sigma, *surround_sigmas)]
    # Sobel = [1, 2, 1] / 4 across times this along, /8 in all
    diff = torch.tensor([-0.5, 0.0, 0.5], dtype=torch.float32)
    smooth = torch.tensor([0.25, 0.5, 0.25], dtype=torch.float32)
    centre = blurs[0]
    d_centre = torch.conv1d(F.pad(centre, (1, 1))[None, None], diff.flip(0)[None, None])[0, 0]
    s_centre = torch.conv1d(F.pad(centre, (1, 1))[None, None], smooth[None, None])[0, 0]
    along_x = [*blurs, d_centre, s_centre]  # outputs: blurs..., gx, gy
    along_y = [*blurs, s_centre, d_centre]
    radius = max(k.numel() for k in along_x) // 2

    def bank(kernels: list[Tensor]) -> Tensor:  # -> [3 * F, K]
        padded = [F.pad(k, ((2 * radius + 1 - k.numel()) // 2,) * 2) for k in kernels]
        return torch.stack(padded).repeat(3, 1)

    buffers["_filters_x"] = bank(along_x)[:, None, None, :]  # [3F, 1, 1, K]
    buffers["_filters_y"] = bank(along_y)[:, None, :, None]  # [3F, 1, K, 1]
    opponent = torch.tensor([[0.299, 0.587, 0.114], [0.5, -0.5, 0.0], [0.25, 0.25, -0.5]], dtype=torch.float32)
    buffers["_opponent"] = opponent  # rows: L, red-green, yellow-blue
    buffers["_colour_weights"] = torch.tensor([1.0, _CHROMA_WEIGHT, _CHROMA_WEIGHT], dtype=torch.float32)

    c = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    y, x = torch.meshgrid(c, c, indexing="ij")
    cells = torch.stack([y.flatten(), x.flatten()], -1)  # [N, 2] frame units
    far = 1.0 - torch.exp(-((cells[:, None] - cells[None]) ** 2).sum(-1) / (2 * _FAR**2))
    buffers["_far"] = far.float()  # [N, N]: 0 for the same cell, ~1 across the frame
    thirds = (1.0 / 3.0, 2.0 / 3.0)
    s = thirds_sigma
    points = torch.stack(
        [torch.exp(-((x - a) ** 2 + (y - b) ** 2) / (2 * s * s)) for a in thirds for b in thirds]
    ).amax(0)
    ridge = torch.stack(
        [torch.exp(-((x - a) ** 2) / (2 * (s / 2) ** 2)) for a in thirds]
        + [torch.exp(-((y - a) ** 2) / (2 * (s / 2) ** 2)) for a in thirds]
    ).amax(0)
    ring = torch.zeros(n, n, dtype=torch.float64)
    ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = 1.0
    buffers["_x"] = x.float()
    buffers["_y"] = y.float()
    buffers["_thirds"] = torch.maximum(points, 0.5 * ridge).float()
    buffers["_ring"] = ring.float()
    buffers["_rows"] = c.float()
    buffers["_box3"] = _smoothing_matrix(n, torch.full((3,), 1.0 / 3.0, dtype=torch.float32))
    buffers["_row_blur"] = _smoothing_matrix(n, _gaussian_kernel(1.5))
    # Annulus means as one [N, N] matrix (source cell -> target cell): the outer Gaussian minus
    # the inner one (both 1 at distance 0, so the cell itself drops out), clipped to the frame
    # and normalised per target cell; every weight >= 0.
    inner, outer = (torch.exp(-((c[:, None] - c[None]) ** 2) / (2 * sg**2)) for sg in _ANNULUS_SIGMAS)
    annulus = (torch.kron(outer, outer) - torch.kron(inner, inner)).clamp_min(0.0)
    buffers["_annulus"] = (annulus / annulus.sum(0, keepdim=True)).float()  # [N, N]
    groups = torch.zeros(n, 3, dtype=torch.float32)  # column -> left / middle / right third of the width
    for j, (a, b) in enumerate(zip((0, n // 3, n - n // 3), (n // 3, n - n // 3, n))):
        groups[a:b, j] = 1.0
    buffers["_thirds_of_width"] = groups
    return _Tables(len(along_x), radius, tuple(buffers.items()))


class CompositionTeacher(Teacher):
    """Composition teacher (the default): see the module docstring for the map, terms and score."""

    name = "composition"
    score_range = "[0, 1]: ~0 featureless, 0.1-0.45 bare structure or texture, 0.3-0.65 a subject, ~0.8 well composed"

    _CENTRE_SIGMA = 1.0  # px of the working frame
    _SURROUND_SIGMAS = (4.0, 10.0)

    def __init__(self, config: CompositionConfig | None = None):
        super().__init__()
        self.config = cfg = config or CompositionConfig()
        n = cfg.feature_size
        self.feature_channels = len(CHANNELS)
        self.feature_size = (n, n)
        tables = _constant_tables(n, cfg.thirds_sigma, self._CENTRE_SIGMA, self._SURROUND_SIGMAS)
        self._filters, self._radius = tables.filters, tables.radius
        for name, value in tables.buffers:  # copies: a caller's in-place change stays in its teacher
            self.register_buffer(name, value.clone(), persistent=False)
        weights = torch.tensor([getattr(cfg.weights, t) for t in TERMS], dtype=torch.float32)
        self.register_buffer("_weights", weights, persistent=False)
        self.freeze()

    # ------------------------------------------------------------------ features
    def _working_frame(self, images: Tensor) -> Tensor:  # [B, 3, H, W] -> [B, 3, s, s]
        s = self.config.work_size
        h, w = images.shape[-2:]
        if h < s or w < s:
            images = F.interpolate(images, size=(max(h, s), max(w, s)), mode="bilinear", align_corners=False)
        if images.shape[-2:] != (s, s):
            images = F.adaptive_avg_pool2d(images, (s, s))
        return images

    def features(self, images: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1] -> [B, 4, n, n]
        images = check_images(images, "composition teacher")
        rgb = self._working_frame(images.to(self._x.dtype))
        bsz, size, nf = rgb.shape[0], rgb.shape[-1], self._filters
        opp = torch.einsum("oc,bchw->bohw", self._opponent, rgb)  # [B, 3, s, s]
        r = self._radius
        padded = F.pad(opp, (r, r, r, r), mode="replicate")
        out = F.conv2d(F.conv2d(padded, self._filters_x, groups=3), self._filters_y, groups=3 * nf)
        out = out.view(bsz, 3, nf, size, size)  # [B, colour, filter, s, s]

        centre, surrounds = out[:, :, :1], out[:, :, 1 : nf - 2]
        d2 = (centre - surrounds).pow(2).sum(1)  # [B, surrounds, s, s]
        sal = ((d2 + _EPS).sqrt() - math.sqrt(_EPS)).mean(1)  # [B, s, s]

        gx, gy = out[:, :, nf - 2], out[:, :, nf - 1]  # [B, colour, s, s]
        tensor = _EDGE_GAIN * torch.stack([(gx * gx).sum(1), (gy * gy).sum(1), (gx * gy).sum(1)], 1)

        maps = F.adaptive_avg_pool2d(
            torch.cat([sal[:, None], tensor, centre[:, :, 0]], 1), self.feature_size
        )  # [B, 7, n, n]
        contrast, colour = maps[:, 0], maps[:, 4:]
        return torch.cat([(contrast * self._distinctiveness(colour, contrast))[:, None], maps[:, 1:4]], 1)

    def _distinctiveness(self, colour: Tensor, contrast: Tensor) -> Tensor:  # [B, 3, n, n], [B, n, n] -> [B, n, n]
        """How unlike the rest of the frame each cell's colour is, in ``(0, 1]``.

        With ``K[i, j]`` the similarity of the colours of cells ``i`` and ``j`` (Gaussian in
        opponent colour, chroma weighted up) and ``far[i, j]`` how far apart they are (``1 -
        Gaussian`` of their distance), two densities of cell ``i``'s colour, as means over the
        frame's cells: its *area* ``mean_j K[i, j]`` (a wall, a floor, a sky covers much of the
        frame), and its *repeated contrast* ``mean_j K[i, j] far[i, j] contrast[j]`` (a checker,
        stripes, tiles or floor boards put contrast into the same colours all over the frame,
        while a subject's own outline lies near it). The result is ``exp(-(area / share +
        repeated / amount))``: near 1 for a subject of its own colour, small for a large
        surface or a repeated pattern. (Chunks of the batch bound the ``[B, N, N]`` temporaries.)"""
        if colour.shape[0] > _DISTINCT_CHUNK:
            parts = zip(colour.split(_DISTINCT_CHUNK), contrast.split(_DISTINCT_CHUNK))
            return torch.cat([self._distinctiveness(col, con) for col, con in parts])
        c = (colour * self._colour_weights[:, None, None]).flatten(2).transpose(1, 2)  # [B, N, 3]
        sq = (c * c).sum(-1)  # [B, N]
        d2 = (sq[:, :, None] + sq[:, None, :] - 2 * c @ c.transpose(1, 2)).clamp_min(0.0)  # [B, N, N]
        similar = torch.exp(-d2 / (2 * _COLOUR_SIGMA**2))
        area = similar.mean(-1)  # [B, N]
        repeated = (similar * self._far * contrast.flatten(1)[:, None, :]).mean(-1)  # [B, N]
        return torch.exp(-(area / _AREA_SHARE + repeated / _REPEATED_CONTRAST)).view_as(contrast)

    # ---------------------------------------------------------------------- head
    def head(self, fmap: Tensor) -> Tensor:  # [B, 4, n, n] -> [B]
        return self._terms(fmap)["score"]

    def explain_map(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, 4, n, n] -> {name: [B]}
        return self._terms(fmap)

    def explain_scores(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, 4, n, n] -> {name: [B]}
        """:meth:`Teacher.explain_scores` in one compiled kernel (:mod:`composition_kernel
        <aes_planner.teachers.composition_kernel>`: the terms and the score's analytic gradient
        in one pass) where numba imports and the map is a float32 or float64 CPU tensor, else
        :meth:`explain_map`. The same values as :meth:`explain_map` up to float32 rounding (its
        intermediates in float64) and the gradient autograd computes; at a stage-2 step (2 maps)
        ~0.1 ms instead of ~4 ms of the torch head forward and backward (docs/benchmarks.md,
        "perf-2, seventh round")."""
        check_feature_map(fmap, self.feature_channels, self.feature_size, "composition teacher head")
        kernel = _compiled_head()
        if kernel is None or fmap.device.type != "cpu" or fmap.dtype not in (torch.float32, torch.float64):
            return super().explain_scores(fmap)
        score, rest = _CompiledHead.apply(fmap, kernel, self._kernel_tables())
        names = (*TERMS, "content", "subject_presence", "horizon_presence")  # the kernel's T_* columns after the score
        return {"score": score, **{name: rest[:, i] for i, name in enumerate(names)}}

    def warm(self) -> float | None:
        """:meth:`Teacher.warm`: the compiled head for float32 maps, forward and gradient (numba
        compiles it once per install, ~30-50 s on two cores, and loads it from its cache after)."""
        if _compiled_head() is None:
            return None
        t0 = time.perf_counter()
        fmap = torch.zeros(1, self.feature_channels, *self.feature_size, requires_grad=True)
        with torch.enable_grad():
            self.explain_scores(fmap)["score"].sum().backward()
        return time.perf_counter() - t0

    def _kernel_tables(self) -> tuple:
        """The head's tables (copies) and its constants (float64), in :func:`composition_kernel.head
        <aes_planner.teachers.composition_kernel.head>`'s order; rebuilt when a buffer changed."""
        bufs = (self._box3, self._annulus, self._thirds, self._x, self._y, self._ring, self._rows,
                self._row_blur, self._thirds_of_width, self._weights)  # fmt: skip
        key = tuple((t.data_ptr(), t._version, t.dtype) for t in bufs)
        cached = getattr(self, "_kernel_cache", None)
        if cached is None or cached[0] != key:
            # in the buffers' own dtype (the kernel computes in float64 whatever it reads): the
            # float32 annulus is half the memory traffic of a float64 copy, and the same values
            box3, annulus, *rest = (t.detach().cpu().numpy().copy() for t in bufs)
            arrays = tuple(np.ascontiguousarray(a) for a in (box3, box3.T, annulus, annulus.T, *rest))
            cfg = self.config
            consts = np.array(
                [_MAP_LIMIT, _TINY, _EPS, _OBJECT_ENERGY, _ISOLATION, _PRESENCE_MASS, _CONTENT_EDGE_FLOOR,
                 _CONTENT_EDGE, _CONTENT_OBJECT, _LINES_CONTENT, _SAL_FLOOR, _BALANCE_SIGMA, _RING_FLOOR,
                 _BORDER_FREE, _BORDER_SCALE, _AREA_GAIN, cfg.ideal_subject_area, _SIZE_LOG_SIGMA, _BUSY_ENERGY,
                 _CLUTTER_MID, _CLUTTER_WIDTH, _HORIZON_ENERGY, _HORIZON_SIGMA,
                 math.sin(math.radians(cfg.tilt_tolerance_deg))],
                dtype=np.float64,
            )  # fmt: skip
            cached = self._kernel_cache = (key, (*arrays, consts))
        return cached[1]

    def _terms(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, 4, n, n] -> {name: [B]}
        check_feature_map(fmap, self.feature_channels, self.feature_size, "composition teacher head")
        fmap = fmap.clamp(-_MAP_LIMIT, _MAP_LIMIT)  # real maps stay within about [-1, 1]
        cfg = self.config
        n = self.feature_size[0]
        sal = fmap[:, 0].clamp_min(0.0)  # [B, n, n]
        jxx, jyy, jxy = fmap[:, 1].clamp_min(0.0), fmap[:, 2].clamp_min(0.0), fmap[:, 3]
        energy = jxx + jyy
        dims = (1, 2)

        # Objects versus lines: the smaller eigenvalue of the structure tensor pooled over 3x3
        # cells (Shi-Tomasi at cell scale) is large where edges of several orientations meet
        # (objects, corners, foliage) and about zero along straight lines (wall edges, floor
        # boards, a horizon), which frame a view but are not a subject.
        a, b, c = (self._box3 @ m @ self._box3.T for m in (jxx, jyy, jxy))
        # (A tiny epsilon: sqrt(eps) biases every straight edge's value upwards.)
        corners = F.relu(0.5 * (a + b - ((a - b) ** 2 + 4 * c * c + _TINY).sqrt() + math.sqrt(_TINY)))
        objectness = (corners / (corners + _OBJECT_ENERGY)) ** 2  # [B, n, n] in [0, 1); squared: the
        # steps of a slightly tilted line leave a little corner energy that must not make it a subject
        salient = sal * objectness  # salient and object-like
        # Isolated rather than repeated: a subject stands out from its surround, while the cells
        # of a texture (checker, tiles, stripes filling the frame) are as strong as theirs.
        # Divisive normalisation by the mean evidence over an annulus around each cell (between
        # Gaussians of 3 and 6 cells, clipped to the frame), which leaves most of a compact
        # object's own outline out: about 1/(1 + k) of a uniform texture survives, most of a lone
        # object.
        surround = (salient.flatten(1) @ self._annulus).view_as(salient)
        subject = salient * salient / (salient + _ISOLATION * surround + _TINY)
        mass = subject.sum(dims)
        presence = 1.0 - torch.exp(-mass / _PRESENCE_MASS)  # [B]: is there a subject at all

        # How much there is to look at: objects count fully, lines at most half (a bare wall
        # corner or an empty horizon is half-empty); shading ramps stay under the floor.
        lines = 1.0 - torch.exp(-F.relu(energy - _CONTENT_EDGE_FLOOR).mean(dims) / _CONTENT_EDGE)
        content = 1.0 - torch.exp(-(corners.mean(dims) / _CONTENT_OBJECT + _LINES_CONTENT * lines))

        # Where the subject is: squared, so that it counts more than its halo.
        p = subject * subject + _SAL_FLOOR**2
        p = p / p.sum(dims, keepdim=True)
        thirds = (p * self._thirds).sum(dims)

        q = energy + _SAL_FLOOR**2
        q = q / q.sum(dims, keepdim=True)
        weight = 0.5 * (p + q)
        cx, cy = (weight * self._x).sum(dims), (weight * self._y).sum(dims)
        balance = torch.exp(-((cx - 0.5) ** 2 + 0.25 * (cy - 0.5) ** 2) / (2 * _BALANCE_SIGMA**2))

        # (From the salient evidence before isolation: an object cut by the frame edge shows little
        # contrast along it, and isolation would hide what little there is.)
        ring_share = (salient * self._ring).sum(dims) / (salient.sum(dims) + _RING_FLOOR * n * n)
        border = torch.exp(-F.relu(ring_share - _BORDER_FREE) / _BORDER_SCALE)

        # Area the subject spans: the ellipse of its second moments (2 pi sqrt(det cov) is the
        # area of a disc whose outline, or whole, carries the mass), in shares of the frame.
        s2 = subject * subject
        m = s2 / (s2.sum(dims, keepdim=True) + _TINY)
        mx, my = (m * self._x).sum(dims, keepdim=True), (m * self._y).sum(dims, keepdim=True)
        dx, dy = self._x - mx, self._y - my
        vxx, vyy, vxy = (m * dx * dx).sum(dims), (m * dy * dy).sum(dims), (m * dx * dy).sum(dims)
        area = _AREA_GAIN * 2 * math.pi * (F.relu(vxx * vyy - vxy * vxy) + _TINY).sqrt()
        subject_size = torch.exp(-(torch.log(area / cfg.ideal_subject_area) ** 2) / (2 * _SIZE_LOG_SIGMA**2))

        busy = (energy / (energy + _BUSY_ENERGY)).mean(dims)
        clutter = torch.sigmoid((_CLUTTER_MID - busy) / _CLUTTER_WIDTH)

        placement, level, horizon = self._horizon(jxx, jyy, jxy)

        terms = dict(
            thirds=thirds,
            balance=balance,
            border=border,
            horizon_placement=placement,
            horizon_level=level,
            clutter=clutter,
            subject_size=subject_size,
        )
        stacked = torch.stack([terms[t] for t in TERMS], -1)  # [B, T]
        ones = torch.ones_like(presence)
        # The horizon terms count as much as a horizon is present (weight and all: a view without
        # one is judged on the rest). The subject terms are *earned* in proportion to the subject's
        # presence while keeping their weight: a view without a subject scores as if they were 0.
        w = self._weights * torch.stack([horizon if t in _HORIZON_TERMS else ones for t in TERMS], -1)  # [B, T]
        earned = torch.stack([presence if t in _SUBJECT_TERMS else ones for t in TERMS], -1)
        composition = (w * earned * stacked).sum(-1) / (w.sum(-1) + _EPS)
        return {
            "score": content * composition,
            **terms,
            "content": content,
            "subject_presence": presence,
            "horizon_presence": horizon,
        }

    def _horizon(self, jxx: Tensor, jyy: Tensor, jxy: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(placement, level, presence) of the dominant frame-spanning near-horizontal line, each [B]."""
        n = jxx.shape[-1]
        # Near-horizontal line energy: > 0 for edges within ~40 deg of horizontal.
        line = F.relu(jyy - jxx - 0.25 * ((jxy * jxy + _EPS).sqrt() - math.sqrt(_EPS)))  # [B, n, n]
        # Line energy per row in each third of the width, smoothed over neighbouring rows so that
        # a slightly tilted line still spans the frame.
        parts = self._row_blur @ (line @ self._thirds_of_width)  # [B, n rows, 3]
        log_span = torch.log(parts + _EPS).mean(-1)  # [B, n]: geometric mean over the thirds
        span = torch.exp(log_span)
        w4 = torch.softmax(4.0 * log_span, -1)  # = span^4 / sum(span^4), without overflow
        strength = (w4 * span).sum(-1)
        presence = 1.0 - torch.exp(-strength / _HORIZON_ENERGY)
        y = (w4 * self._rows).sum(-1)  # [B]
        s2 = 2 * _HORIZON_SIGMA**2
        placement = (torch.exp(-((y - 1.0 / 3.0) ** 2) / s2) + torch.exp(-((y - 2.0 / 3.0) ** 2) / s2)).clamp(max=1.0)
        band = torch.exp(-((self._rows - y[:, None]) ** 2) / (2 * (2.0 / n) ** 2))[..., None]  # [B, n, 1]
        # For one straight line tilted by t: sum(xy) = g^2 sin t cos t, sum(yy) = g^2 cos^2 t,
        # so this is sin t, bounded whatever the map holds.
        sxy, syy = (band * jxy).sum((1, 2)), (band * jyy).sum((1, 2))
        sin_tilt = sxy / (syy * syy + sxy * sxy + _EPS).sqrt()
        tol = math.sin(math.radians(self.config.tilt_tolerance_deg))
        level = torch.exp(-(sin_tilt**2) / (2 * tol * tol))
        return placement, level, presence


_kernel_module = None
_kernel_error: str | None = None


def _compiled_head():
    """:mod:`aes_planner.teachers.composition_kernel` (numba), or None where numba does not import."""
    global _kernel_module, _kernel_error
    if _kernel_module is None and _kernel_error is None:
        try:
            from aes_planner.runtime import light_numba_cache_loads
            from aes_planner.teachers import composition_kernel

            light_numba_cache_loads()  # before its first cached load
            _kernel_module = composition_kernel
        except ImportError as exc:  # numba missing or broken: the torch head
            _kernel_error = f"{type(exc).__name__}: {exc}"
            log.info("composition head: compiled kernel unavailable (%s); the torch head runs", _kernel_error)
    return _kernel_module


class _CompiledHead(torch.autograd.Function):
    """The composition head's score (differentiable w.r.t. the map) and its other terms (not)."""

    @staticmethod
    def forward(ctx, fmap: Tensor, kernel, tables: tuple):  # [B, 4, n, n] -> [B], [B, NTERMS - 1]
        want_grad = bool(ctx.needs_input_grad[0])
        x = np.ascontiguousarray(fmap.detach().numpy())
        terms = np.empty((x.shape[0], kernel.NTERMS))  # float64
        grad = np.empty(x.shape if want_grad else (0, *x.shape[1:]), dtype=np.float64)
        kernel.head(x, *tables, want_grad, terms, grad)
        out = torch.from_numpy(terms).to(fmap.dtype)
        score, rest = out[:, 0].contiguous(), out[:, 1:]
        ctx.mark_non_differentiable(rest)
        if want_grad:
            ctx.save_for_backward(torch.from_numpy(grad).to(fmap.dtype))
        return score, rest

    @staticmethod
    def backward(ctx, grad_score: Tensor, grad_rest: Tensor):  # [B], [B, NTERMS - 1] -> [B, 4, n, n]
        (dscore,) = ctx.saved_tensors
        return grad_score[:, None, None, None] * dscore, None, None
