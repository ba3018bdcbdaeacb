"""Bad-input sweep (issue 13): reconstruct() never returns an empty reconstruction silently."""

import copy

import numpy as np
import pytest

from aes_planner.reconstruct import ReconstructConfig, ReconstructError, reconstruct


@pytest.fixture(scope="module")
def frames():
    from aes_planner.sim import SimCamera, SimCameraConfig, load_scene

    cam = SimCamera(load_scene("indoor:3"), SimCameraConfig(width=32, height=24))
    return [cam.capture_joints(pan, 0.0) for pan in (0.0, 0.3)]


def _edited(frames, depth=None, drop_depth=False):
    out = copy.deepcopy(frames)
    for f in out:
        if drop_depth:
            f.depth_m = None
        elif depth is not None:
            f.depth_m = np.full_like(f.depth_m, depth)
    return out


@pytest.mark.parametrize(
    "make, kwargs",
    [
        (lambda fr: _edited(fr, depth=1e30), {}),
        (lambda fr: _edited(fr[:1], drop_depth=True), {"mode": "stereo"}),
        (lambda fr: _edited([fr[0], fr[0]], drop_depth=True), {"mode": "stereo"}),
    ],
    ids=["depth-1e30", "stereo-one-frame", "stereo-identical-frames"],
)
def test_nothing_reconstructed_is_an_error(frames, make, kwargs, clean_error):
    err = clean_error(reconstruct, make(frames), ReconstructConfig(**kwargs), match="made no Gaussians")
    assert isinstance(err, ReconstructError)


def test_bad_batches(frames, clean_error):
    clean_error(reconstruct, [], match="at least one")
    clean_error(reconstruct, [frames[0], "frame"], match="not a PosedFrame")
    assert len(reconstruct(frames).gaussians.means) > 0  # and the good batch still works


def test_featureless_stereo_frames_are_told_apart_from_bad_depth():
    """Blank RGB frames with parallax: stereo matches nothing; the error said to check depth maps
    the frames never had."""
    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.geometry.poses import view_to_cam2world
    from aes_planner.messages import PosedFrame

    k = Intrinsics(30.0, 30.0, 16, 12, 32, 24)
    blank = np.full((24, 32, 3), 128, np.uint8)
    frames = [
        PosedFrame(blank, k, view_to_cam2world(np.array([0.0, 0.3 * i, 1.5, 0.0, 0.0])), float(i)) for i in range(4)
    ]
    with pytest.raises(ReconstructError, match="stereo matched no pixel between the frames"):
        reconstruct(frames, ReconstructConfig(mode="stereo"))
