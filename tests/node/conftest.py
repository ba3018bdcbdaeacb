"""Fixtures of the node tests."""

import pytest

from aes_planner.geometry.pantilt import PanTilt

from .nodekit import RIG


@pytest.fixture
def rig():
    return PanTilt(RIG)
