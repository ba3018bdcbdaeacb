"""The ray caster against analytic geometry, shading arithmetic and the extremes."""

import dataclasses
import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.geometry import Intrinsics, look_at, view_to_cam2world
from aes_planner.sim import RenderError, Scene, SceneSpec, render
from aes_planner.sim.raycast import _BATCH_BELOW
from aes_planner.sim.spec import (
    AmbientLightSpec,
    BoxSpec,
    CylinderSpec,
    DirectionalLightSpec,
    MaterialSpec,
    PatternSpec,
    PlaneSpec,
    QuadSpec,
    RigSpec,
    SkySpec,
    SphereSpec,
)
from aes_planner.sim.texture import pattern_weight, value_noise

K128 = Intrinsics.from_fov(128, 128, 60.0)


def assert_depth_close(depth_m, t):
    """Within 1e-4 m of the analytic distance, plus float32 rounding of far depths."""
    err = np.abs(depth_m.astype(np.float64) - t)
    assert np.all(err <= 1e-4 + 6e-8 * np.abs(t)), err.max()
    assert np.all(err[t < 100] <= 1e-4)


def scene_of(*objects, lights=(), sky=None, base_dir=None) -> Scene:
    return Scene(SceneSpec(objects=list(objects), lights=list(lights), sky=sky or SkySpec(), rig=RigSpec()), base_dir)


def camera_rays(cam2world, intrinsics):
    """World ray origin [3] and directions [H, W, 3] with camera z = 1 (so t is z-depth)."""
    d_cam = intrinsics.pixel_directions()
    return cam2world[:3, 3], d_cam @ cam2world[:3, :3].T


def analytic_sphere(origin, dirs, centre, radius):
    oc = origin - centre
    a = (dirs * dirs).sum(-1)
    b = (dirs * oc).sum(-1)
    c = oc @ oc - radius**2
    disc = b * b - a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / a
    return np.where(disc > 0, t, np.nan), disc / a


@pytest.mark.parametrize("radius, distance", [(1.0, 3.0), (0.15, 6.0), (2.0, 40.0)])
def test_sphere_depth_matches_analytic(radius, distance):
    rng = np.random.default_rng(int(radius * 100))
    centre = rng.normal(size=3) * 2
    eye = centre + distance * np.array([-0.8, 0.5, 0.3]) / np.linalg.norm([-0.8, 0.5, 0.3])
    pose = look_at(eye, centre + rng.normal(size=3) * 0.1 * radius)
    out = render(scene_of(SphereSpec(centre_m=tuple(centre), radius_m=radius)), pose, K128)
    t, margin = analytic_sphere(*camera_rays(pose, K128), centre, radius)
    clear = np.abs(margin) > 1e-6 * radius**2  # not grazing the silhouette
    hit = out.instance_id == 1
    assert np.array_equal(hit[clear], np.isfinite(t)[clear])
    assert_depth_close(out.depth_m[hit], t[hit])
    assert np.all(out.depth_m[~hit] == 0)
    area = hit.sum()
    assert area > 0
    # both code paths are exercised across the cases: one object per call, and batched
    assert (area >= _BATCH_BELOW) or radius < 1.0 or distance > 10


def test_plane_depth_matches_analytic():
    normal = np.array([0.2, -0.3, 1.0])
    normal /= np.linalg.norm(normal)
    point = np.array([1.0, 2.0, -0.5])
    pose = view_to_cam2world(np.array([0.3, -0.4, 1.7, 0.4, -0.35]))
    out = render(scene_of(PlaneSpec(point_m=tuple(point), normal=tuple(normal))), pose, K128)
    origin, dirs = camera_rays(pose, K128)
    t = ((point - origin) @ normal) / (dirs @ normal)
    hit = out.instance_id == 1
    expect = (t > 0) & (t < 1e6)
    assert np.array_equal(hit, expect)
    assert_depth_close(out.depth_m[hit], t[hit])


def test_inside_a_box_every_ray_hits_the_nearest_wall():
    half = np.array([3.0, 2.0, 1.5])
    pose = view_to_cam2world(np.array([0.5, -0.3, 0.2, 0.7, 0.3]))
    out = render(scene_of(BoxSpec(centre_m=(0.0, 0.0, 0.0), size_m=tuple(2 * half))), pose, K128)
    origin, dirs = camera_rays(pose, K128)
    with np.errstate(divide="ignore"):
        t = np.min((np.sign(dirs) * half - origin) / dirs, axis=-1)
    assert np.all(out.instance_id == 1)
    assert_depth_close(out.depth_m, t)


def test_quad_and_cylinder_cap_facing_the_camera():
    pose = look_at(np.array([-5.0, 0, 1]), np.array([0.0, 0, 1]))
    quad = QuadSpec(centre_m=(0.0, 0.0, 1.0), size_m=(2.0, 1.0), yaw_deg=180.0)
    cap = CylinderSpec(centre_m=(2.0, 0.0, 1.0), radius_m=3.0, height_m=1.0, axis=(1.0, 0.0, 0.0))
    out = render(scene_of(quad, cap), pose, K128)
    on_quad = out.instance_id == 1
    assert np.allclose(out.depth_m[on_quad], 5.0, atol=1e-5)
    assert np.allclose(out.depth_m[out.instance_id == 2], 6.5, atol=1e-5)  # the cap at x = 1.5
    # the quad's projection: 2 m x 1 m at 5 m
    f = K128.fx
    cols = np.nonzero(on_quad.any(axis=0))[0]
    rows = np.nonzero(on_quad.any(axis=1))[0]
    assert abs(len(cols) - 2.0 / 5.0 * f) <= 1 and abs(len(rows) - 1.0 / 5.0 * f) <= 1


def test_ids_follow_scene_order_and_nearest_wins():
    pose = look_at(np.array([-5.0, 0, 0]), np.array([0.0, 0, 0]))
    far = SphereSpec(centre_m=(2.0, 0.0, 0.0), radius_m=1.5)
    near = SphereSpec(centre_m=(0.0, 0.0, 0.0), radius_m=0.5)
    out = render(scene_of(far, near), pose, Intrinsics.from_fov(129, 129, 60.0))  # pixel 64 on the axis
    assert out.instance_id[64, 64] == 2 and abs(out.depth_m[64, 64] - 4.5) < 1e-5
    assert out.instance_id[64, 40] == 1
    assert out.instance_id.dtype == np.int32 and out.depth_m.dtype == np.float32 and out.rgb.dtype == np.uint8


def test_lambert_and_ambient_values():
    angle = math.radians(35)
    light = DirectionalLightSpec(
        direction=(-math.sin(angle), 0.0, -math.cos(angle)), colour=(1.0, 1.0, 1.0), intensity=0.6, shadows=False
    )
    ground = PlaneSpec(material=MaterialSpec(albedo=(0.5, 0.8, 0.2)))
    scene = scene_of(ground, lights=[AmbientLightSpec(intensity=0.25), light])
    out = render(scene, view_to_cam2world(np.array([0, 0, 2.0, 0.3, -0.6])), K128)
    expect = np.rint(np.array([0.5, 0.8, 0.2]) * (0.25 + 0.6 * math.cos(angle)) * 255)
    assert np.abs(out.rgb[out.instance_id == 1].astype(int) - expect).max() <= 1
    # the same plane seen from below: the normal faces the viewer, the light is behind it
    below = render(scene, view_to_cam2world(np.array([0, 0, -2.0, 0.3, 0.6])), K128)
    expect_below = np.rint(np.array([0.5, 0.8, 0.2]) * 0.25 * 255)
    assert np.abs(below.rgb[below.instance_id == 1].astype(int) - expect_below).max() <= 1


@pytest.mark.parametrize("radius", [0.6, 0.05])
def test_shadow_rays_are_exact(radius):
    """A sphere above the ground under a vertical sun: ground points under it are in shadow."""
    centre = np.array([0.0, 0.0, 1.0])
    ambient = AmbientLightSpec(intensity=0.3)
    sun = DirectionalLightSpec(direction=(0.0, 0.0, -1.0), colour=(1.0, 1.0, 1.0), intensity=0.5)
    scene = scene_of(
        PlaneSpec(material=MaterialSpec(albedo=(1.0, 1.0, 1.0))),
        SphereSpec(centre_m=tuple(centre), radius_m=radius),
        lights=[ambient, sun],
    )
    pose = look_at(np.array([-1.0, -0.5, 3.0]) * max(radius, 0.2) * 3, np.array([0.0, 0.0, 0.0]))
    out = render(scene, pose, K128)
    origin, dirs = camera_rays(pose, K128)
    ground = out.instance_id == 1
    world = origin + dirs * out.depth_m[..., None].astype(np.float64)
    r_xy = np.hypot(world[..., 0], world[..., 1])
    shaded, lit = ground & (r_xy < radius * 0.98), ground & (r_xy > radius * 1.02)
    assert shaded.sum() > 3 and lit.sum() > 100
    assert np.all(out.rgb[shaded] == round(0.3 * 255))
    assert np.all(out.rgb[lit] == round(0.8 * 255))
    no_shadow = scene_of(*scene.objects, lights=[ambient, dataclasses.replace(sun, shadows=False)])
    assert np.all(render(no_shadow, pose, K128).rgb[shaded] == round(0.8 * 255))


def test_sky_gradient_and_empty_scene():
    sky = SkySpec(horizon=(1.0, 0.0, 0.0), zenith=(0.0, 0.0, 1.0), nadir=(0.0, 1.0, 0.0))
    scene = scene_of(sky=sky)
    k = Intrinsics.from_fov(9, 9, 1.0)
    for pitch, colour in ((math.pi / 2, (0, 0, 255)), (0.0, (255, 0, 0)), (-math.pi / 2, (0, 255, 0))):
        out = render(scene, view_to_cam2world(np.array([0, 0, 0, 0.3, pitch])), k)
        assert np.abs(out.rgb[4, 4].astype(int) - colour).max() <= 3
        assert not out.instance_id.any() and not out.depth_m.any()
    mid = render(scene, view_to_cam2world(np.array([0, 0, 0, 0.0, math.pi / 4])), k).rgb[4, 4]
    assert abs(int(mid[0]) - 128) <= 3 and abs(int(mid[2]) - 128) <= 3  # linear in elevation


def test_image_texture_reads_upright(tmp_path):
    colours = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], np.uint8)  # RGB, 2x2
    cv2.imwrite(str(tmp_path / "tiles.png"), cv2.cvtColor(colours, cv2.COLOR_RGB2BGR))
    quad = QuadSpec(
        centre_m=(0.0, 0.0, 0.0), size_m=(2.0, 2.0), yaw_deg=180.0, material=MaterialSpec(image="tiles.png")
    )
    scene = scene_of(quad, lights=[AmbientLightSpec(intensity=1.0)], base_dir=tmp_path)
    k = Intrinsics.from_fov(64, 64, 60.0)
    pose = look_at(np.array([-4.0, 0, 0]), np.zeros(3))
    out = render(scene, pose, k)
    # the centres of the four texels: (-0.5, +0.5) is top-left as the viewer sees it
    for (y_local, z), colour in (
        ((-0.5, 0.5), colours[0, 0]),
        ((0.5, 0.5), colours[0, 1]),
        ((-0.5, -0.5), colours[1, 0]),
        ((0.5, -0.5), colours[1, 1]),
    ):
        world = np.array([0.0, -y_local, z])  # the quad faces -x, so its local +y is world -y
        u, v = k.project((np.linalg.inv(pose) @ np.append(world, 1))[:3])
        assert np.abs(out.rgb[int(v), int(u)].astype(int) - colour).max() < 30  # bilinear: near the texel centre


def test_patterns():
    u = np.linspace(-3, 3, 6001)
    v = np.full_like(u, 0.1)
    checker = pattern_weight("checker", u, v, 0.5, 0.0)
    assert set(np.unique(checker)) == {0.0, 1.0}
    assert checker[np.searchsorted(u, 0.25)] != checker[np.searchsorted(u, 0.75)]
    stripes = pattern_weight("stripes", u, v, 0.4, 0.0, duty=0.3)
    assert abs(stripes.mean() - 0.3) < 0.01
    gradient = pattern_weight("gradient", u, v, 2.0, 0.0)
    assert gradient[0] == 0 and gradient[-1] == 1 and abs(gradient[3000] - 0.5) < 1e-9
    rotated = pattern_weight("gradient", v, u, 2.0, math.pi / 2)  # along v when turned 90 deg
    assert np.allclose(rotated, gradient)
    noise = value_noise(u * 3, v * 3, 3, 7)
    assert noise.min() >= 0 and noise.max() <= 1 and noise.std() > 0.05
    assert np.abs(np.diff(noise)).max() < 0.05  # smooth
    assert np.array_equal(noise, value_noise(u * 3, v * 3, 3, 7))
    assert not np.allclose(noise, value_noise(u * 3, v * 3, 3, 8))
    per_point = value_noise(u * 3, v * 3, np.full(len(u), 3), np.where(u < 0, 7, 8))
    assert np.array_equal(per_point[u < 0], noise[u < 0])


def test_checker_on_the_ground_alternates_in_world_metres():
    ground = PlaneSpec(
        material=MaterialSpec(
            albedo=(1.0, 1.0, 1.0), pattern=PatternSpec(kind="checker", colour2=(0.0, 0.0, 0.0), scale_m=1.0)
        )
    )
    scene = scene_of(ground, lights=[AmbientLightSpec(intensity=1.0)])
    pose = look_at(np.array([0.0, 0.0, 10.0]), np.array([0.0, 0.0, 0.0]), yaw_hint_rad=0.0)
    k = Intrinsics.from_fov(101, 101, 60.0)
    out = render(scene, pose, k)
    for x, y in ((0.5, 0.5), (1.5, 0.5), (0.5, -0.5), (-1.5, -1.5), (2.5, 1.5)):
        u, v = k.project((np.linalg.inv(pose) @ np.array([x, y, 0.0, 1.0]))[:3])
        expect = 0 if (math.floor(x) + math.floor(y)) % 2 else 255
        assert out.rgb[int(v), int(u), 0] == expect, (x, y)


def test_supersampling_keeps_depth_and_ids_and_averages_rgb():
    scene = scene_of(
        PlaneSpec(material=MaterialSpec(pattern=PatternSpec(kind="checker", scale_m=0.3))),
        SphereSpec(centre_m=(3.0, 0.0, 0.8), radius_m=0.8),
        lights=[AmbientLightSpec(), DirectionalLightSpec()],
    )
    pose = view_to_cam2world(np.array([0, 0, 1.2, 0.05, -0.15]))
    k = Intrinsics.from_fov(48, 32, 70.0)
    plain = render(scene, pose, k)
    for s in (2, 3):
        aa = render(scene, pose, k, supersample=s)
        assert np.array_equal(aa.depth_m, plain.depth_m) and np.array_equal(aa.instance_id, plain.instance_id)
        big = render(scene, pose, k.scaled(48 * s, 32 * s)).rgb.astype(np.float64)
        mean = big.reshape(32, s, 48, s, 3).mean(axis=(1, 3))
        assert np.abs(aa.rgb - mean).max() <= 1.0
    assert np.abs(render(scene, pose, k, supersample=3).rgb.astype(int) - plain.rgb).max() > 20  # edges do change


def test_bad_arguments():
    scene = scene_of()
    with pytest.raises(RenderError, match="supersample"):
        render(scene, np.eye(4), K128, supersample=0)
    with pytest.raises(RenderError, match="Intrinsics"):
        render(scene, np.eye(4), K128.K)
    with pytest.raises(RenderError, match="load_scene"):
        render(scene.spec, np.eye(4), K128)


def test_far_from_the_origin_renders_the_same():
    offset = np.array([1e5, -2e5, 300.0])
    objects = [
        PlaneSpec(material=MaterialSpec(pattern=PatternSpec(kind="noise", scale_m=0.5))),
        BoxSpec(centre_m=(3.0, 0.5, 0.5), size_m=(1.0, 1.0, 1.0), yaw_deg=20.0),
        SphereSpec(centre_m=(4.0, -1.0, 0.7), radius_m=0.7),
    ]
    moved = [
        PlaneSpec(point_m=tuple(offset), material=objects[0].material),
        BoxSpec(centre_m=tuple(np.add(objects[1].centre_m, offset)), size_m=(1.0, 1.0, 1.0), yaw_deg=20.0),
        SphereSpec(centre_m=tuple(np.add(objects[2].centre_m, offset)), radius_m=0.7),
    ]
    lights = [AmbientLightSpec(), DirectionalLightSpec()]
    pose = view_to_cam2world(np.array([0, 0, 1.5, 0.0, -0.2]))
    far_pose = pose.copy()
    far_pose[:3, 3] += offset
    a, b = (
        render(scene_of(*objects, lights=lights), pose, K128),
        render(scene_of(*moved, lights=lights), far_pose, K128),
    )
    assert np.mean(a.instance_id != b.instance_id) < 0.002
    same = a.instance_id == b.instance_id
    assert np.abs(a.depth_m[same] - b.depth_m[same]).max() < 1e-4
    assert np.mean(np.abs(a.rgb.astype(int) - b.rgb)) < 0.5


# ------------------------------------------------------------------------------- extremes
finite = st.floats(-5, 5, allow_nan=False)
objects_strategy = st.lists(
    st.one_of(
        st.builds(
            lambda c, s, y: BoxSpec(centre_m=c, size_m=s, yaw_deg=y),
            st.tuples(finite, finite, finite),
            st.tuples(*[st.floats(0.01, 6)] * 3),
            st.floats(-180, 180),
        ),
        st.builds(
            lambda c, r: SphereSpec(centre_m=c, radius_m=r), st.tuples(finite, finite, finite), st.floats(0.01, 6)
        ),
        st.builds(
            lambda c, r, h, a: CylinderSpec(centre_m=c, radius_m=r, height_m=h, axis=a),
            st.tuples(finite, finite, finite),
            st.floats(0.01, 3),
            st.floats(0.01, 6),
            st.sampled_from([(0, 0, 1), (1, 0, 0), (0.3, -0.5, 0.8)]),
        ),
        st.builds(
            lambda p, n: PlaneSpec(point_m=p, normal=n),
            st.tuples(finite, finite, finite),
            st.sampled_from([(0, 0, 1), (0, 1, 0), (1, 1e-9, 0), (0.2, 0.3, -1)]),
        ),
        st.builds(
            lambda c, s, y: QuadSpec(centre_m=c, size_m=s, yaw_deg=y),
            st.tuples(finite, finite, finite),
            st.tuples(st.floats(0.01, 6), st.floats(0.01, 6)),
            st.floats(-180, 180),
        ),
    ),
    max_size=6,
)


@given(
    objects=objects_strategy,
    eye=st.tuples(finite, finite, finite),
    yaw=st.floats(-math.pi, math.pi),
    pitch=st.sampled_from([-math.pi / 2, math.pi / 2, 0.0, -1.2, 0.7, math.pi / 2 - 1e-9]),
    far=st.booleans(),
    size=st.sampled_from([(1, 1), (3, 2), (17, 11)]),
    supersample=st.sampled_from([1, 2, 3]),
)
def test_outputs_are_always_finite(objects, eye, yaw, pitch, far, size, supersample):
    """Camera inside objects, at the poles, 1e5 m out, 1x1 images, grazing planes, empty scenes."""
    offset = np.array([1e5, 1e5, 0.0]) if far else np.zeros(3)
    if far:
        objects = [_moved(o, offset) for o in objects]
    scene = scene_of(*objects, lights=[AmbientLightSpec(), DirectionalLightSpec()])
    pose = view_to_cam2world(np.array([*(np.array(eye) + offset), yaw, pitch]))
    out = render(scene, pose, Intrinsics.from_fov(*size, 90.0), supersample=supersample)
    assert out.rgb.shape == (size[1], size[0], 3) and out.rgb.dtype == np.uint8
    assert np.all(np.isfinite(out.depth_m)) and np.all(out.depth_m >= 0)
    assert np.array_equal(out.depth_m > 0, out.instance_id > 0)
    assert out.instance_id.min() >= 0 and out.instance_id.max() <= len(objects)


def _moved(obj, offset):
    if isinstance(obj, PlaneSpec):
        return dataclasses.replace(obj, point_m=tuple(np.add(obj.point_m, offset)))
    return dataclasses.replace(obj, centre_m=tuple(np.add(obj.centre_m, offset)))


def test_camera_inside_a_sphere_sees_its_inner_wall():
    scene = scene_of(SphereSpec(centre_m=(0.0, 0.0, 0.0), radius_m=2.0), lights=[AmbientLightSpec()])
    out = render(scene, view_to_cam2world(np.array([0.5, 0.2, -0.3, 1.0, 0.4])), K128)
    origin, dirs = camera_rays(view_to_cam2world(np.array([0.5, 0.2, -0.3, 1.0, 0.4])), K128)
    oc = origin
    a, b, c = (dirs * dirs).sum(-1), (dirs * oc).sum(-1), oc @ oc - 4.0
    t = (-b + np.sqrt(b * b - a * c)) / a
    assert np.all(out.instance_id == 1)
    assert_depth_close(out.depth_m, t)
