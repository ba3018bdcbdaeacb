"""Bad-input sweep: reconstruct() never returns an empty reconstruction silently."""

import copy

import numpy as np
import pytest
import torch

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
        (lambda fr: _edited(fr, depth=float(np.finfo(np.float32).max)), {}),
        (lambda fr: _edited(fr[:1], drop_depth=True), {"mode": "stereo"}),
        (lambda fr: _edited([fr[0], fr[0]], drop_depth=True), {"mode": "stereo"}),
    ],
    ids=["depth-1e30", "depth-f32-max", "stereo-one-frame", "stereo-identical-frames"],
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


def test_depth_beyond_any_sensor_is_no_measurement():
    """Depths at float32's maximum overflowed the splats' float32 means (a LinAlgError from the
    merge); beyond MAX_DEPTH_M a pixel makes no splat, and the others still do."""
    import warnings

    from aes_planner.geometry.camera import Intrinsics
    from aes_planner.geometry.poses import view_to_cam2world
    from aes_planner.messages import PosedFrame
    from aes_planner.reconstruct.reconstructor import MAX_DEPTH_M

    k = Intrinsics(30.0, 30.0, 16, 12, 32, 24)
    rng = np.random.default_rng(0)
    frames = [
        PosedFrame(
            rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
            k,
            view_to_cam2world(np.array([0.0, 0.3 * i, 1.5, 0.0, 0.0])),
            float(i),
            depth_m=np.where(rng.random((24, 32)) < 0.5, 2.0, np.finfo(np.float32).max if i else 2 * MAX_DEPTH_M),
        )
        for i in range(2)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow on the way
        rec = reconstruct(frames)
    assert len(rec.gaussians) > 0 and torch.isfinite(rec.gaussians.means).all()
