"""Benchmark group ``reconstruct``: reconstruction quality against the simulator, count and speed.

Scenes: ``indoor:3``, ``gallery:1``, ``tabletop:2`` (``--quick``: the first only), 128 x 96 frames.
Figures are medians over scenes (and over held-out views within a scene: their mean PSNR).

* **Trajectories.** *Dolly*: the camera slides sideways at the rig's height over 0.3 x the
  median depth it sees, looking where the rig's pan range is centred (depth and stereo modes;
  stereo sees RGB only). *Rig*: pan-tilt joint poses through the rig's kinematics over an 80 degree pan window (sphere
  mode, RGB only; ``depth_rig`` gives the same frames their depth, for comparison). Inputs are
  ``n`` poses spread over the trajectory; held-out poses lie between them.
* ``reconstruct.<mode>_<n>v.psnr_db`` (n = 2, 4, 6; ``--quick``: 4): PSNR of the reconstruction
  rendered at held-out poses against the simulator's ground truth (frames and truth rendered with
  3 x 3 anti-aliasing, as a lens gives), all pixels (black where nothing is drawn);
  ``.coverage`` the fraction of those pixels drawn (alpha > 0.5); ``.count`` Gaussians.
* ``reconstruct.depth_rig_4v.*``: the sphere mode's rig frames given their depth (what depth
  would buy on a rig).
* PSNR against count (depth mode, 4 dolly views): ``reconstruct.raw.{psnr_db,count}`` keeps every
  splat of every frame (no merging, pruning or budget); ``reconstruct.unpruned.*`` merges
  overlapping frames but neither prunes nor budgets; ``reconstruct.budget_<r>.*`` for budget
  ratios ``r`` and ``reconstruct.budget_default.*`` for the default, each with ``psnr_db``,
  ``count``, ``fraction`` (count / unpruned count), ``fraction_of_raw`` and ``psnr_loss_db``
  (unpruned PSNR minus this one, per scene, median).
* ``reconstruct.stereo.abs_rel`` (median |d - d_true| / d_true over the pixels stereo keeps after
  the consistency check), ``.within_5pct`` (% of those within 5 %), ``.density`` (% of pixels
  given a depth), ``.abs_rel_unchecked`` (before the check); 4 dolly frames, each matched with
  the frames beside it.
* ``reconstruct.build_4x128.ms``: depth mode from 4 frames of 128 x 128 (median of runs);
  ``reconstruct.stream_frame.ms``: one ``add_frame`` of a 128 x 96 frame into a map at its budget.
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import replace

import numpy as np

from aes_planner.bench import Recorder
from aes_planner.geometry import Intrinsics, view_to_cam2world
from aes_planner.messages import PosedFrame
from aes_planner.reconstruct import ReconstructConfig, Reconstructor, reconstruct
from aes_planner.reconstruct.stereo import consistent_depth, plane_sweep_depth

SCENES = ("indoor:3", "gallery:1", "tabletop:2")
WIDTH, HEIGHT = 128, 96
VIEW_COUNTS = (2, 4, 6)
BUDGET_RATIOS = (0.05, 0.1, 0.2, 0.3, 0.5)
DOLLY_SPAN = 0.3  # dolly length relative to the median depth seen from its middle
RIG_WINDOW_RAD = math.radians(80.0)
RIG_TILT_RAD = 0.08  # rig inputs alternate this far above and below the held-out tilt
SUPERSAMPLE = 3  # anti-aliased frames and ground truth, as a real lens gives


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR of two uint8 images (any shape), in dB; capped at 100 for identical images."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 100.0 if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def to_uint8(rgb) -> np.ndarray:
    """A rasterizer image ``[3, H, W]`` (torch) -> ``[H, W, 3]`` uint8."""
    return (rgb.detach().clamp(0, 1).permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)


class SimSource:
    """Frames and ground truth of one sim scene along the two bench trajectories."""

    def __init__(self, spec: str, width: int = WIDTH, height: int = HEIGHT, supersample: int = SUPERSAMPLE):
        self.supersample = supersample
        self._cache: dict[bytes, object] = {}  # renders by pose: cases share frames
        from aes_planner.sim import load_scene, render

        self.scene = load_scene(spec)
        rig = self.scene.rig
        self.kin = rig.kinematics()
        self.intrinsics = Intrinsics.from_fov(width, height, rig.camera.hfov_deg)
        (plo, phi), (tlo, thi) = self.kin.pan_limits_rad, self.kin.tilt_limits_rad
        self.pan0, self.tilt0 = 0.5 * (plo + phi), 0.5 * (tlo + thi)
        self.base = np.asarray(rig.pan_tilt.base_xyz_m, np.float64)
        centre = render(self.scene, self.dolly(0.5, span_m=0.0), self.intrinsics).depth_m
        self.dolly_span_m = DOLLY_SPAN * float(np.median(centre[centre > 0])) if (centre > 0).any() else 1.0

    def _render(self, cam2world: np.ndarray):
        from aes_planner.sim import render

        key = np.asarray(cam2world, np.float64).tobytes()
        if key not in self._cache:
            self._cache[key] = render(self.scene, cam2world, self.intrinsics, self.supersample)
        return self._cache[key]

    def frame(self, cam2world: np.ndarray, with_depth: bool) -> PosedFrame:
        out = self._render(cam2world)
        return PosedFrame(out.rgb, self.intrinsics, cam2world, depth_m=out.depth_m if with_depth else None)

    def truth(self, cam2world: np.ndarray) -> np.ndarray:
        return self._render(cam2world).rgb

    def dolly(self, t: float, yaw_jitter: float = 0.0, span_m: float | None = None) -> np.ndarray:
        """Pose at ``t`` in [0, 1] along the sideways slide."""
        span = self.dolly_span_m if span_m is None else span_m
        yaw, pitch = self.pan0 + yaw_jitter, min(max(self.tilt0, -0.3), 0.1) - 0.1
        side = np.array([-math.sin(self.pan0), math.cos(self.pan0), 0.0])
        eye = self.base + (t - 0.5) * span * side
        return view_to_cam2world(np.array([*eye, yaw, pitch]))

    def rig(self, t: float, tilt_offset: float = 0.0) -> np.ndarray:
        """Rig pose at ``t`` in [0, 1] across the pan window."""
        pan = self.pan0 + (t - 0.5) * RIG_WINDOW_RAD
        return self.kin.forward(pan, self.tilt0 + tilt_offset)


def inputs_and_held_out(n: int) -> tuple[list[float], list[float]]:
    """``n`` input positions in [0, 1] and held-out positions halfway between neighbours."""
    ts = list(np.linspace(0.0, 1.0, n))
    held = [0.5 * (a + b) for a, b in zip(ts[:-1], ts[1:])]
    return ts, held[:: max(1, len(held) // 3)][:3]


def evaluate(recon, source: SimSource, poses: list[np.ndarray]) -> tuple[float, float]:
    """Mean PSNR (dB) and coverage of ``recon`` rendered at world ``poses``."""
    psnrs, cover = [], []
    for c2w in poses:
        out = recon.render(c2w, source.intrinsics)
        psnrs.append(psnr_db(to_uint8(out.rgb[0]), source.truth(c2w)))
        cover.append(float((out.alpha[0] > 0.5).float().mean()))
    return float(np.mean(psnrs)), float(np.mean(cover))


def case(source: SimSource, mode: str, n: int, config: ReconstructConfig) -> tuple[float, float, int]:
    """PSNR, coverage and count of one mode with ``n`` input views on one scene."""
    ts, held = inputs_and_held_out(n)
    if mode == "sphere" or mode == "depth_rig":
        poses = [source.rig(t, RIG_TILT_RAD * (-1) ** i) for i, t in enumerate(ts)]
        held_poses = [source.rig(t) for t in held]
    else:
        poses = [source.dolly(t) for t in ts]
        held_poses = [source.dolly(t, 0.05) for t in held]
    with_depth = mode in ("depth", "depth_rig")
    frames = [source.frame(p, with_depth) for p in poses]
    cfg = replace(config, mode="depth" if with_depth else mode)
    recon = reconstruct(frames, cfg)
    psnr, cover = evaluate(recon, source, held_poses)
    return psnr, cover, len(recon.gaussians)


def stereo_error(source: SimSource, n: int = 4) -> tuple[float, float, float, float]:
    """Stereo depth against the simulator's on the dolly frames, each matched with the frames
    beside it and kept where a neighbour agrees (as the reconstructor does): (median abs rel,
    % within 5 %, % of pixels given a depth, median abs rel before the consistency check)."""
    ts, _ = inputs_and_held_out(n)
    frames = [source.frame(source.dolly(t), with_depth=True) for t in ts]
    rgb = [PosedFrame(f.image, f.intrinsics, f.cam2world) for f in frames]
    cfg = ReconstructConfig()
    nbs = [[j for j in (i - 1, i + 1) if 0 <= j < len(rgb)] for i in range(len(rgb))]
    raw = [plane_sweep_depth(rgb[i], [rgb[j] for j in nbs[i]], cfg.stereo).depth_m for i in range(len(rgb))]
    rel, raw_rel, dense = [], [], []
    for i, f in enumerate(frames):
        kept = consistent_depth(rgb[i], raw[i], [(rgb[j], raw[j]) for j in nbs[i]], cfg.stereo_consistency)
        for depth, out in ((kept, rel), (raw[i], raw_rel)):
            ok = (depth > 0) & (f.depth_m > 0)
            out.append(np.abs(depth[ok] - f.depth_m[ok]) / f.depth_m[ok])
        dense.append(float(((kept > 0) & (f.depth_m > 0)).mean()))
    r = np.concatenate(rel)
    return (
        float(np.median(r)),
        100.0 * float((r < 0.05).mean()),
        100.0 * float(np.mean(dense)),
        float(np.median(np.concatenate(raw_rel))),
    )


def _record_cases(rec: Recorder, key: str, results: list[tuple[float, float, int]]) -> None:
    rec.record(f"{key}.psnr_db", statistics.median(r[0] for r in results), "dB", runs=len(results))
    rec.record(f"{key}.coverage", statistics.median(r[1] for r in results), "fraction", runs=len(results))
    rec.record(f"{key}.count", statistics.median(r[2] for r in results), "gaussians", runs=len(results))


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.gaussians import resolve_backend

    rec.meta["backends"]["reconstruct"] = (
        f"rasterizer {resolve_backend()}; sim frames {WIDTH}x{HEIGHT}, {SUPERSAMPLE}x{SUPERSAMPLE} anti-aliased"
    )
    scenes = SCENES[:1] if quick else SCENES
    sources = [SimSource(s) for s in scenes]
    base = ReconstructConfig()
    counts = (4,) if quick else VIEW_COUNTS
    for mode in ("depth", "stereo", "sphere"):
        for n in counts:
            _record_cases(rec, f"reconstruct.{mode}_{n}v", [case(src, mode, n, base) for src in sources])
    _record_cases(rec, "reconstruct.depth_rig_4v", [case(src, "depth_rig", 4, base) for src in sources])

    # PSNR against Gaussian count (depth, 4 dolly views): every splat of every frame (raw), merged
    # overlapping frames without pruning or budget (unpruned), budgets, and the default
    raw = [
        case(src, "depth", 4, replace(base, dedupe=False, budget_ratio=0.0, min_contribution=0.0)) for src in sources
    ]
    ref = [case(src, "depth", 4, replace(base, budget_ratio=0.0, min_contribution=0.0)) for src in sources]
    for name, res in (("raw", raw), ("unpruned", ref)):
        rec.record(f"reconstruct.{name}.psnr_db", statistics.median(r[0] for r in res), "dB", runs=len(res))
        rec.record(f"reconstruct.{name}.count", statistics.median(r[2] for r in res), "gaussians", runs=len(res))
    ratios = (0.1,) if quick else BUDGET_RATIOS
    for name, cfg in [(f"budget_{r:g}", replace(base, budget_ratio=r)) for r in ratios] + [("budget_default", base)]:
        res = [case(src, "depth", 4, cfg) for src in sources]
        rec.record(f"reconstruct.{name}.psnr_db", statistics.median(r[0] for r in res), "dB", runs=len(res))
        rec.record(f"reconstruct.{name}.count", statistics.median(r[2] for r in res), "gaussians", runs=len(res))
        rec.record(
            f"reconstruct.{name}.fraction",
            statistics.median(r[2] / u[2] for r, u in zip(res, ref)),
            "fraction",
            runs=len(res),
        )
        rec.record(
            f"reconstruct.{name}.fraction_of_raw",
            statistics.median(r[2] / u[2] for r, u in zip(res, raw)),
            "fraction",
            runs=len(res),
        )
        rec.record(
            f"reconstruct.{name}.psnr_loss_db",
            statistics.median(u[0] - r[0] for r, u in zip(res, ref)),
            "dB",
            runs=len(res),
        )
    rec.meta["reconstruct_default_budget_ratio"] = base.budget_ratio

    errs = [stereo_error(src) for src in sources]
    rec.record("reconstruct.stereo.abs_rel", statistics.median(e[0] for e in errs), "fraction", runs=len(errs))
    rec.record("reconstruct.stereo.within_5pct", statistics.median(e[1] for e in errs), "%", runs=len(errs))
    rec.record("reconstruct.stereo.density", statistics.median(e[2] for e in errs), "%", runs=len(errs))
    rec.record(
        "reconstruct.stereo.abs_rel_unchecked", statistics.median(e[3] for e in errs), "fraction", runs=len(errs)
    )

    # speed: 4 frames of 128 x 128 with depth; one frame streamed into a map at its budget
    sq = SimSource(scenes[0], 128, 128)
    frames128 = [sq.frame(sq.dolly(t), with_depth=True) for t in np.linspace(0, 1, 4)]
    cfg = replace(base, mode="depth")
    rec.time("reconstruct.build_4x128.ms", lambda: reconstruct(frames128, cfg), runs=3 if quick else 7)
    stream = Reconstructor(cfg)
    src = sources[0]
    frames = [src.frame(src.rig(t), with_depth=True) for t in np.linspace(0, 1, 8)]
    for f in frames:
        stream.add_frame(f)
    cycle = itertools.cycle(frames)
    rec.time("reconstruct.stream_frame.ms", lambda: stream.add_frame(next(cycle)), runs=5 if quick else 15)
