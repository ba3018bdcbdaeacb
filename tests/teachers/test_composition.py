"""Composition teacher: known answers for every term and the total, and finite gradients everywhere."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.config import ConfigError
from aes_planner.teachers import CompositionConfig, CompositionTeacher, CompositionWeights, TeacherError
from aes_planner.teachers.composition import CHANNELS, TERMS
from aes_planner.teachers.synthetic import add_clutter, canvas, draw_box, draw_disc, draw_horizon

H, W = 96, 128
WALL = (0.5, 0.5, 0.52)
RED = (0.85, 0.2, 0.15)


@pytest.fixture(scope="module")
def teacher():
    return CompositionTeacher()


def explain(teacher, *images):
    """One dict of plain floats per image."""
    out = teacher.explain(torch.stack(images))
    return [{k: float(v[i]) for k, v in out.items()} for i in range(len(images))]


def subject(cx, cy, r=0.12, size=(H, W)):
    return draw_disc(canvas(*size, WALL), cx, cy, r, RED)


def test_map_shape_and_attributes(teacher):
    fmap = teacher.features(torch.rand(3, 3, 50, 70))
    assert fmap.shape == (3, teacher.feature_channels, *teacher.feature_size) == (3, len(CHANNELS), 16, 16)
    e = teacher.explain(torch.rand(2, 3, 40, 40))
    assert set(e) == {"score", "content", "subject_presence", "horizon_presence", *TERMS}
    assert all(v.shape == (2,) for v in e.values())


def test_score_is_head_of_features_and_in_unit_range(teacher):
    x = torch.stack([subject(1 / 3, 1 / 3), torch.rand(3, H, W), canvas(H, W)])
    s = teacher.score(x)
    torch.testing.assert_close(s, teacher.head(teacher.features(x)), rtol=0, atol=0)
    torch.testing.assert_close(s, teacher.explain(x)["score"], rtol=0, atol=0)
    for v in teacher.explain(x).values():
        assert bool(((v >= 0) & (v <= 1)).all())


def test_batch_items_are_independent(teacher):
    a, b = subject(1 / 3, 1 / 3), draw_horizon(canvas(H, W), 0.5, 4.0)
    both = teacher.score(torch.stack([a, b]))
    torch.testing.assert_close(both, torch.cat([teacher.score(a[None]), teacher.score(b[None])]), rtol=1e-5, atol=1e-6)


def test_subject_on_thirds_beats_centred_beats_cut(teacher):
    thirds, centred, cut = explain(teacher, subject(1 / 3, 1 / 3), subject(0.5, 0.5), subject(0.02, 0.5, r=0.2))
    assert thirds["thirds"] > centred["thirds"] + 0.4
    assert centred["balance"] > thirds["balance"]  # the price of going off-centre, smaller than the gain
    assert cut["border"] < 0.5 < thirds["border"] == pytest.approx(1.0)
    assert centred["border"] == pytest.approx(1.0)
    assert thirds["score"] > centred["score"] + 0.03
    assert centred["score"] > cut["score"] + 0.1


@pytest.mark.parametrize("corner", [(1 / 3, 1 / 3), (2 / 3, 1 / 3), (1 / 3, 2 / 3), (2 / 3, 2 / 3)])
def test_every_power_point_counts_alike(teacher, corner):
    e = teacher.explain(subject(*corner)[None])
    ref = teacher.explain(subject(1 / 3, 1 / 3)[None])
    assert e["thirds"].item() == pytest.approx(ref["thirds"].item(), abs=0.03)


def test_counterweight_restores_balance(teacher):
    alone = subject(1 / 3, 0.5)
    both = draw_disc(alone.clone(), 0.75, 0.5, 0.06, (0.2, 0.3, 0.8))
    e = explain(teacher, alone, both)
    assert e[1]["balance"] > e[0]["balance"] + 0.1


def test_horizon_on_a_third_beats_the_middle_and_level_beats_tilted(teacher):
    third, middle, tilt3, tilt8 = (
        draw_horizon(canvas(H, W), 2 / 3),
        draw_horizon(canvas(H, W), 0.5),
        draw_horizon(canvas(H, W), 2 / 3, 3.0),
        draw_horizon(canvas(H, W), 2 / 3, -8.0),
    )
    e = explain(teacher, third, middle, tilt3, tilt8)
    assert all(x["horizon_presence"] > 0.4 for x in e)  # all four are found as horizons
    assert e[0]["horizon_placement"] > 0.9 > 0.2 > e[1]["horizon_placement"]
    assert e[0]["horizon_level"] > 0.95 > 0.5 > e[2]["horizon_level"] > e[3]["horizon_level"]
    assert e[0]["score"] > e[1]["score"] + 0.05
    assert e[0]["score"] > e[2]["score"] > e[3]["score"]
    upper = explain(teacher, draw_horizon(canvas(H, W), 1 / 3))
    assert upper[0]["horizon_placement"] > 0.9


def test_horizon_terms_are_neutral_without_a_horizon(teacher):
    e = explain(teacher, subject(1 / 3, 1 / 3))
    assert e[0]["horizon_presence"] < 0.05
    w = CompositionWeights()
    rest = {t: getattr(w, t) for t in TERMS if not t.startswith("horizon")}
    earned = {t: e[0]["subject_presence"] if t in ("thirds", "border", "subject_size") else 1.0 for t in rest}
    expected = e[0]["content"] * sum(wt * earned[t] * e[0][t] for t, wt in rest.items()) / sum(rest.values())
    assert e[0]["score"] == pytest.approx(expected, abs=0.01)


def test_clutter_versus_clean(teacher):
    clean = subject(1 / 3, 1 / 3)
    busy = add_clutter(clean.clone(), 60, np.random.default_rng(0))
    e = explain(teacher, clean, busy)
    assert e[0]["clutter"] > 0.9 and e[1]["clutter"] < 0.3
    assert e[0]["score"] > e[1]["score"] + 0.1


def test_subject_size_prefers_a_sensible_share_of_the_frame(teacher):
    speck, good, filling = subject(1 / 3, 1 / 3, r=0.04), subject(0.4, 0.4, r=0.2), subject(0.5, 0.5, r=0.9)
    e = explain(teacher, speck, good, filling)
    assert e[1]["subject_size"] > 0.8
    assert e[0]["subject_size"] < 0.3
    assert e[1]["score"] > e[0]["score"] and e[1]["score"] > e[2]["score"]


@pytest.mark.parametrize(
    "name, image",
    [
        ("blank wall", canvas(H, W, WALL)),
        ("black", canvas(H, W, (0, 0, 0))),
        ("white", canvas(H, W, (1, 1, 1))),
        (
            "sky gradient",
            torch.stack([torch.linspace(0.55, 0.9, H)[:, None].expand(H, W)] * 3)
            * torch.tensor([0.7, 0.8, 1.0])[:, None, None],
        ),
        ("faint shading", canvas(H, W, WALL) + 0.02 * torch.linspace(0, 1, W)),
    ],
)
def test_featureless_views_cannot_game_the_score(teacher, name, image):
    e = explain(teacher, image, subject(1 / 3, 1 / 3))
    assert e[0]["content"] < 0.2, name
    assert e[0]["score"] < 0.12, name
    assert e[1]["score"] > 0.6
    assert e[1]["score"] > 4 * e[0]["score"]


def test_texture_without_a_subject_scores_below_a_composition(teacher):
    noise = torch.rand(3, H, W, generator=torch.Generator().manual_seed(0))
    checker = ((torch.arange(H)[:, None] // 8 + torch.arange(W)[None] // 8) % 2).float().expand(3, H, W)
    e = explain(teacher, noise, checker, draw_disc(draw_horizon(canvas(H, W), 2 / 3), 1 / 3, 0.45, 0.1, RED))
    assert e[0]["content"] > 0.9 and e[1]["content"] > 0.9  # not empty ...
    assert (
        max(e[0]["subject_presence"], e[1]["subject_presence"]) < 0.35 < 0.95 < e[2]["subject_presence"]
    )  # ... no subject ...
    assert max(e[0]["score"], e[1]["score"]) < 0.3 < 0.75 < e[2]["score"]  # ... and no composition either


def _pattern_of(r, nx, ny):
    img = canvas(H, W, WALL)
    for i in range(nx):
        for j in range(ny):
            img = draw_disc(img, (i + 0.5) / nx, (j + 0.5) / ny, r, RED)
    return img


def test_a_lone_object_beats_the_same_object_repeated_as_a_pattern(teacher):
    # Each disc of a pattern is as compact, bounded and colourful as the lone one: only its
    # repetition (the same colour's contrast all over the frame, evidence all around it) tells
    # a texture from a subject.
    lone, small, large = explain(
        teacher, subject(1 / 3, 1 / 3, r=0.08), _pattern_of(0.06, 6, 4), _pattern_of(0.1, 4, 3)
    )
    assert lone["subject_presence"] > 0.8 > 0.65 > large["subject_presence"] > small["subject_presence"]
    assert small["subject_presence"] < 0.4
    assert lone["score"] > large["score"] + 0.2 and lone["score"] > small["score"] + 0.3


def test_bare_architecture_has_no_subject_until_an_object_enters(teacher):
    room = draw_box(
        draw_box(
            draw_box(canvas(H, W, (0.78, 0.78, 0.76)), 0.0, 0.0, 0.45, 1.0, (0.62, 0.62, 0.6)),
            0.0,
            0.7,
            1.0,
            1.0,
            (0.5, 0.42, 0.33),
        ),
        0.0,
        0.0,
        1.0,
        0.12,
        (0.92, 0.92, 0.9),
    )
    boards = canvas(H, W, (0.55, 0.4, 0.25))
    for k in range(16):
        boards = draw_box(boards, k / 16, 0.0, k / 16 + 0.008, 1.0, (0.3, 0.2, 0.12))
    e = explain(
        teacher,
        room,
        draw_disc(room, 2 / 3, 0.55, 0.1, RED),
        boards,
        draw_disc(boards, 1 / 3, 0.4, 0.12, (0.2, 0.5, 0.85)),
    )
    for bare, furnished in ((e[0], e[1]), (e[2], e[3])):
        assert bare["subject_presence"] < 0.15 < 0.95 < furnished["subject_presence"]
        assert bare["score"] < 0.4 and furnished["score"] > bare["score"] + 0.3


def test_score_does_not_depend_on_resolution(teacher):
    small = draw_box(draw_horizon(canvas(96, 128), 2 / 3), 0.25, 0.2, 0.4, 0.62, RED)
    large = draw_box(draw_horizon(canvas(480, 640), 2 / 3), 0.25, 0.2, 0.4, 0.62, RED)
    a, b = teacher.score(small[None]).item(), teacher.score(large[None]).item()
    assert a == pytest.approx(b, abs=0.03)


def test_gradient_wrt_the_image_exists_for_rgb_scoring(teacher):
    x = subject(0.45, 0.4)[None].requires_grad_(True)
    teacher.score(x).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_gradient_wrt_the_map_exists_for_the_field(teacher):
    fmap = teacher.features(subject(0.45, 0.4)[None]).requires_grad_(True)
    teacher.head(fmap).sum().backward()
    assert torch.isfinite(fmap.grad).all() and fmap.grad.abs().sum() > 0


@pytest.mark.parametrize("fill", [0.0, 1.0, 0.5, 1e-30, 1.0 - 1e-7])
def test_gradients_finite_on_constant_images(teacher, fill):
    x = torch.full((2, 3, 32, 48), fill, requires_grad=True)
    s = teacher.score(x)
    s.sum().backward()
    assert torch.isfinite(s).all() and torch.isfinite(x.grad).all()


@settings(max_examples=25)
@given(
    h=st.sampled_from([1, 2, 3, 7, 16, 63, 64, 65, 200]),
    w=st.sampled_from([1, 2, 5, 64, 97, 4096]),
    scale=st.sampled_from([0.0, 1e-30, 1e-6, 1.0, 1e6, 1e30]),
    offset=st.floats(-2.0, 2.0),
    seed=st.integers(0, 2**16),
)
def test_gradients_finite_for_any_size_and_value(h, w, scale, offset, seed):
    teacher = _TEACHER
    g = torch.Generator().manual_seed(seed)
    x = (offset + scale * torch.randn(1, 3, h, w, generator=g)).requires_grad_(True)
    e = teacher.explain(x)
    sum(e.values()).sum().backward()
    assert all(torch.isfinite(v).all() for v in e.values())
    assert torch.isfinite(x.grad).all()


@settings(max_examples=60)
@given(
    scale=st.sampled_from([0.0, 1e-12, 1e-3, 1.0, 1e3, 1e12]),
    signed=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_head_gradients_finite_for_any_rendered_map(scale, signed, seed):
    # The field renders maps the trunk never made: negative, huge, all zero. The head must cope.
    g = torch.Generator().manual_seed(seed)
    fmap = scale * torch.randn(2, 4, 16, 16, generator=g)
    fmap = (fmap if signed else fmap.abs()).requires_grad_(True)
    e = _TEACHER.explain_map(fmap)
    sum(e.values()).sum().backward()
    assert all(torch.isfinite(v).all() for v in e.values())
    assert torch.isfinite(fmap.grad).all()


_TEACHER = CompositionTeacher()


def test_float64_gradcheck_of_the_head():
    teacher = CompositionTeacher().double()
    fmap = teacher.features(subject(0.4, 0.45)[None].double()).detach()
    # Move off the kinks of clamp/relu at exactly 0 (flat regions have exactly zero energy).
    fmap = (fmap + 0.01 * torch.rand_like(fmap)).requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda m: torch.stack(list(teacher.explain_map(m).values())),
        (fmap,),
        eps=1e-7,
        atol=1e-6,
        rtol=1e-4,
        fast_mode=True,
    )


def test_float64_gradcheck_of_the_features_on_a_small_image():
    teacher = CompositionTeacher(CompositionConfig(work_size=16, feature_size=4)).double()
    x = (0.2 + 0.6 * torch.rand(1, 3, 16, 16, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(teacher.features, (x,), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_teacher_is_frozen_and_stays_in_eval_mode():
    teacher = CompositionTeacher()
    teacher.train()
    assert not teacher.training
    assert not any(p.requires_grad for p in teacher.parameters())


@pytest.mark.parametrize(
    "make, key",
    [
        (lambda: CompositionConfig(feature_size=15), "feature_size"),
        (lambda: CompositionConfig(work_size=8), "work_size"),
        (lambda: CompositionConfig(thirds_sigma=0.0), "thirds_sigma"),
        (lambda: CompositionConfig(tilt_tolerance_deg=math.nan), "tilt_tolerance_deg"),
        (lambda: CompositionWeights(thirds=-1.0), "weights.thirds"),
    ],
)
def test_config_errors_name_the_key(make, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        make()


def test_all_zero_weights_refused():
    with pytest.raises(ConfigError, match="at least one weight"):
        CompositionWeights(**{t: 0.0 for t in TERMS})


def test_weights_change_the_total():
    only_thirds = CompositionTeacher(
        CompositionConfig(weights=CompositionWeights(**{t: float(t == "thirds") for t in TERMS}))
    )
    e = only_thirds.explain(subject(1 / 3, 1 / 3)[None])
    assert e["score"].item() == pytest.approx(
        e["content"].item() * e["subject_presence"].item() * e["thirds"].item(), rel=1e-5
    )


@pytest.mark.parametrize(
    "images, match",
    [
        (torch.rand(3, 32, 32), r"\[B, 3, H, W\]"),
        (torch.rand(1, 4, 32, 32), r"\[B, 3, H, W\]"),
        (torch.zeros(1, 3, 8, 8, dtype=torch.uint8), "float"),
        (torch.full((1, 3, 8, 8), math.nan), "NaN"),
        (torch.rand(0, 3, 8, 8), "empty"),
        (np.zeros((1, 3, 8, 8)), "torch.Tensor"),
    ],
)
def test_bad_inputs_are_refused_with_advice(teacher, images, match):
    with pytest.raises(TeacherError, match=match):
        teacher.score(images)


def test_head_refuses_maps_of_the_wrong_shape(teacher):
    with pytest.raises(TeacherError, match="feature_size"):
        teacher.head(torch.zeros(1, 4, 14, 14))


def test_constant_tables_are_shared_by_value_not_by_reference():
    """The filters and cell matrices are computed once per setting (a field builds its teacher
    on every build), but each teacher holds its own copies: an in-place change in one teacher
    leaves the next one's scores as they were."""
    image = draw_disc(canvas(96, 128), 0.33, 0.33, 0.12, (0.9, 0.2, 0.1))[None]
    first = CompositionTeacher()
    before = first.score(image).clone()
    first._annulus.zero_()
    first._filters_x.zero_()
    second = CompositionTeacher()
    assert torch.equal(second.score(image), before)
    assert not torch.equal(first.score(image), before)
    other = CompositionTeacher(CompositionConfig(thirds_sigma=0.2))
    assert not torch.equal(other._thirds, second._thirds)  # a different setting gets its own tables
