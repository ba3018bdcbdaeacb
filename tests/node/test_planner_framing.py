"""The planner applies a PlannerRequest's keep/avoid regions to its next searches, says which are
active in its diagnostics, and refuses (counts, keeps the old framing) regions it cannot use."""

from __future__ import annotations

import numpy as np

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
