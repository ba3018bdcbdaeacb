"""The composition teacher: a differentiable, weight-free model of framing and composition.

It is the default teacher and what the whole product maximises, so every term is built from
image evidence that a bad view cannot fake cheaply, and the score is gated by how much there is
to look at (a blank wall or an empty sky scores about zero).

**Features** (``features(images) -> [B, 5, 16, 16]``; the analogue of VEN's 14x14 pool4 map,
but 5 channels instead of 512 so that the field renders it cheaply). The image is resampled to a
64x64 working frame (area averaging down, bilinear up; composition is judged in normalised frame
coordinates, so the aspect ratio is not kept) and converted to an opponent colour space
(luminance ``L``, red-green, yellow-blue). Per 4x4 cell:

====  ==============  ====================================================================
 ch   name            meaning
====  ==============  ====================================================================
 0    ``saliency``    centre-surround colour contrast: distance in opponent colour between
                      a fine blur and two coarse surrounds (Itti-style difference of
                      Gaussians), so compact things that differ from their surroundings
                      stand out and uniform regions do not
 1    ``edge_xx``     mean ``gx^2`` of the colour gradient (vertical-edge energy)
 2    ``edge_yy``     mean ``gy^2`` (horizontal-edge energy)
 3    ``edge_xy``     mean ``gx*gy``; with 1 and 2 the pooled structure tensor, which gives
                      the edge energy at any orientation ``t`` as
                      ``xx*cos^2 t + 2*xy*sin t*cos t + yy*sin^2 t``
 4    ``luminance``   mean luminance
====  ==============  ====================================================================

**Head** (``head(fmap) -> [B]``; a few dozen tensor ops on the 16x16 map, no weights). Each
term lies in ``[0, 1]``, higher is better:

* ``thirds`` -- share of the salient mass on the rule-of-thirds template (Gaussians at the four
  power points, weaker ridges along the four third lines). A subject on a power point scores
  about 0.8, a centred one about 0.05, an evenly spread image about 0.25.
* ``balance`` -- the visual-weight centroid (saliency and edge energy) lies near the horizontal
  centre (vertical offsets count a quarter as much). A lone subject on a third scores about 0.6.
* ``border`` -- no subject cut by the frame: the share of the saliency in the one-cell frame
  ring beyond 0.15 (a horizon crossing the frame stays under it) decays the term.
* ``horizon_placement`` -- the dominant frame-spanning near-horizontal line (horizon, floor or
  table line) lies on a third rather than in the middle.
* ``horizon_level`` -- that line is level (a 2.5 deg tilt costs about 40 %, 5 deg about 85 %).
* ``clutter`` -- clean versus busy: the share of cells with strong edges; 1 for a clean frame
  with a few strong lines, about 0 when edges fill the frame.
* ``subject_size`` -- the salient mass covers a sensible part of the frame: its effective area
  (inverse participation ratio of the saliency) near 15 %, log-normal falloff, so specks and
  frame-filling textures score low.

and two factors that say how the terms are combined:

* ``content`` -- how much there is to look at (mean saliency, edge strength and tonal
  contrast), ``1 - exp(-evidence)``: about 0 for a blank wall, a black frame or an empty sky,
  above 0.9 with one clear subject.
* ``horizon_presence`` -- how strongly a frame-spanning horizontal line is present, in
  ``[0, 1]``; the two horizon terms count only in proportion to it.

**Score**, in ``[0, 1]``::

    score = content * sum_k(w_k * term_k) / sum_k(w_k)

with the weights of :class:`CompositionWeights` (horizon weights multiplied by
``horizon_presence``). A featureless view scores near 0, an ordinary snapshot 0.4-0.6, a clean
subject on a third with a level horizon on the other third above 0.8.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor

from aes_planner.config import require, require_finite
from aes_planner.teachers.base import Teacher, check_feature_map, check_images

__all__ = ["CompositionConfig", "CompositionWeights", "CompositionTeacher", "TERMS", "CHANNELS"]

#: Feature-map channels, in order.
CHANNELS = ("saliency", "edge_xx", "edge_yy", "edge_xy", "luminance")
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

# Calibration constants of the head (fixed; the tests pin their effect). Energies are per cell
# of the 16x16 map for images in [0, 1].
_EPS = 1e-6
_MAP_LIMIT = 1e3  # the head clamps rendered maps to +-this before anything can overflow
_SAL_FLOOR = 1e-3  # saliency any cell is assumed to have: a blank frame reads as uniform
_EDGE_GAIN = 4.0
_CONTENT_SAL_FLOOR = 0.01  # saliency below this is not content
_CONTENT_SAL = 0.004  # mean saliency above the floor worth one unit of content evidence
_CONTENT_EDGE_FLOOR = 3e-4  # edge energy below this (a smooth shading ramp) is not content
_CONTENT_EDGE = 5e-4  # mean edge energy above the floor worth one unit
_CONTENT_TONE = 0.01  # mean local tonal contrast worth one unit
_BALANCE_SIGMA = 0.18
_BORDER_FREE = 0.15  # share of saliency on the frame ring that costs nothing
_BORDER_SCALE = 0.1
_BUSY_ENERGY = 0.004  # a cell with this edge energy counts half busy
_CLUTTER_MID, _CLUTTER_WIDTH = 0.35, 0.07
_SIZE_LOG_SIGMA = 1.0
_HORIZON_ENERGY = 0.05  # line energy per third of the width for presence 0.63
_HORIZON_SIGMA = 0.06  # of the frame height, around each third


@dataclass(frozen=True)
class CompositionWeights:
    """Weights of the terms in the score (non-negative, at least one positive)."""

    thirds: float = 1.0
    balance: float = 0.5
    border: float = 1.0
    horizon_placement: float = 0.5
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
        require(isinstance(self.work_size, int) and self.work_size >= 16, "work_size", f"must be an integer >= 16, got {self.work_size!r}")
        require(
            isinstance(self.feature_size, int) and 3 <= self.feature_size <= self.work_size and self.work_size % self.feature_size == 0,
            "feature_size",
            f"must be an integer >= 3 that divides work_size={self.work_size}, got {self.feature_size!r}",
        )
        for name, lo, hi in (("thirds_sigma", 0.01, 0.5), ("tilt_tolerance_deg", 0.1, 45.0), ("ideal_subject_area", 0.005, 1.0)):
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


class CompositionTeacher(Teacher):
    """Composition teacher (the default): see the module docstring for the map, terms and score."""

    name = "composition"
    score_range = "[0, 1]: ~0 empty or featureless, 0.4-0.6 ordinary, > 0.8 well composed"

    _CENTRE_SIGMA = 1.0  # px of the working frame
    _SURROUND_SIGMAS = (4.0, 10.0)

    def __init__(self, config: CompositionConfig | None = None):
        super().__init__()
        self.config = cfg = config or CompositionConfig()
        n = cfg.feature_size
        self.feature_channels = len(CHANNELS)
        self.feature_size = (n, n)
        # Every filter of the working frame in one separable pass per axis: per opponent channel,
        # the centre blur, the surround blurs, and the Sobel derivatives of the centre blur.
        # (Few large convolutions: the thread pool's start-up, not arithmetic, dominates here.)
        sigmas = (self._CENTRE_SIGMA, *self._SURROUND_SIGMAS)
        blurs = [_gaussian_kernel(sg) for sg in sigmas]
        diff = torch.tensor([-0.5, 0.0, 0.5])  # Sobel = [1, 2, 1] / 4 across times this along, /8 in all
        smooth = torch.tensor([0.25, 0.5, 0.25])
        centre = blurs[0]
        d_centre = torch.conv1d(F.pad(centre, (1, 1))[None, None], diff.flip(0)[None, None])[0, 0]
        s_centre = torch.conv1d(F.pad(centre, (1, 1))[None, None], smooth[None, None])[0, 0]
        along_x = [*blurs, d_centre, s_centre]  # outputs: blurs..., gx, gy
        along_y = [*blurs, s_centre, d_centre]
        radius = max(k.numel() for k in along_x) // 2
        self._filters = len(along_x)
        self._radius = radius

        def bank(kernels: list[Tensor]) -> Tensor:  # -> [3 * F, K]
            padded = [F.pad(k, ((2 * radius + 1 - k.numel()) // 2,) * 2) for k in kernels]
            return torch.stack(padded).repeat(3, 1)

        self.register_buffer("_filters_x", bank(along_x)[:, None, None, :], persistent=False)  # [3F, 1, 1, K]
        self.register_buffer("_filters_y", bank(along_y)[:, None, :, None], persistent=False)  # [3F, 1, K, 1]
        opponent = torch.tensor([[0.299, 0.587, 0.114], [0.5, -0.5, 0.0], [0.25, 0.25, -0.5]])
        self.register_buffer("_opponent", opponent, persistent=False)  # rows: L, red-green, yellow-blue

        c = (torch.arange(n, dtype=torch.float64) + 0.5) / n
        y, x = torch.meshgrid(c, c, indexing="ij")
        thirds = (1.0 / 3.0, 2.0 / 3.0)
        s = cfg.thirds_sigma
        points = torch.stack([torch.exp(-((x - a) ** 2 + (y - b) ** 2) / (2 * s * s)) for a in thirds for b in thirds]).amax(0)
        ridge = torch.stack(
            [torch.exp(-((x - a) ** 2) / (2 * (s / 2) ** 2)) for a in thirds] + [torch.exp(-((y - a) ** 2) / (2 * (s / 2) ** 2)) for a in thirds]
        ).amax(0)
        ring = torch.zeros(n, n, dtype=torch.float64)
        ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = 1.0
        self.register_buffer("_x", x.float(), persistent=False)
        self.register_buffer("_y", y.float(), persistent=False)
        self.register_buffer("_thirds", torch.maximum(points, 0.5 * ridge).float(), persistent=False)
        self.register_buffer("_ring", ring.float(), persistent=False)
        self.register_buffer("_rows", c.float(), persistent=False)
        self.register_buffer("_box3", _smoothing_matrix(n, torch.full((3,), 1.0 / 3.0)), persistent=False)
        self.register_buffer("_row_blur", _smoothing_matrix(n, _gaussian_kernel(1.0)), persistent=False)
        groups = torch.zeros(n, 3)  # column -> left / middle / right third of the width
        for j, (a, b) in enumerate(zip((0, n // 3, n - n // 3), (n // 3, n - n // 3, n))):
            groups[a:b, j] = 1.0
        self.register_buffer("_thirds_of_width", groups, persistent=False)
        w = torch.tensor([cfg.weights.__dict__[t] for t in TERMS], dtype=torch.float32)
        self.register_buffer("_weights", w, persistent=False)
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

    def features(self, images: Tensor) -> Tensor:  # [B, 3, H, W] in [0, 1] -> [B, 5, n, n]
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

        maps = torch.cat([sal[:, None], tensor, opp[:, :1]], 1)  # [B, 5, s, s]
        return F.adaptive_avg_pool2d(maps, self.feature_size)

    # ---------------------------------------------------------------------- head
    def head(self, fmap: Tensor) -> Tensor:  # [B, 5, n, n] -> [B]
        return self._terms(fmap)["score"]

    def explain_map(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, 5, n, n] -> {name: [B]}
        return self._terms(fmap)

    def _terms(self, fmap: Tensor) -> dict[str, Tensor]:  # [B, 5, n, n] -> {name: [B]}
        check_feature_map(fmap, self.feature_channels, self.feature_size, "composition teacher head")
        fmap = fmap.clamp(-_MAP_LIMIT, _MAP_LIMIT)  # real maps stay within about [-1, 1]
        cfg = self.config
        n = self.feature_size[0]
        sal = fmap[:, 0].clamp_min(0.0)  # [B, n, n]
        jxx, jyy, jxy = fmap[:, 1].clamp_min(0.0), fmap[:, 2].clamp_min(0.0), fmap[:, 3]
        lum = fmap[:, 4]
        energy = jxx + jyy
        dims = (1, 2)

        # How much there is to look at: salient cells, edges and local tonal contrast. Weak,
        # uniform signals (a shading gradient, an overcast sky) stay under the floors.
        local_tone = (lum - self._box3 @ lum @ self._box3.T).abs()  # against the 3x3-cell mean
        evidence = (
            F.relu(sal - _CONTENT_SAL_FLOOR).mean(dims) / _CONTENT_SAL
            + F.relu(energy - _CONTENT_EDGE_FLOOR).mean(dims) / _CONTENT_EDGE
            + local_tone.mean(dims) / _CONTENT_TONE
        )
        content = 1.0 - torch.exp(-evidence)

        # Where the salient mass is: squared saliency favours the subject over its halo.
        p = sal * sal + _SAL_FLOOR**2
        p = p / p.sum(dims, keepdim=True)
        thirds = (p * self._thirds).sum(dims)

        q = energy + _SAL_FLOOR**2
        q = q / q.sum(dims, keepdim=True)
        weight = 0.5 * (p + q)
        cx, cy = (weight * self._x).sum(dims), (weight * self._y).sum(dims)
        balance = torch.exp(-((cx - 0.5) ** 2 + 0.25 * (cy - 0.5) ** 2) / (2 * _BALANCE_SIGMA**2))

        ring_share = (sal * self._ring).sum(dims) / (sal.sum(dims) + _SAL_FLOOR * n * n)
        border = torch.exp(-F.relu(ring_share - _BORDER_FREE) / _BORDER_SCALE)

        area = 1.0 / (n * n * (p * p).sum(dims))
        subject_size = torch.exp(-torch.log(area / cfg.ideal_subject_area) ** 2 / (2 * _SIZE_LOG_SIGMA**2))

        busy = (energy / (energy + _BUSY_ENERGY)).mean(dims)
        clutter = torch.sigmoid((_CLUTTER_MID - busy) / _CLUTTER_WIDTH)

        placement, level, presence = self._horizon(jxx, jyy, jxy)

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
        gate = torch.stack([presence if t.startswith("horizon") else torch.ones_like(presence) for t in TERMS], -1)
        w = self._weights * gate  # [B, T]: the horizon terms count as much as a horizon is present
        composition = (w * stacked).sum(-1) / (w.sum(-1) + _EPS)
        return {"score": content * composition, **terms, "content": content, "horizon_presence": presence}

    def _horizon(self, jxx: Tensor, jyy: Tensor, jxy: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(placement, level, presence) of the dominant frame-spanning near-horizontal line, each [B]."""
        n = jxx.shape[-1]
        # Near-horizontal line energy: > 0 for edges within ~30 deg of horizontal.
        line = F.relu(jyy - jxx - (jxy * jxy + _EPS).sqrt() + math.sqrt(_EPS))  # [B, n, n]
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
