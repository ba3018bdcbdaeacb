"""`aes-planner train`'s hard-example search: a preset's search over the starting field, its
stage-1 candidates ranked by the objective the search ranks them by."""

import numpy as np
import pytest

from aes_planner.cli.train import SearchProposer
from aes_planner.field.protocol import plan_views
from aes_planner.sim import SimCameraConfig, SimSource


@pytest.mark.slow  # two searches: ~2 s idle, 8 s beside busy helpers
def test_search_proposer_returns_the_candidates_with_the_searchs_objective(tmp_path):
    source = SimSource("tabletop:51000", camera=SimCameraConfig(width=32, height=24, supersample=1))
    plan = plan_views(source.platform, "sweep", 3, 1, np.random.default_rng(0))
    frames = [source.capture(p, depth=False) for p in plan.inputs]
    propose = SearchProposer("fast")
    cands, objective, sugg = propose(frames, plan.inputs, source.platform, 7)
    assert cands.ndim == 3 and cands.shape[1:] == (4, 4) and objective.shape == (len(cands),)
    assert np.isfinite(objective).all() and len(sugg) >= 1 and np.isfinite(sugg).all()
    again = propose(frames, plan.inputs, source.platform, 7)  # seeded: the same views
    assert np.array_equal(again[0], cands) and np.array_equal(again[1], objective)
    # the tag names the field searched over: another checkpoint file, another tag
    other = tmp_path / "other.npz"
    other.write_bytes(b"not the shipped field")
    assert len(propose.tag()) == 8 and SearchProposer("fast", str(other)).tag() != propose.tag()
    assert SearchProposer("fast", "default").tag() == propose.tag()
