"""Procedural families: seeded, reproducible, round-trip through YAML, and worth pointing at."""

import numpy as np
import pytest

from aes_planner.sim import FAMILIES, load_scene, render, save_scene
from aes_planner.sim.shapes import SHAPES

SEEDS = (0, 1, 2)


def test_the_four_families():
    assert list(FAMILIES) == ["indoor", "outdoor", "tabletop", "gallery"]


@pytest.mark.parametrize("family", FAMILIES)
def test_seeded_and_reproducible(family):
    a, b, c = FAMILIES[family](3), FAMILIES[family](3), FAMILIES[family](4)
    assert a == b
    assert a != c
    assert load_scene(f"{family}:3").spec == a
    assert a.rig is not None and a.drone is None
    assert len(a.objects) >= 20


@pytest.mark.parametrize("family", FAMILIES)
def test_yaml_round_trip_gives_the_same_render(family, tmp_path):
    scene = load_scene(f"{family}:1")
    back = load_scene(save_scene(scene, tmp_path / f"{family}.yaml"))
    assert back.spec == scene.spec
    kin = scene.rig.kinematics()
    k = scene.rig.intrinsics().scaled(48, 36)
    for pan, tilt in kin.joint_grid(2, 2):
        a, b = render(scene, kin.forward(pan, tilt), k), render(back, kin.forward(pan, tilt), k)
        assert (
            np.array_equal(a.rgb, b.rgb)
            and np.array_equal(a.depth_m, b.depth_m)
            and np.array_equal(a.instance_id, b.instance_id)
        )


def _inside(scene, point) -> list[str]:
    """Names of the bounded objects that contain ``point [3]``."""
    names = []
    for k, obj in enumerate(scene.objects):
        kind = SHAPES[scene.kind[k]].kind
        p = scene.rotations[k].T @ (point - scene.centres[k])
        d = scene.dims[k]
        inside = {
            "box": np.all(np.abs(p) <= d),
            "sphere": np.linalg.norm(p) <= d[0],
            "cylinder": np.hypot(p[0], p[1]) <= d[0] and abs(p[2]) <= d[2],
        }.get(kind, False)
        if inside:
            names.append(obj.name)
    return names


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("seed", SEEDS)
def test_the_rig_sweep_sees_strong_and_weak_views(family, seed):
    scene = load_scene(f"{family}:{seed}")
    kin = scene.rig.kinematics()
    k = scene.rig.intrinsics().scaled(64, 48)
    subjects = []
    for pan, tilt in kin.joint_grid(7, 3):
        pose = kin.forward(pan, tilt)
        assert not _inside(scene, pose[:3, 3]), f"camera inside {_inside(scene, pose[:3, 3])}"
        out = render(scene, pose, k)
        assert out.depth_m[out.instance_id > 0].min(initial=np.inf) > 0.1  # nothing touching the lens
        counts = np.bincount(out.instance_id.ravel(), minlength=len(scene.objects) + 1)[1:]
        subjects.append(int((counts >= 0.005 * out.instance_id.size).sum()))
    assert max(subjects) >= 7, subjects  # somewhere: several distinct things in frame
    assert min(subjects) <= 3, subjects  # somewhere: a bare wall, floor or sky


@pytest.mark.parametrize("family", FAMILIES)
def test_scenes_differ_in_content_not_just_colour(family):
    names = [sorted({o.name.rstrip("0123456789_") for o in FAMILIES[family](seed).objects}) for seed in range(6)]
    counts = [len(FAMILIES[family](seed).objects) for seed in range(6)]
    assert len(set(counts)) >= 3
    assert len({tuple(n) for n in names}) >= 2
