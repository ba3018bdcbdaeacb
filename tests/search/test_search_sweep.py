"""Bad-input sweep of the search API (issue 13): inputs and platforms that are not what the
search needs are a SearchError naming them, never an AttributeError or a silent result."""

import numpy as np
import pytest

from aes_planner.search import SearchConfig, SearchError, search_views
from tests.search.test_search import AimScorer, rig_inputs, rig_platform


def scaled(p):
    p = p.copy()
    p[:, :3, :3] *= 2.0
    return p


def mirrored(p):
    p = p.copy()
    p[:, :, 0] *= -1.0
    return p


def sheared(p):
    p = p.copy()
    p[:, 0, 1] += 0.3
    return p


def bad_last_row(p):
    p = p.copy()
    p[:, 3, 0] = 1.0
    return p


def huge(p):
    p = p.copy()
    p[:, :3, 3] = 1e300
    return p


@pytest.mark.parametrize("make", [scaled, mirrored, sheared, bad_last_row, huge])
def test_search_refuses_non_rigid_inputs(make, clean_error):
    platform = rig_platform()
    inputs = rig_inputs(platform)
    cfg = SearchConfig.preset("fast", steps=0)
    clean_error(
        search_views, AimScorer(np.array([1.0, 0.0, 0.0])), make(inputs), platform, cfg, match="inputs_cam2world"
    )


@pytest.mark.parametrize("platform", [None, "rig", {"kind": "rig"}])
def test_search_refuses_what_is_not_a_platform(platform):
    inputs = rig_inputs(rig_platform())
    with pytest.raises(SearchError, match="platform"):
        search_views(AimScorer(np.array([1.0, 0.0, 0.0])), inputs, platform, SearchConfig.preset("fast", steps=0))
