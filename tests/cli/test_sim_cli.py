"""``aes-planner sim render`` writes dataset folders that load back with the same poses (the demo is
tested in tests/node)."""

import numpy as np

from aes_planner.cli import main
from aes_planner.dataset import load_dataset
from aes_planner.sim import load_scene


def test_sim_render_round_trip(tmp_path, capsys):
    out = tmp_path / "renders" / "indoor3"
    assert main(["sim", "render", "--scene", "indoor:3", "--views", "4", "--out", str(out), "--supersample", "1"]) == 0
    assert "wrote 4 views" in capsys.readouterr().out
    ds = load_dataset(out)
    rig = load_scene("indoor:3").rig
    expected = rig.kinematics().sweep(4)
    assert len(ds) == 4 and ds.meta["scene"] == "indoor:3"
    for f, (pan, tilt) in zip(ds.frames, expected):
        np.testing.assert_array_equal(f.cam2world, rig.kinematics().forward(pan, tilt))
        assert f.extras["meta"]["joints_rad"] == [pan, tilt]
        assert f.depth_m is not None and (f.depth_m > 0).any()
        assert f.intrinsics == rig.intrinsics()


def test_sim_render_errors_are_one_line(tmp_path, capsys):
    assert main(["sim", "render", "--scene", "nowhere:1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "nowhere" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("objects:\n  - type: sphere\n    centre_m: [0, 0, 1]\n    radius_m: 1\n    colour: red\n")
    assert main(["sim", "render", "--scene", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "objects[0].colour" in capsys.readouterr().err
