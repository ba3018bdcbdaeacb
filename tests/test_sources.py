import numpy as np
import pytest
import torch

from aes_planner.config import ConfigError
from aes_planner.field import ScorerError, check_poses
from aes_planner.platform import DroneBox, DronePlatform, RigPlatform, parse_kind
from aes_planner.sim import SimSource


def test_sim_source_rig_renders_ground_truth_at_any_pose():
    src = SimSource("indoor:1")
    assert src.platform.kind == "rig" and src.platform.rig is not None
    kin = src.scene.rig.kinematics()
    poses = np.stack([kin.forward(0.0, 0.0), kin.forward(0.4, -0.1)])
    rgb = src.render_rgb(poses)
    k = src.platform.intrinsics
    assert rgb.shape == (2, k.height, k.width, 3) and rgb.dtype == np.float32
    assert 0.0 <= rgb.min() and rgb.max() <= 1.0 and not np.allclose(rgb[0], rgb[1])
    frame = src.capture(poses[1], depth=False)
    assert frame.depth_m is None and np.allclose(frame.image / 255.0, rgb[1], atol=1 / 255 + 1e-6)


def test_drone_box_and_platform_validate():
    box = DroneBox((0, 0, 0), (1, 2, 3))
    assert box.contains([[0.5, 1, 1], [2, 0, 0]]).tolist() == [True, False]
    assert np.allclose(box.clamp([5, -1, 1]), [1, 0, 1])
    with pytest.raises(ConfigError):
        DroneBox((0, 0, 0), (1, 0, 1))
    src = SimSource("indoor:1")
    with pytest.raises(ConfigError):
        DronePlatform(src.platform.intrinsics, src.platform.rig)  # a rig is not a drone's box
    with pytest.raises(ConfigError):
        RigPlatform(src.platform.intrinsics, None)
    assert [parse_kind(w) for w in ("rig", "drone", "free")] == ["rig", "drone", "drone"]
    with pytest.raises(ConfigError, match="kind"):
        parse_kind("boat")


def test_check_poses_refuses_bad_batches():
    with pytest.raises(ScorerError, match="empty"):
        check_poses(torch.zeros(0, 4, 4), "t")
    with pytest.raises(ScorerError, match="NaN"):
        check_poses(torch.full((1, 4, 4), float("nan")), "t")
    with pytest.raises(ScorerError, match=r"\[B, 4, 4\]"):
        check_poses(torch.eye(4), "t")
    assert check_poses(torch.eye(4)[None].float(), "t").dtype == torch.float64


def test_rig_metadata_round_trips_every_field():
    """``sim render`` writes the rig into cameras.json and ``suggest`` reads it back: every
    PanTiltConfig field survives JSON, the scalar camera_roll_deg included."""
    import json

    from aes_planner.geometry import Intrinsics, PanTiltConfig
    from aes_planner.platform import platform_from_meta, platform_to_meta
    from aes_planner.search.oracle import _platform_dict

    k = Intrinsics.from_fov(64, 48, 60.0)
    rig = PanTiltConfig(base_xyz_m=(0.0, 0.0, 2.6), base_rpy_deg=(180.0, 0.0, 0.0), camera_roll_deg=180.0)
    meta = json.loads(json.dumps(platform_to_meta(RigPlatform(k, rig))))
    assert meta["rig"]["camera_roll_deg"] == 180.0
    assert platform_from_meta(meta, k).rig == rig
    # the oracle cache key names the roll only when it is set (older rigs keep their keys)
    assert _platform_dict(RigPlatform(k, rig))["rig"]["camera_roll_deg"] == 180.0
    assert "camera_roll_deg" not in _platform_dict(RigPlatform(k, PanTiltConfig()))["rig"]


def test_box_around_a_centre():
    box = DroneBox.around((1.0, -2.0, 0.5), (0.8, 0.8, 0.3))
    assert box.bounds_min_m == pytest.approx((0.2, -2.8, 0.3))  # the floor raised from 0.2 to 0.3
    assert box.bounds_max_m == pytest.approx((1.8, -1.2, 0.8))
    assert all(type(v) is float for v in box.bounds_min_m + box.bounds_max_m)
    assert DroneBox.around((0.0, 0.0, 2.0), 1.0).bounds_min_m == pytest.approx((-1.0, -1.0, 1.0))
    for bad in ((-1.0, 1.0, 1.0), (1.0, 0.0, 1.0), (float("nan"), 1.0, 1.0)):
        with pytest.raises(ConfigError, match=r"half_m: must be > 0 in every axis"):
            DroneBox.around((0.0, 0.0, 2.0), bad)
