"""The subject-versus-structure measurement of the ``teachers`` bench: names, labels, metrics."""

import math

import pytest
import torch

from aes_planner.bench import teachers as bench
from aes_planner.bench.teachers import SubjectViews, ViewLabel, classify_object, subject_metrics

sim = pytest.importorskip("aes_planner.sim")


@pytest.mark.parametrize(
    "name, group",
    [
        ("floor", None),
        ("wall_far_left", None),
        ("wall_side1", None),
        ("ceiling_edge", None),
        ("ground_outside", None),
        ("hill3", None),
        ("rug", None),
        ("cloth", None),
        ("table_top", None),
        ("table_leg2", None),
        ("door", None),
        ("window_sill", None),
        ("post4", None),
        ("rail1", None),
        ("label2", None),
        ("baseboard", None),
        ("painting_sofa_frame", "painting_sofa"),
        ("painting_side_disc0", "painting_side"),
        ("work3_canvas", "work3"),
        ("plant1_leaves2", "plant1"),
        ("tree10_crown0", "tree10"),
        ("table0_vase", "table0"),
        ("sofa_arm1", "sofa"),
        ("cushion2", "sofa"),
        ("book1_4", "shelf"),
        ("shelf_case", "shelf"),
        ("roof", "house"),
        ("window2", "house"),
        ("plinth", "sculpture"),
        ("sculpture1", "sculpture"),
        ("bloom3", "vase"),
        ("vase_belly", "vase"),
        ("fruit2", "bowl"),
        ("book2", "books"),
        ("flame", "candle"),
        ("bottle1_label", "bottle1"),
        ("bush2_1", "bush2"),
        ("cup0", "cup0"),
        ("rock1", "rock1"),
        ("lamp_shade", "lamp"),
        ("bench_leg0", "bench"),
    ],
)
def test_objects_split_into_structure_and_grouped_subjects(name, group):
    assert classify_object(name) == group


def test_every_family_object_is_classified_on_purpose():
    # A new kind of object in a family must be placed knowingly: unmatched names become
    # subjects of their own, which is right only for single-primitive things.
    singles = {"cup", "rock", "house", "vase", "bowl", "candle"}
    for family in sim.FAMILIES:
        for o in sim.load_scene(f"{family}:0").spec.objects:
            g = classify_object(o.name)
            if g is not None and g == o.name:
                assert g.rstrip("0123456789") in singles, (family, o.name)


def test_labels_of_a_texture_view_and_a_subject_view():
    scene = sim.load_scene("tabletop:1")
    camera = sim.SimCamera(scene, sim.SimCameraConfig(width=128, height=96))
    grid = camera.kinematics.joint_grid(6, 4)
    floor, books, cut = (
        bench.label_view(scene, camera, camera.capture_joints(*map(float, grid[k]))) for k in (1, 16, 19)
    )
    assert floor.subject is None and floor.structure_only and floor.texture > 0.9
    assert books.subject == "books" and books.inside == 1.0 and 0.03 < books.cover < 0.1
    assert math.isclose(books.quality, books.cover / bench.QUALITY_COVER)
    assert cut.subject is None and not cut.structure_only and cut.inside < 0.5  # a vase cut by the frame: neither


def _views(labels_by_scene):
    v = SubjectViews()
    for scene, labels in labels_by_scene.items():
        for label, sweep in labels:
            v.images.append(torch.zeros(3, 4, 4))
            v.labels.append(label)
            v.scenes.append(scene)
            v.sweep.append(sweep)
    return v


SUBJ = ViewLabel("vase", False, 0.8, 0.08, 1.0, 0.0)
HALF = ViewLabel("vase", False, 0.4, 0.04, 1.0, 0.0)
TEX = ViewLabel(None, True, 0.0, 0.0, 0.0, 0.9)
BARE = ViewLabel(None, True, 0.0, 0.0, 0.0, 0.0)


def test_metrics_count_pairs_within_scenes_and_the_sweep_argmax():
    views = _views(
        {
            "indoor:0": [(SUBJ, False), (HALF, False), (TEX, False), (BARE, False), (TEX, True), (SUBJ, True)],
            "outdoor:0": [(SUBJ, False), (BARE, False), (BARE, True), (SUBJ, True)],
        }
    )
    scores = [
        0.9,
        0.5,
        0.6,
        0.1,
        0.95,
        0.2,  # indoor: the texture view beats the weaker subject view and wins the sweep
        0.3,
        0.3,
        0.1,
        0.8,
    ]  # outdoor: a tie, and the subject view wins the sweep
    m = subject_metrics(scores, views)
    assert m["subject_pairs"] == 5 and m["subject_pairs_texture"] == 2
    assert m["subject_pref_acc_indoor"] == pytest.approx(3 / 4)
    assert m["subject_pref_acc_outdoor"] == pytest.approx(0.5)
    assert m["subject_pref_acc"] == pytest.approx(3.5 / 5)
    assert m["subject_pref_acc_texture"] == pytest.approx(0.5)
    assert m["sweep_argmax_subject_rate"] == 0.5 and m["sweep_argmax_texture_rate"] == 0.5
    assert m["sweep_argmax_structure_rate"] == 0.5
    assert m["sweep_subject_share"] == 0.5
    # outdoor's random views tie, so only indoor has a within-scene SRCC
    assert m["subject_srcc"] == pytest.approx(bench.srcc([0.9, 0.5, 0.6, 0.1], [0.8, 0.4, 0, 0]))


def test_metrics_refuse_a_score_count_that_does_not_match():
    with pytest.raises(ValueError, match="one score per view"):
        subject_metrics([0.1], _views({"indoor:0": [(SUBJ, False), (BARE, False)]}))
