"""Benchmark group ``photos``: the pose step (pycolmap structure from motion) on a hand-held photo set.

Figures (medians of several runs after a warm-up):

* ``photos.pose_10x640.s``: ten 640 x 480 photos of a sim scene textured with the shipped CC0
  photographs (:func:`aes_planner.photos.simscene.cc0_photos`), a photographer walking an 80 degree arc, posed by
  :func:`aes_planner.photos.pose_images` (features, matching, mapping, undistortion, outputs).
  Target: under 30 s on 2 cores.
* ``photos.pose_10x640.cpu_s``: the CPU time of the same (every thread of the process): on a
  machine shared with other work the wall time grows with the load, this much less.
* ``photos.pose_10x640.<stage>_s``: the wall time of each stage (features, matching, mapping, undistort).
* ``photos.pose_10x640.registered``: photos registered of the ten.
* ``photos.pose_10x640.rotation_err_deg`` / ``centre_err_pct``: the largest rotation error and
  centre error (percent of the cameras' spread) after a similarity alignment with the truth.
* ``photos.pose_10x640.reprojection_px``: pycolmap's mean reprojection error.

:func:`render_photo_set` renders such a set (also used by the tests).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from aes_planner.bench import Recorder

__all__ = ["render_photo_set", "run"]


def render_photo_set(
    out_dir: str | Path,
    n: int = 10,
    size: tuple[int, int] = (640, 480),
    seed: int = 0,
    textures: Sequence[str | Path] | None = None,
    supersample: int = 2,
    poses: np.ndarray | None = None,
    hfov_deg: float = 60.0,
    board: str | None = None,
) -> tuple[Path, np.ndarray, Path]:
    """Render ``n`` photos (``IMG_0000.jpg``...) of :func:`~aes_planner.photos.simscene.photo_scene`
    from :func:`~aes_planner.photos.simscene.arc_poses` (or ``poses [n, 4, 4]``) into
    ``out_dir/images``; returns the images folder, the true cam2world ``[n, 4, 4]`` and the scene file.
    ``textures`` defaults to the shipped CC0 photographs (:func:`~aes_planner.photos.simscene.cc0_photos`);
    an empty sequence puts dead-leaves images (:func:`~aes_planner.photos.simscene.dead_leaves_textures`)
    in their place."""
    import cv2
    import yaml

    from aes_planner.photos.simscene import arc_poses, cc0_photos, dead_leaves_textures, photo_scene
    from aes_planner.sim import load_scene, render

    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    if textures is None:
        textures = cc0_photos()
    if not textures:
        textures = dead_leaves_textures(out / "textures", seed=seed)
    scene_file = out / "scene.yaml"
    scene_file.write_text(
        yaml.safe_dump(photo_scene(textures, seed=seed, camera=(size[0], size[1], hfov_deg), board=board))
    )
    scene = load_scene(scene_file, allow_outside=True)
    truth = arc_poses(n, seed=seed) if poses is None else np.asarray(poses, np.float64)
    k = scene.intrinsics()
    for i, pose in enumerate(truth):
        rgb = render(scene, pose, k, supersample=supersample).rgb  # [H, W, 3] uint8
        cv2.imwrite(str(out / "images" / f"IMG_{i:04d}.jpg"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                    [cv2.IMWRITE_JPEG_QUALITY, 92])  # fmt: skip
    return out / "images", truth, scene_file


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.photos import PoseConfig, pose_errors, pose_images
    from aes_planner.photos.sfm import import_pycolmap

    pycolmap = import_pycolmap()

    rec.meta["backends"]["photos"] = f"pycolmap {pycolmap.__version__} (CPU)"
    runs = 1 if quick else 3
    with tempfile.TemporaryDirectory(prefix="bench-photos-") as tmp:
        images, truth, _ = render_photo_set(Path(tmp) / "set", 10, (640, 480), seed=0)
        times, cpu, results = [], [], []
        for i in range(runs + 1):  # the first run warms the caches (and is not timed)
            t0, c0 = time.perf_counter(), time.process_time()
            result = pose_images(images, Path(tmp) / f"posed{i}", PoseConfig())
            if i:
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                results.append(result)
        rec.record("photos.pose_10x640.s", statistics.median(times), "s", runs)
        rec.record("photos.pose_10x640.cpu_s", statistics.median(cpu), "s", runs)
        for stage in results[-1].timings_s:
            rec.record(
                f"photos.pose_10x640.{stage}_s", statistics.median(r.timings_s[stage] for r in results), "s", runs
            )
        last = results[-1]
        idx = [int(name[4:8]) for name in last.registered]
        errors = pose_errors(last.cam2world, truth[idx])
        rec.record("photos.pose_10x640.registered", len(last.registered), "photos")
        rec.record("photos.pose_10x640.rotation_err_deg", float(errors.rotation_deg.max()), "deg")
        rec.record("photos.pose_10x640.centre_err_pct", float(100 * errors.centre_frac.max()), "%")
        rec.record("photos.pose_10x640.reprojection_px", last.mean_reprojection_px, "px")
