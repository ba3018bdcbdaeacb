"""The planner applies a PlannerRequest's keep/avoid regions to its next searches, says which are
active in its diagnostics, and refuses (counts, keeps the old framing) regions it cannot use."""

from __future__ import annotations

import numpy as np
import pytest

from aes_planner.eval.framing import FramingEvalConfig, object_points, pick_subject, true_holds
from aes_planner.messages import PlannerRequest
from aes_planner.messages.diagnostics import FramingRegion

from .nodekit import passive_sim_planner


def test_planner_keeps_the_requested_subject_in_its_suggestions():
    source, node, kin = passive_sim_planner("tabletop:1")
    sweep = kin.sweep(4)
    poses = kin.forward(sweep[:, 0], sweep[:, 1])
    k = source.platform.intrinsics
    picked = pick_subject(source.scene, poses, k, 0, FramingEvalConfig(min_frac=0.005))
    assert picked is not None
    obj_i, view, region = picked
    now = 1.0
    for p in [*np.delete(poses, view, axis=0), poses[view]]:  # the subject's view last: "latest"
        node.step({"camera/frame": [source.capture(p, stamp_s=now)]}, now)
        now += 1.0
    # a frame it does not hold, then a box outside the image: refused, counted, nothing changes
    bad = [FramingRegion("nope.png", 1, 1, 5, 5), FramingRegion("latest", 1, 1, 500, 5)]
    for r in bad:
        node.step({"planner/request": [PlannerRequest("suggest", set_framing=True, keep=[r])]}, now)
    assert node.counters["framing_rejected"] == 2 and node.proposer.framing is None
    box = FramingRegion("latest", region.x0, region.y0, region.x1, region.y1)
    out = node.step({"planner/request": [PlannerRequest("suggest", set_framing=True, keep=[box])]}, now + 0.1)
    assert out["planner/suggestion"], "the request asked for a suggestion"
    best = out["planner/suggestion"][-1].candidates[0]
    points = object_points(source.scene.objects[obj_i])
    assert true_holds(points, best.cam2world[None], k)[0], "the suggestion cuts the kept subject"
    diag = node.diagnostics(now + 0.2)
    active = {name: v for name, v in diag.values.items() if name.startswith("framing.keep.latest")}
    assert len(active) == 1 and list(active.values())[0] == 1.0
    # the lifted box, for the Foxglove view: around the subject's true centre
    from aes_planner.transport.foxglove_view import framing_boxes

    ((kind, centre, size, _),) = framing_boxes(diag.values)
    assert kind == "keep" and np.all(np.abs(centre - points.mean(0)) < size / 2 + 0.05)
    # both lists empty: framing off
    node.step({"planner/request": [PlannerRequest("suggest", set_framing=True)]}, now + 0.3)
    assert node.proposer.framing is None
    assert not any(n.startswith("framing.") for n in node.diagnostics(now + 0.4).values)
    assert np.isfinite(best.cam2world).all()


def test_planner_ranks_the_framed_views_on_its_held_frames_with_photo_rank():
    """``photo_rank: true`` in the planner's config: a keep request's searches rank the views that
    hold the subject by the teacher on the frames the planner holds, warped into each view; the
    published best candidate holds the subject (true geometry) and carries that score, which is
    the teacher's score of exactly those frames warped into it."""
    import dataclasses

    from aes_planner.search.photo_warp import warped_photo_scores

    source, node, kin = passive_sim_planner("tabletop:1")
    node.config = dataclasses.replace(node.config, photo_rank=True)
    sweep = kin.sweep(4)
    poses = kin.forward(sweep[:, 0], sweep[:, 1])
    k = source.platform.intrinsics
    obj_i, view, region = pick_subject(source.scene, poses, k, 0, FramingEvalConfig(min_frac=0.005))
    now = 1.0
    frames = []
    for p in [*np.delete(poses, view, axis=0), poses[view]]:
        frames.append(source.capture(p, stamp_s=now))
        node.step({"camera/frame": [frames[-1]]}, now)
        now += 1.0
    box = FramingRegion("latest", region.x0, region.y0, region.x1, region.y1)
    out = node.step({"planner/request": [PlannerRequest("suggest", set_framing=True, keep=[box])]}, now)
    assert node.proposer.framing[2].photo_rank, "the planner's photo_rank reaches the framing it applies"
    best = out["planner/suggestion"][-1].candidates[0]
    assert true_holds(object_points(source.scene.objects[obj_i]), best.cam2world[None], k)[0]
    assert 0.0 < best.terms["photo_cover"] <= 1.0 and np.isfinite(best.terms["photo"])
    framing = node.proposer._framing(node.proposer.scorer(), node.platform)
    again, cover = warped_photo_scores(node.proposer.scorer().teacher, [f.image for f in frames],
                                       np.stack([f.cam2world for f in frames]), frames[0].intrinsics,
                                       best.cam2world[None], framing.keep[0].centre_m,
                                       framing.cfg.photo_width_px)  # fmt: skip
    assert best.terms["photo"] == pytest.approx(float(again[0]), abs=1e-5)
    assert best.terms["photo_cover"] == pytest.approx(float(cover[0]), abs=1e-9)
