"""Fixtures of the reconstruction tests: the analytic scene (helpers: :mod:`tests.helpers`)."""

import pytest

from aes_planner.config import from_dict
from tests.helpers import ANALYTIC


@pytest.fixture(scope="session")
def analytic_scene():
    from aes_planner.sim import load_scene
    from aes_planner.sim.spec import SceneSpec

    return load_scene(from_dict(SceneSpec, ANALYTIC))
