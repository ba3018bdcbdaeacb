"""Framing (``suggest --keep/--avoid``): regions, the lift, the constrained search, the request."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from aes_planner.field.scorer import ScoreOutput
from aes_planner.geometry import Intrinsics
from aes_planner.geometry.poses import look_at
from aes_planner.messages import PlannerRequest
from aes_planner.messages.codec import HEADER_SIZE, decode
from aes_planner.messages.diagnostics import FramingRegion
from aes_planner.search import SearchConfig, search_views
from aes_planner.search.framing import Framing, FramingConfig, FramingError, Region, Subject, lift_region
from tests.search.test_search import AimScorer, rig_inputs, rig_platform

K = Intrinsics.from_fov(32, 24, 60.0)


def subject_at(centre, half=(0.2, 0.2, 0.2)) -> Subject:
    return Subject(Region("a.png", 0, 0, 1, 1), np.asarray(centre, float), np.eye(3), np.asarray(half, float))


# ---------------------------------------------------------------- regions
@pytest.mark.parametrize(
    "text, words",
    [
        ("a.png:1,2,3", "FRAME:X0,Y0,X1,Y1"),
        ("a.png:5,5,5,9", "zero size"),
        ("a.png:9,5,3,9", "zero size"),
        ("a.png:x,5,3,9", "numbers"),
        ("a.png:0,0,nan,9", "finite"),
    ],
)
def test_a_bad_region_names_the_flag(text, words):
    with pytest.raises(FramingError, match=words) as exc:
        Region.parse(text, "--keep")
    assert "--keep" in str(exc.value)


def test_a_region_outside_its_image_is_refused():
    r = Region.parse("00003.png:21,0,61,36")
    assert (r.frame, r.x1) == ("00003.png", 61.0)
    r.checked("--keep", 64, 48)
    with pytest.raises(FramingError, match="outside the 32x24 image"):
        r.checked("--keep", 32, 24)


# ---------------------------------------------------------------- the lift
def test_the_lift_keeps_the_subject_not_the_wall_behind_it():
    """A box around a subject 2 m away with a wall at 5 m filling the rest of the box: the 3D box
    is the subject's (and the box's frustum at the subject's depth), never reaches the wall."""
    cam = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))  # looking along +x
    rng = np.random.default_rng(0)
    subject = np.c_[rng.uniform(1.9, 2.1, 300), rng.uniform(-0.2, 0.2, 300), rng.uniform(-0.2, 0.2, 300)]
    wall = np.c_[np.full(900, 5.0), rng.uniform(-2, 2, 900), rng.uniform(-2, 2, 900)]
    means = np.concatenate([subject, wall])
    k = Intrinsics.from_fov(64, 48, 60.0)
    region = Region("a.png", 20, 12, 44, 36)  # wider than the subject: the wall fills its rim
    s = lift_region(means, np.full(len(means), 0.9), np.asarray(cam), k, region)
    lo, hi = s.corners_m.min(0), s.corners_m.max(0)
    assert hi[0] < 2.6 and lo[0] > 1.5  # the depth slab stays at the subject
    assert s.gaussians >= 250
    framing = Framing([s], [], k, FramingConfig(margin_frac=0.0))
    assert bool(framing.feasible(torch.as_tensor(np.asarray(cam))[None])[0])


def test_a_thin_subject_is_lifted_at_its_own_depth_not_at_the_wall_that_fills_its_box():
    """A pole 2 m away, 4 px wide in a box 14 px wide: the wall 3 m behind it fills most of the
    box, and the heaviest depth inside is the wall's. The ring just outside the box is all wall,
    so the pole's depth is the figure; without the ring (``ring_frac=0``) the lift takes the wall."""
    cam = np.asarray(look_at(np.zeros(3), np.array([1.0, 0.0, 0.0])))
    k = Intrinsics.from_fov(64, 48, 60.0)
    depth = np.full((48, 64), 3.0)
    depth[6:42, 30:34] = 2.0  # the pole, the box's full height
    region = Region("a.png", 25, 6, 39, 42)
    means, opac = np.zeros((0, 3)), np.zeros(0)  # the rendered depth decides; no Gaussians needed
    for ring, (lo_m, hi_m) in ((0.25, (1.8, 2.2)), (0.0, (2.8, 3.2))):
        s = lift_region(means, opac, cam, k, region, FramingConfig(ring_frac=ring), depth_map=depth)
        assert lo_m < s.centre_m[0] < hi_m, (ring, s.centre_m)
    s = lift_region(means, opac, cam, k, region, depth_map=depth)
    x = s.corners_m[:, 0]
    assert x.max() - x.min() < 0.3  # the slab holds the pole, not the wall 1 m behind it


def test_a_subject_that_fills_its_box_is_lifted_as_before():
    """The ring changes nothing when the box's heaviest depth is also its figure (a tight box), or
    when the box is the whole image (no ring to compare with)."""
    cam = np.asarray(look_at(np.zeros(3), np.array([1.0, 0.0, 0.0])))
    k = Intrinsics.from_fov(64, 48, 60.0)
    depth = np.full((48, 64), 3.0)
    depth[10:38, 20:44] = np.linspace(1.9, 2.1, 24)[None]  # a slanted face filling the box
    region = Region("a.png", 20, 10, 44, 38)
    z = [lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, region, FramingConfig(ring_frac=r), depth_map=depth)
         for r in (0.0, 0.25)]  # fmt: skip
    np.testing.assert_allclose(z[0].centre_m, z[1].centre_m)
    np.testing.assert_allclose(z[0].size_m, z[1].size_m)
    whole = Region("a.png", 0, 0, 64, 48)  # no ring inside the image: the rule as without it
    z = [lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, whole, FramingConfig(ring_frac=r), depth_map=depth)
         for r in (0.0, 0.25)]  # fmt: skip
    np.testing.assert_allclose(z[0].centre_m, z[1].centre_m)


def test_only_what_the_ring_holds_more_of_is_ground():
    """A bin is ground when the ring holds a larger share of it than the box; an empty bin is not
    (the slab still bridges one), and a ring with too little to compare with leaves all figure."""
    from aes_planner.search.framing import _figure_bins

    p_in = np.array([0.5, 0.0, 0.3, 0.2, 0.0])
    ring = np.exp(np.full(4, 3.5) * 0.04)  # all in bin 3 (from lo = 0); smoothed: 0.25 / 0.5 / 0.25 in bins 2-4
    fig = _figure_bins(p_in, ring, np.ones(4), 0.0, 5, 0.04)
    assert fig.tolist() == [True, True, True, False, False]
    assert _figure_bins(p_in, ring[:3], np.ones(3), 0.0, 5, 0.04).all()


def _downward_face():
    """A camera 2 m up looking 35 degrees down at a face filling its box: the face is square to
    the ray, so the world-upright 3D box around it sticks out past the drawn box on every side."""
    cam = np.asarray(look_at(np.array([0.0, 0.0, 2.0]), np.array([2.0, 0.0, 2.0 - 2.0 * math.tan(math.radians(35))])))
    k = Intrinsics.from_fov(64, 48, 60.0)
    depth = np.full((48, 64), 6.0)
    depth[12:36, 22:42] = 2.5
    return cam, k, depth, Region("a.png", 22, 12, 42, 36)


def _projected_rect(points: np.ndarray, cam: np.ndarray, k: Intrinsics) -> np.ndarray:  # -> [x0, y0, x1, y1] px
    pc = (points - cam[:3, 3]) @ cam[:3, :3]
    u, v = k.fx * pc[:, 0] / pc[:, 2] + k.cx, k.fy * pc[:, 1] / pc[:, 2] + k.cy
    return np.array([u.min(), v.min(), u.max(), v.max()])


def test_a_view_holds_the_lifted_points_where_only_the_box_corners_stick_out():
    """``hold_by="points"`` (the default): a view must hold the lifted points' outline, which in
    the input view is the drawn box; the 3D box's corners reach past it, so holding them rejects
    views that hold everything the lift knows of the subject (on the dev scenes: the best kept
    grid view 0.84 -> 0.87 of the constrained oracle, and none that cuts a subject)."""
    cam, k, depth, region = _downward_face()
    s = lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, region, depth_map=depth)
    assert s.occluded_frac == 0.0 and s.outline_m is not None and 4 <= len(s.outline_m) <= 64
    np.testing.assert_allclose(_projected_rect(s.outline_m, cam, k), [22, 12, 42, 36], atol=0.6)
    corners = _projected_rect(s.corners_m, cam, k)
    assert corners[0] < 20 and corners[2] > 44, corners  # the box's empty corners stick out
    assert np.array_equal(s.hold_points_m("box"), s.corners_m)
    # turns of the camera on the spot: every view that holds the box holds the points, and more do
    turns = [cam @ np.block([[_rot_y(a), np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]])
             for a in np.radians(np.arange(-40, 41, 2))]  # fmt: skip
    poses = torch.as_tensor(np.stack(turns))
    by_box = Framing([s], [], k, FramingConfig(hold_by="box")).feasible(poses)
    by_points = Framing([s], [], k, FramingConfig()).feasible(poses)
    assert bool((by_points | ~by_box).all()) and int(by_points.sum()) > int(by_box.sum())


def _rot_y(a: float) -> np.ndarray:  # a turn about the camera's own y axis (pan)
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def test_a_subject_partly_hidden_is_held_by_its_box():
    """Something nearer than the subject covering more than ``occluded_max`` of its box may hide
    more of it: the subject is then held by its (larger) 3D box, not by the points seen."""
    cam, k, depth, region = _downward_face()
    depth[12:20, 22:42] = 1.2  # an occluder over the top third of the box
    s = lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, region, depth_map=depth)
    assert 0.25 < s.occluded_frac < 0.45
    assert np.array_equal(s.hold_points_m("points", 0.2), s.corners_m)
    assert np.array_equal(s.hold_points_m("points", 0.5), s.outline_m)
    framing = Framing([s], [], k, FramingConfig())
    np.testing.assert_allclose(framing._keep[0].numpy(), s.corners_m)


def test_a_box_cut_by_its_image_border_is_said_to_hold_only_what_the_image_shows():
    cam, k, depth, region = _downward_face()
    inside = lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, region, depth_map=depth)
    depth[12:48, 22:42] = 2.5  # the face runs on past the bottom of the image
    cut = lift_region(np.zeros((0, 3)), np.zeros(0), cam, k, Region("a.png", 22, 12, 42, 48), depth_map=depth)
    assert not inside.cut_by_frame and cut.cut_by_frame
    assert Framing([inside], [], k, FramingConfig()).notes() == []
    (note,) = Framing([inside, cut], [], k, FramingConfig()).notes()
    assert "--keep a.png:22,12,42,48" in note and "border" in note


@pytest.mark.parametrize("kw, word", [({"hold_by": "hull"}, "hold_by"), ({"occluded_max": 1.5}, "occluded_max"),
                                      ({"outline_dirs": 2}, "outline_dirs")])  # fmt: skip
def test_the_hold_rule_is_checked(kw, word):
    with pytest.raises(AesPlannerError, match=word):
        FramingConfig(**kw)


def test_nothing_behind_the_box_is_an_error():
    cam = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    with pytest.raises(FramingError, match="nothing behind this box"):
        lift_region(np.zeros((0, 3)), np.zeros(0), np.asarray(cam), K, Region("a.png", 1, 1, 5, 5))


# ---------------------------------------------------------------- the constraint
@settings(max_examples=30, deadline=None)
@given(st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50))
def test_violation_is_finite_and_zero_only_when_held(x, y, z):
    framing = Framing([subject_at((x, y, z))], [subject_at((1.0, 1.0, 1.0))], K, FramingConfig(keep_at="thirds"))
    poses = torch.as_tensor(np.asarray(look_at(np.zeros((3, 3)), np.eye(3)))).double()
    for f in (framing.violation, framing.held, framing.avoid_visible, framing.placement):
        assert torch.isfinite(f(poses)).all()
    held = framing.held(poses)
    assert torch.all((framing.violation(poses) > 0) | (held >= 1.0 - 1e-9))


def test_with_a_kept_subject_explore_says_what_the_inputs_cover_of_the_views_that_hold_it():
    """The framed search says how much of the views that hold the subject the inputs cover
    (``covered_fraction``) and where to look next (``explore``): a view that holds the subject,
    only partly covered. EdgeScorer's coverage fades from views along +x to those across it; the
    subject stands off +y towards +x, so some views that hold it are covered and some are not."""
    from aes_planner.search.space import space_for
    from tests.search.test_search import EdgeScorer

    platform = rig_platform(pan_limits_deg=(-170.0, 170.0), tilt_limits_deg=(-40.0, 40.0))
    subject = subject_at((0.8, 3.0, 1.3), (0.1, 0.1, 0.1))
    framing = Framing([subject], [], platform.intrinsics, FramingConfig(explore_samples=256))
    cfg = SearchConfig.preset("fast", top_k=2, explore_points=16)
    result = search_views(EdgeScorer([0.0, 1.0, 0.0]), rig_inputs(platform), platform, cfg, framing=framing)
    space = space_for(platform, cfg)
    poses = space.to_poses(space.grid(256))
    held = framing.feasible(poses)
    cov = EdgeScorer([0.0, 1.0, 0.0]).score(poses[held]).coverage.double()
    assert result.covered_fraction == pytest.approx(float((cov >= cfg.coverage_min).double().mean()))
    assert 0.0 < result.covered_fraction < 1.0
    e = result.explore
    assert e is not None and 0.0 < e.coverage < cfg.coverage_min  # the search's own rule, as without a subject
    assert float(framing.held(torch.as_tensor(e.cam2world[None]))[0]) == pytest.approx(1.0)
    # no views spread (explore_samples 0): nothing said rather than a view that may cut the subject
    tiny = Framing([subject], [], platform.intrinsics, FramingConfig(explore_samples=0))
    quiet = search_views(EdgeScorer([0.0, 1.0, 0.0]), rig_inputs(platform), platform, cfg, framing=tiny)
    assert quiet.covered_fraction is None and quiet.explore is None


@pytest.mark.parametrize("refine", [False, True])
def test_the_search_keeps_the_subject_whole_in_every_suggestion(refine):
    """The scorer wants the view straight ahead; the subject stands off to the side: every
    suggestion holds it and turns towards it, with stage 2 off (the default) and on (it never
    leaves the feasible set)."""
    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    subject = subject_at((3.0, 3.0, 1.3), (0.1, 0.1, 0.1))
    framing = Framing([subject], [], platform.intrinsics, FramingConfig(refine=refine))
    scorer = AimScorer([1.0, 0.0, 0.0])
    cfg = SearchConfig.preset("fast", top_k=2, steps=15, lr=0.05)
    result = search_views(scorer, rig_inputs(platform), platform, cfg, framing=framing)
    if refine:  # stage 2 ran: its steps were scored, on top of what the search without it scored
        without = Framing([subject], [], platform.intrinsics, FramingConfig(refine=False))
        assert result.scored > search_views(scorer, rig_inputs(platform), platform, cfg, framing=without).scored
    assert result.suggestions
    for s in result.suggestions:
        assert s.held == pytest.approx(1.0)
        assert float(framing.violation(torch.as_tensor(s.cam2world[None]))[0]) == 0.0
    free = search_views(scorer, rig_inputs(platform), platform, cfg)
    assert free.best.score > result.best.score  # the constraint costs something here: it is active
    assert math.degrees(result.best.pan_rad) > 10.0


def test_no_reachable_view_is_a_clear_error():
    platform = rig_platform(pan_limits_deg=(-30.0, 30.0), tilt_limits_deg=(-20.0, 20.0))
    framing = Framing([subject_at((-4.0, 0.0, 1.3))], [], platform.intrinsics, FramingConfig())  # behind the rig
    with pytest.raises(FramingError, match=r"no reachable view holds the whole subject.*holds \d+%"):
        search_views(
            AimScorer([1.0, 0.0, 0.0]), rig_inputs(platform), platform, SearchConfig.preset("fast"), framing=framing
        )


def test_a_subject_held_only_near_the_edge_is_held_with_a_smaller_margin_and_said_so():
    """At the pan limit (30 deg, half the 60 deg field of view) a subject 57 deg off the rig's
    axis projects 95.5 % across the frame: outside the 5 % margin, inside half of it. The search
    holds it whole with the smaller margin and says so, rather than refusing a view that exists."""
    platform = rig_platform(pan_limits_deg=(-30.0, 30.0), tilt_limits_deg=(-20.0, 20.0))
    bearing = math.radians(57.0)
    base = np.asarray(platform.rig.base_xyz_m, float)
    subject = subject_at(base + 4.0 * np.array([math.cos(bearing), math.sin(bearing), 0.0]), (0.05, 0.05, 0.05))
    subject.cut_by_frame, subject.open_sides = True, ("left",)  # its box touched its image's border: said too
    framing = Framing([subject], [], platform.intrinsics, FramingConfig(margin_frac=0.05))
    result = search_views(
        AimScorer([1.0, 0.0, 0.0]), rig_inputs(platform), platform, SearchConfig.preset("fast"), framing=framing
    )
    assert result.suggestions and any("5% margin asked" in w and "2.5% margin" in w for w in result.warnings)
    assert any("touches its image's border" in w for w in result.warnings)
    half = framing.with_margin(0.025)
    for s in result.suggestions:
        pose = torch.as_tensor(s.cam2world[None])
        assert float(half.violation(pose)[0]) == 0.0 and s.held == pytest.approx(1.0)
        assert float(framing.violation(pose)[0]) > 0.0  # the margin asked could not be had


def test_an_avoided_region_pushes_the_view_away():
    platform = rig_platform(pan_limits_deg=(-90.0, 90.0), tilt_limits_deg=(-30.0, 30.0))
    ahead = subject_at((4.0, 0.0, 1.3), (0.5, 0.5, 0.5))
    scorer = AimScorer([1.0, 0.0, 0.0])
    cfg = SearchConfig.preset("fast", steps=10, lr=0.05)
    plain = search_views(scorer, rig_inputs(platform), platform, cfg)
    framing = Framing([], [ahead], platform.intrinsics, FramingConfig(avoid_weight=5.0))
    steered = search_views(scorer, rig_inputs(platform), platform, cfg, framing=framing)
    pose = lambda s: torch.as_tensor(s.cam2world[None])  # noqa: E731
    assert float(framing.avoid_visible(pose(steered.best))[0]) < float(framing.avoid_visible(pose(plain.best))[0])
    assert steered.best.terms["aesthetic"] == pytest.approx(steered.best.score)


# ---------------------------------------------------------------- the request
def test_planner_request_carries_regions_and_old_versions_decode():
    req = PlannerRequest("suggest", set_framing=True, keep=[FramingRegion("00003.png", 21, 0, 61, 36)], keep_margin=0.1)
    back = decode(req.encode(), PlannerRequest)
    assert back.keep == req.keep and back.set_framing and back.keep_margin == 0.1
    v1 = PlannerRequest("reset", 3, 1.5, 7).encode()
    head = bytearray(v1)
    # a version-1 writer: schema version 1 and only the first four fields (kind, count, stamp, sequence)
    payload_len = 1 + 4 + 8 + 8
    name_len = head[5]
    head[6:8] = (1).to_bytes(2, "little")
    head[8:12] = payload_len.to_bytes(4, "little")
    old = bytes(head[: HEADER_SIZE + name_len + payload_len])
    got = decode(old, PlannerRequest)
    assert (got.kind, got.max_candidates, got.sequence, got.set_framing, got.keep) == ("reset", 3, 7, False, [])


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"keep": [FramingRegion("a", 0, 0, 1, 1)] * 9}, "at most 8"),
        ({"keep_margin": 0.5}, "keep_margin"),
    ],
)
def test_bad_requests_are_refused(kw, words):
    with pytest.raises(Exception, match=words):
        PlannerRequest("suggest", set_framing=True, **kw)
    with pytest.raises(Exception, match="zero size"):
        FramingRegion("a.png", 3, 3, 3, 9)


# ---------------------------------------------------------------- verification
class CentreRedTeacher:
    """A teacher that likes red at the image centre: score = red mass weighted by a centre bump."""

    name = "centre_red"

    def features(self, rgb):  # [B, 3, H, W] -> the same
        return rgb

    def explain_map(self, rgb):  # -> {"score": [B]}
        h, w = rgb.shape[-2:]
        yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
        bump = torch.exp(-(xx**2 + yy**2) / 0.1)
        red = (rgb[:, 0] - 0.5 * (rgb[:, 1] + rgb[:, 2])).clamp_min(0)
        return {"score": (red * bump).sum((1, 2)) / bump.sum()}


class ColouredAim(AimScorer):
    """AimScorer (wants the view straight ahead) beside a reconstruction of one red blob: what the
    verification renders and scores with its teacher."""

    def __init__(self, blob_m, target_dir):
        from types import SimpleNamespace

        from aes_planner.gaussians import Gaussians

        super().__init__(target_dir)
        n = 64
        rng = np.random.default_rng(0)
        means = torch.as_tensor(np.asarray(blob_m) + rng.normal(0, 0.05, (n, 3)), dtype=torch.float32)
        g = Gaussians(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.full((n, 3), math.log(0.06)),
                      torch.full((n,), 0.9), torch.tensor([[1.0, 0.0, 0.0]]).repeat(n, 1))  # fmt: skip
        self.reconstruction = SimpleNamespace(gaussians=g, local_frame=None)
        self.teacher = CentreRedTeacher()


def test_verification_ranks_by_the_teacher_on_rendered_rgb():
    """The field (AimScorer) wants the optical axis along +x, so among the views holding the subject
    it prefers those with the subject at the frame's edge; the teacher on the reconstruction's
    render wants the (red) subject at the centre: with verification the suggestion is the
    teacher's choice, still holding the subject, and carries its verified score."""
    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    subject = subject_at((3.0, 2.0, 1.3), (0.15, 0.15, 0.15))
    scorer = ColouredAim(subject.centre_m, [1.0, 0.0, 0.0])
    cfg = SearchConfig.preset("fast", top_k=2, steps=10, lr=0.05)

    def off_centre(result):  # normalised distance of the subject's centre from the image centre
        from aes_planner.search.framing import project_corners

        c = torch.as_tensor(subject.centre_m)[None, None]
        u, v, _ = project_corners(c, torch.as_tensor(result.best.cam2world[None]), platform.intrinsics)
        return math.hypot(float(u) - 0.5, float(v) - 0.5)

    runs = {}
    for top in (0, 16):
        framing = Framing([subject], [], platform.intrinsics, FramingConfig(verify_top=top, verify_width_px=32))
        runs[top] = search_views(scorer, rig_inputs(platform), platform, cfg, framing=framing)
        assert all(s.held == pytest.approx(1.0) for s in runs[top].suggestions)
        assert len(runs[top].suggestions) >= 1
    assert "verified" not in runs[0].best.terms
    assert runs[16].best.terms["verified"] > 0
    assert off_centre(runs[16]) < off_centre(runs[0]) - 0.05
    assert runs[16].timings_ms["verify"] > 0


def test_verification_config_is_checked():
    with pytest.raises(AesPlannerError, match="verify_weight"):
        FramingConfig(verify_weight=1.5)
    with pytest.raises(AesPlannerError, match="verify_width_px"):
        FramingConfig(verify_width_px=4)


# ---------------------------------------------------------------- stage 2 under a kept subject
def test_with_a_kept_subject_the_suggestions_are_unmoved_stage1_picks_unless_refine():
    """Stage 2 is off under a kept subject by default (FramingConfig.refine): every suggestion is
    a stage-1 candidate, unmoved, with its stage-1 score; with refine on, stage 2 moves the best
    view off the candidates and raises the field's score."""
    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    subject = subject_at((3.0, 3.0, 1.3), (0.1, 0.1, 0.1))
    scorer = AimScorer([1.0, 0.0, 0.0])
    cfg = SearchConfig.preset("fast", top_k=2, steps=15, lr=0.05)
    runs = {}
    for refine in (False, True):
        framing = Framing([subject], [], platform.intrinsics, FramingConfig(refine=refine))
        runs[refine] = search_views(scorer, rig_inputs(platform), platform, cfg, framing=framing)
        assert all(s.held == pytest.approx(1.0) for s in runs[refine].suggestions)

    def in_stage1(s):
        return float(np.abs(runs[False].candidates_cam2world - s.cam2world[None]).max(axis=(1, 2)).min()) < 1e-9

    assert all(in_stage1(s) for s in runs[False].suggestions)
    assert all(s.objective == pytest.approx(s.stage1_score, abs=1e-6) for s in runs[False].suggestions)
    assert not in_stage1(runs[True].best)
    assert runs[True].best.objective > runs[False].best.objective


@pytest.mark.parametrize("lr", [0.02, 0.3, 1.0])
def test_stage_2_never_returns_a_feasible_view_the_field_scores_below_its_start(lr):
    """Stage 2 under a kept subject (``FramingConfig(refine=True)``), with steps small and large
    enough to overshoot: every returned view still holds the subject, and the field (the wrapped
    objective, scored afresh) never rates it below the stage-1 view it started from."""
    from aes_planner.search.pipeline import _objective, refine_params
    from aes_planner.search.space import space_for

    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    framing = Framing(
        [subject_at((3.0, 3.0, 1.3), (0.1, 0.1, 0.1))], [], platform.intrinsics, FramingConfig(refine=True)
    )
    cfg = SearchConfig.preset("fast", steps=20, lr=lr)
    space = space_for(platform, cfg)
    scorer = framing.wrap(AimScorer([1.0, 0.0, 0.0]))
    cands = space.random(4096, np.random.default_rng(0))  # [C, D]
    start = cands[framing.feasible(space.to_poses(cands))][:8]  # [K, D], all holding the subject
    assert len(start) >= 4
    start_obj = _objective(scorer.score_batched(space.to_poses(start), 64), cfg).double()
    _, best, best_obj = refine_params(scorer, space, start, start_obj, cfg, framing)
    assert bool(framing.feasible(space.to_poses(best)).all())
    rescored = _objective(scorer.score_batched(space.to_poses(best).detach(), 64), cfg).double()
    assert torch.all(rescored >= start_obj - 1e-9)
    assert torch.all(best_obj >= start_obj)
    assert bool((rescored > start_obj + 1e-6).any())  # it climbed somewhere: the check is not vacuous


# ---------------------------------------------------------------- the coverage rule under a kept subject
class PartlySeenScorer(AimScorer):
    """Best aimed 15 deg left of the rig's axis; views turned more than 5 deg left are partly
    covered (0.55): the best view is there, the most covered ones are straight ahead."""

    def __init__(self):
        super().__init__([math.cos(math.radians(15.0)), math.sin(math.radians(15.0)), 0.0])

    def score(self, cam2world):
        out = super().score(cam2world)
        left = cam2world[:, :3, 2].detach() @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
        cov = torch.where(left > math.sin(math.radians(5.0)), 0.55, 1.0).to(out.score.dtype)
        return ScoreOutput(out.score, cov, out.terms)


def test_a_kept_subject_is_ranked_by_the_field_not_pushed_to_the_most_covered_view():
    """Every view that holds a kept subject sees something the inputs saw, so the search takes the
    milder coverage rule of FramingConfig (0.5 and 0.5): the field's best view (0.55 covered)
    wins. The search's own rule (0.7 and 2), still used without a kept subject, and the framed
    search configured with it pick a fully covered view instead."""
    platform = rig_platform(pan_limits_deg=(-60.0, 60.0), tilt_limits_deg=(-30.0, 30.0))
    base = np.asarray(platform.rig.base_xyz_m, float)
    subject = subject_at(base + np.array([4.0, 0.0, 0.0]), (0.05, 0.05, 0.05))
    scorer, cfg = PartlySeenScorer(), SearchConfig.preset("fast", top_k=2)
    mild = search_views(scorer, rig_inputs(platform), platform, cfg,
                        framing=Framing([subject], [], platform.intrinsics, FramingConfig()))  # fmt: skip
    strict = Framing([subject], [], platform.intrinsics, FramingConfig(coverage_min=0.7, coverage_penalty=2.0))
    strict_run = search_views(scorer, rig_inputs(platform), platform, cfg, framing=strict)
    free = search_views(scorer, rig_inputs(platform), platform, cfg)
    assert mild.best.held == pytest.approx(1.0) and strict_run.best.held == pytest.approx(1.0)
    assert mild.best.coverage == pytest.approx(0.55) and math.degrees(mild.best.pan_rad) > 10.0
    for run in (strict_run, free):
        assert run.best.coverage == pytest.approx(1.0) and math.degrees(run.best.pan_rad) < 6.0
    assert mild.best.score > strict_run.best.score


def test_the_coverage_rule_under_a_kept_subject_is_checked():
    for kw in (dict(coverage_min=1.5), dict(coverage_min=float("nan")), dict(coverage_penalty=-1.0)):
        with pytest.raises(AesPlannerError, match=next(iter(kw))):
            FramingConfig(**kw)


# ---------------------------------------------------------------- ranking on the warped input photos
def red_dot_photos(platform, centre, n: int = 4, width: int = 64):
    """Photos of a red dot at ``centre`` on grey from the rig's survey sweep: (frames, poses)."""
    from types import SimpleNamespace

    poses = rig_inputs(platform, n)
    k = platform.intrinsics
    scale = width / k.width
    h = round(k.height * scale)
    frames = []
    for c2w in poses:
        img = np.full((h, width, 3), 100, np.uint8)
        p = np.linalg.inv(c2w) @ np.r_[centre, 1.0]
        if p[2] > 0:
            u, v = (k.K[:2, :2] @ (p[:2] / p[2]) + k.K[:2, 2]) * scale
            yy, xx = np.mgrid[:h, :width]
            img[(xx - u) ** 2 + (yy - v) ** 2 <= (0.08 * width) ** 2] = (230, 20, 20)
        frames.append(SimpleNamespace(image=img, cam2world=c2w, intrinsics=k))
    return frames, poses


def test_a_photo_warped_to_its_own_view_scores_as_the_photo_and_a_view_away_is_uncovered():
    from aes_planner.search.photo_warp import warped_photo_scores

    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    frames, poses = red_dot_photos(platform, np.array([3.0, 0.5, 1.3]))
    teacher = CentreRedTeacher()
    eye = poses[:1, :3, 3]
    away = np.asarray(look_at(eye, eye + np.array([[0.05, 0.0, -1.0]])), float)  # straight down: no photo saw it
    scores, cover = warped_photo_scores(teacher, [f.image for f in frames], poses, platform.intrinsics,
                                        np.concatenate([poses, away]), None, 64, 0.5)  # fmt: skip
    own = teacher.explain_map(torch.as_tensor(np.stack([f.image for f in frames])).permute(0, 3, 1, 2).float() / 255)
    assert cover[:4] == pytest.approx(1.0, abs=0.05)
    assert scores[:4] == pytest.approx(own["score"].double().numpy(), rel=0.05, abs=1e-3)
    assert cover[4] == 0.0 and np.isnan(scores[4])
    red = lambda views, size: np.broadcast_to(np.array([230, 20, 20], np.uint8), (len(views), size[1], size[0], 3))  # noqa: E731
    filled, _ = warped_photo_scores(teacher, [f.image for f in frames], poses, platform.intrinsics, away, None, 64,
                                    fill=red)  # fmt: skip
    assert filled[0] > 0.5  # what no photo saw comes from the fill: all red


def test_the_suggestion_is_ranked_on_the_warped_input_photos():
    """The field (AimScorer) wants the optical axis along +x, so among the views that hold the
    subject it prefers those with the subject at the frame's edge; the teacher on the input photos
    warped into each view wants the (red) subject at the centre: with ``photo_rank`` the
    suggestion is the teacher's choice, still holds the subject, and carries its warped score."""
    from aes_planner.search.framing import PhotoSet, project_corners

    platform = rig_platform(pan_limits_deg=(-120.0, 120.0), tilt_limits_deg=(-40.0, 40.0))
    subject = subject_at((3.0, 0.9, 1.3), (0.15, 0.15, 0.15))
    frames, poses = red_dot_photos(platform, subject.centre_m)
    scorer = AimScorer([1.0, 0.0, 0.0])
    scorer.teacher = CentreRedTeacher()
    cfg = SearchConfig.preset("fast", top_k=2, steps=0)

    def off_centre(result):
        c = torch.as_tensor(subject.centre_m)[None, None]
        u, v, _ = project_corners(c, torch.as_tensor(result.best.cam2world[None]), platform.intrinsics)
        return math.hypot(float(u) - 0.5, float(v) - 0.5)

    runs = {}
    for on in (False, True):
        fc = FramingConfig(photo_rank=on, photo_width_px=64)
        framing = Framing([subject], [], platform.intrinsics, fc, PhotoSet.of(frames) if on else None)
        runs[on] = search_views(scorer, poses, platform, cfg, framing=framing)
        assert runs[on].suggestions and all(s.held == pytest.approx(1.0) for s in runs[on].suggestions)
    assert "photo" not in runs[False].best.terms
    assert runs[True].best.terms["photo"] > 0 and runs[True].best.terms["photo_cover"] > 0.3
    assert runs[True].timings_ms["photo_rank"] > 0
    assert off_centre(runs[True]) < 0.05 < off_centre(runs[False])


def test_the_photo_ranking_config_is_checked():
    for kw, name in ((dict(photo_rank=1), "photo_rank"), (dict(photo_turn_deg=90.0), "photo_turn_deg"),
                     (dict(photo_step_deg=0.0), "photo_step_deg"), (dict(photo_min_cover=1.5), "photo_min_cover"),
                     (dict(photo_width_px=8), "photo_width_px"), (dict(photo_top=-1), "photo_top")):  # fmt: skip
        with pytest.raises(AesPlannerError, match=name):
            FramingConfig(**kw)


# ---------------------------------------------------------------- a box cut by the image's border
def _picture_on_a_wall(seen_to_y: float = 3.0, picture_y=(1.0, 2.2)):
    """A camera at the origin looking along +x at a wall 3 m away (Gaussians every 5 cm, white)
    with a picture on it (y in ``picture_y``, z in [-0.4, 0.4], coloured): the picture runs past
    the image's left border (world +y). Other views saw the wall up to ``seen_to_y``."""
    cam = np.asarray(look_at(np.zeros(3), np.array([1.0, 0.0, 0.0])))
    k = Intrinsics.from_fov(64, 48, 60.0)
    yy, zz = np.meshgrid(np.arange(-3.0, seen_to_y + 1e-9, 0.05), np.arange(-2.0, 2.0 + 1e-9, 0.05))
    means = np.c_[np.full(yy.size, 3.0), yy.ravel(), zz.ravel()]
    pic = (means[:, 1] >= picture_y[0]) & (means[:, 1] <= picture_y[1]) & (np.abs(means[:, 2]) <= 0.4)
    rng = np.random.default_rng(0)
    colours = np.where(pic[:, None], rng.uniform([0.5, 0.0, 0.0], [1.0, 0.4, 0.3], (len(means), 3)), 0.92)
    depth = np.full((48, 64), 3.0)
    u_edge = k.cx - k.fx * picture_y[0] / 3.0
    region = Region(
        "a.png", 0, math.floor(k.cy - k.fy * 0.4 / 3.0), math.ceil(u_edge), math.ceil(k.cy + k.fy * 0.4 / 3.0)
    )
    return cam, k, depth, means, colours, region


def test_a_box_cut_by_the_border_grows_over_what_other_views_saw():
    """The picture runs 0.5 m past the left border; other views saw it and the wall beyond: the
    subject is grown to the picture's far edge, and no side is left open."""
    cam, k, depth, means, colours, region = _picture_on_a_wall()
    opac = np.full(len(means), 0.9)
    s = lift_region(means, opac, cam, k, region, depth_map=depth, colours=colours)
    assert s.cut_by_frame and s.grown > 50 and s.open_sides == ()
    assert 2.1 <= s.outline_m[:, 1].max() <= 2.3, s.outline_m[:, 1].max()  # the picture's far edge, not the wall's
    bare = lift_region(means, opac, cam, k, region, depth_map=depth)  # no colours: as before
    assert bare.grown == 0 and bare.outline_m[:, 1].max() < 1.8 and bare.open_sides == ("left",)
    off = lift_region(means, opac, cam, k, region, FramingConfig(grow_beyond_frame=False), depth_map=depth,
                      colours=colours)  # fmt: skip
    assert off.grown == 0


def test_a_cut_subject_that_no_view_saw_end_stays_open():
    """The wall was reconstructed only up to y = 1.9 m, inside the picture: the subject grows to
    where the reconstruction ends and its left side stays open (the inputs never saw it end)."""
    cam, k, depth, means, colours, region = _picture_on_a_wall(seen_to_y=1.9)
    s = lift_region(means, np.full(len(means), 0.9), cam, k, region, depth_map=depth, colours=colours)
    assert s.open_sides == ("left",) and s.grown > 0
    assert s.outline_m[:, 1].max() <= 1.95
    assert "never saw" in Framing([s], [], k, FramingConfig()).notes()[0]


@settings(max_examples=40, deadline=None)
@given(
    x0=st.integers(0, 40),
    y0=st.integers(0, 30),
    w=st.integers(1, 64),
    h=st.integers(1, 48),
    seen=st.floats(1.0, 3.0),
)
def test_boxes_at_any_border_lift_without_surprises(x0, y0, w, h, seen):
    """Any box inside the image, at a border or not, of one pixel or the whole image: the lift
    either refuses it with a FramingError or returns a finite subject whose open sides are among
    the borders the box touches, grown only over points on the wall."""
    cam, k, depth, means, colours, _ = _picture_on_a_wall(seen_to_y=seen)
    region = Region("a.png", x0, y0, min(64, x0 + w), min(48, y0 + h))
    try:
        s = lift_region(means, np.full(len(means), 0.9), cam, k, region, depth_map=depth, colours=colours)
    except FramingError:
        return
    touched = {side for side, hit in (("left", region.x0 == 0), ("top", region.y0 == 0),
                                      ("right", region.x1 == 64), ("bottom", region.y1 == 48)) if hit}  # fmt: skip
    assert set(s.open_sides) <= touched and s.cut_by_frame == bool(touched)
    assert np.isfinite(s.outline_m).all() and np.isfinite(s.corners_m).all()
    np.testing.assert_allclose(
        s.outline_m[:, 0], 3.0, atol=0.13
    )  # on the wall (the drawn box sits at the depth bin's centre)
    if not touched:
        assert s.grown == 0


def test_an_open_side_is_held_with_room_beyond_it_while_a_view_gives_it():
    """A subject open on its left (world +y here) is held with its outline and the same shifted
    ``open_reach`` of its extent towards that side; a view that holds only what was seen of it
    then no longer counts, and with no room anywhere the search falls back to what was seen."""
    cam, k, depth, means, colours, region = _picture_on_a_wall(seen_to_y=1.9)
    s = lift_region(means, np.full(len(means), 0.9), cam, k, region, depth_map=depth, colours=colours)
    assert s.open_sides == ("left",) and s.reach_m.shape == (1, 3)
    assert s.reach_m[0, 1] > 0.5 and abs(s.reach_m[0, 0]) < 0.1 * s.reach_m[0, 1]  # along the wall, towards +y
    pts = s.hold_points_m("points", 0.2, 0.5)
    assert len(pts) == 2 * len(s.outline_m)
    np.testing.assert_allclose(
        pts[len(s.outline_m) :] - s.outline_m, np.broadcast_to(0.5 * s.reach_m[0], s.outline_m.shape)
    )
    back = np.asarray(look_at(np.array([-2.0, 1.2, 0.0]), np.array([3.0, 1.5, 0.0])))  # far back, wide view
    tight = np.asarray(look_at(np.array([1.5, 1.4, 0.0]), np.array([3.0, 1.4, 0.0])))  # close: the seen part only
    poses = torch.as_tensor(np.stack([back, tight]))
    seen = Framing([s], [], k, FramingConfig(open_reach=0.0)).feasible(poses).tolist()
    room = Framing([s], [], k, FramingConfig(open_reach=0.5)).feasible(poses).tolist()
    assert seen == [True, True] and room == [True, False]


@pytest.mark.parametrize("kw, word", [({"open_reach": -1.0}, "open_reach"), ({"grow_colour_tol": 2.0}, "grow_colour_tol"),
                                      ({"grow_beyond_frame": 1}, "grow_beyond_frame")])  # fmt: skip
def test_the_growth_knobs_are_checked(kw, word):
    with pytest.raises(AesPlannerError, match=word):
        FramingConfig(**kw)


def test_an_open_subject_no_view_leaves_room_for_is_refused_with_the_closest_view():
    """A subject open on one side whose unseen continuation no reachable view could hold: no view
    can be trusted to hold all of it, and the search says so (issue 40 item 2) with the closest
    view, unless ``open_refuse`` is off (then it holds what was seen, and warns)."""
    platform = rig_platform(pan_limits_deg=(-30.0, 30.0), tilt_limits_deg=(-20.0, 20.0))
    base = np.asarray(platform.rig.base_xyz_m, float)
    subject = subject_at(base + np.array([4.0, 0.0, 0.0]), (0.1, 0.1, 0.1))
    subject.cut_by_frame, subject.open_sides = True, ("left",)
    subject.reach_m = np.array([[0.0, 40.0, 0.0]])  # it may go on 40 m to the left: no view holds half of that
    with pytest.raises(FramingError, match="no view can be trusted") as exc:
        search_views(AimScorer([1.0, 0.0, 0.0]), rig_inputs(platform), platform, SearchConfig.preset("fast"),
                     framing=Framing([subject], [], platform.intrinsics, FramingConfig()))  # fmt: skip
    assert "closest view" in str(exc.value) and "(left)" in str(exc.value)
    lenient = Framing([subject], [], platform.intrinsics, FramingConfig(open_refuse=False))
    result = search_views(AimScorer([1.0, 0.0, 0.0]), rig_inputs(platform), platform, SearchConfig.preset("fast"),
                          framing=lenient)  # fmt: skip
    assert result.suggestions and any("never saw" in w for w in result.warnings)
    seen = lenient.with_margin(0.05, 0.0)
    assert all(float(seen.violation(torch.as_tensor(s.cam2world[None]))[0]) == 0.0 for s in result.suggestions)


def test_the_fill_term_grows_as_the_subject_fills_the_frame():
    """``fill_weight`` adds the share of the frame the subject's projected rectangle covers: more
    from near than from far, at most 1 (the rectangle clipped to the frame), 0 with no subject."""
    k = Intrinsics.from_fov(64, 48, 60.0)
    s = subject_at((4.0, 0.0, 0.0), (0.3, 0.3, 0.3))
    poses = torch.as_tensor(np.stack([np.asarray(look_at(np.array([x, 0.0, 0.0]), np.array([4.0, 0.0, 0.0])))
                                      for x in (0.0, 2.0, 3.5)]))  # fmt: skip
    framing = Framing([s], [], k, FramingConfig(fill_weight=0.1))
    fill = framing.fill(poses).numpy()
    assert 0.0 < fill[0] < fill[1] < fill[2] <= 1.0
    np.testing.assert_allclose(framing.soft_terms(poses).numpy(), 0.1 * fill)
    assert Framing([s], [], k, FramingConfig()).soft_terms(poses).abs().max() == 0.0
    assert Framing([], [], k, FramingConfig(fill_weight=0.1)).fill(poses).abs().max() == 0.0


def test_a_smoothed_stage_one_ranks_a_view_by_its_neighbourhood():
    """``smooth_dedup``: each finite objective becomes the Gaussian-weighted mean of the finite ones
    around it; an infeasible (-inf) candidate stays out, and a lone peak among poor neighbours
    falls below a broad hill."""
    from aes_planner.search.pipeline import _smoothed
    from aes_planner.search.space import space_for

    platform = rig_platform(pan_limits_deg=(-90.0, 90.0), tilt_limits_deg=(-30.0, 30.0))
    space = space_for(platform, SearchConfig.preset("fast"))
    step = math.radians(2.0)
    pans = torch.tensor([-0.6, -0.6 + step, -0.6 + 2 * step, 0.6 - step, 0.6, 0.6 + step, 0.0], dtype=torch.float64)
    cand = torch.stack([pans, torch.zeros_like(pans)], -1)
    obj = torch.tensor([0.70, 0.72, 0.70, 0.20, 0.80, 0.20, -math.inf], dtype=torch.float64)
    out = _smoothed(space, cand, obj, 0.25)
    assert out[6] == -math.inf and bool(torch.isfinite(out[:6]).all())
    assert float(out[1]) > float(out[4])  # the broad hill beats the lone peak
    assert float(out[:6].min()) >= 0.2 and float(out[:6].max()) <= 0.8
    np.testing.assert_allclose(_smoothed(space, cand, obj, 1e-6)[:6].numpy(), obj[:6].numpy())
