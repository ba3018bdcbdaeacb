"""Small simulated frames for the field tests (64x48: quick to reconstruct and render)."""

import numpy as np
import pytest

from aes_planner.geometry.pantilt import PanTilt
from aes_planner.sim import SimCameraConfig, SimSource


@pytest.fixture(scope="session")
def rig_source():
    return SimSource("tabletop:5", camera=SimCameraConfig(width=64, height=48, supersample=1))


@pytest.fixture(scope="session")
def rig_frames(rig_source):
    """Three RGB frames of a pan sweep (sphere mode) and their poses ``[3, 4, 4]``."""
    pt = PanTilt(rig_source.platform.rig)
    poses = np.stack([pt.forward(p, -0.1) for p in np.radians([-20.0, 0.0, 20.0])])
    return [rig_source.capture(p, depth=False) for p in poses], poses


@pytest.fixture(scope="session")
def depth_frames(rig_source):
    """Two frames with depth (depth mode) and their poses."""
    pt = PanTilt(rig_source.platform.rig)
    poses = np.stack([pt.forward(p, -0.15) for p in np.radians([-10.0, 10.0])])
    return [rig_source.capture(p, depth=True) for p in poses], poses


@pytest.fixture(scope="module")
def checkpoint():
    """A tiny field model's checkpoint (a dict, as the trainer writes it)."""
    from aes_planner.field.model import FieldModel, FieldModelConfig

    model = FieldModel(FieldModelConfig(hidden=4, encoder_channels=4), 4, (16, 16), "composition")
    return model.checkpoint({"step": 1})
