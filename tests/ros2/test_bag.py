"""``export rosbag2``: a recording becomes a rosbag2 folder that rosbags reads with the stock Jazzy types."""

from __future__ import annotations

import pytest

pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")
pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")

import cv2
import numpy as np
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from aes_planner.cli import main
from aes_planner.messages import GimbalState
from aes_planner.messages.samples import sample_messages
from aes_planner.transport.record import Recorder
from tests.ros2.stock import MSG_DIR, typestore


@pytest.fixture
def recording(tmp_path):
    msgs = sample_messages()
    path = tmp_path / "run.mcap"
    with Recorder(path) as rec:
        rec.write("gimbal/state", GimbalState(0.0, 0.0, 0.3, -0.1, True, stamp_s=2.0), 2_000_000_000)
        rec.write("camera/frame", msgs["PosedFrame"], 2_500_000_000)
        rec.write("gimbal/state", GimbalState(0.2, -0.1, 0.3, -0.1, True, stamp_s=2.5), 2_600_000_000)
        rec.write("planner/suggestion", msgs["ViewSuggestion"], 3_100_000_000)
        rec.write("planner/diagnostics", msgs["Diagnostics"], 5_000_000_000)
        rec.write("planner/request", msgs["PlannerRequest"], 6_000_000_000)  # no ROS 2 mapping: skipped
    return path


def test_export_reads_back_with_stock_jazzy_types(recording, tmp_path, capsys):
    out = tmp_path / "bag"
    assert main(["export", "rosbag2", str(recording), str(out), "--scene", "indoor:3"]) == 0
    assert "wrote" in capsys.readouterr().out
    ts = typestore()  # stock Jazzy + aes_planner_msgs parsed from the shipped .msg files
    seen: dict[str, list] = {}
    with Reader(out) as reader:
        assert (out / "metadata.yaml").is_file() and "storage_identifier: mcap" in (out / "metadata.yaml").read_text()
        conns = {c.topic: c for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            seen.setdefault(conn.topic, []).append((t_ns, ts.deserialize_cdr(raw, conn.msgtype)))
    types = {t: c.msgtype for t, c in conns.items()}
    assert types["/planner/suggestion"] == "geometry_msgs/msg/PoseStamped"
    assert types["/gimbal/joint_states"] == "sensor_msgs/msg/JointState"
    assert types["/camera/image/compressed"] == "sensor_msgs/msg/CompressedImage"
    assert types["/planner/view_suggestion"] == "aes_planner_msgs/msg/ViewSuggestion"
    assert {"/tf", "/tf_static", "/camera/camera_info", "/diagnostics", "/planner/suggestions"} <= set(types)
    qos = {t: c.ext.offered_qos_profiles[0] for t, c in conns.items()}
    assert qos["/planner/suggestion"].durability.name == "TRANSIENT_LOCAL"
    assert qos["/camera/image/compressed"].reliability.name == "BEST_EFFORT"
    # logged at the messages' own stamps
    ((t_ns, ps),) = seen["/planner/suggestion"]
    assert t_ns == 3_000_000_000 and ps.header.frame_id == "map"
    js = [m for _, m in seen["/gimbal/joint_states"]]
    assert [list(m.name) for m in js] == [["pan", "tilt"]] * 2
    assert list(js[1].velocity) == pytest.approx([0.4, -0.2])
    ((_, img),) = seen["/camera/image/compressed"]
    assert cv2.imdecode(np.frombuffer(img.data.tobytes(), np.uint8), cv2.IMREAD_COLOR).shape == (6, 8, 3)
    ((_, vs),) = seen["/planner/view_suggestion"]
    assert len(vs.candidates) == 2 and list(vs.candidates[0].term_names) == ["thirds", "balance"]
    assert vs.has_covered_fraction and vs.covered_fraction == pytest.approx(0.625)
    assert len(vs.explore) == 1 and vs.explore[0].has_joints and vs.explore[0].pan == pytest.approx(2.5)


def test_the_mcap_is_a_ros2_profile_chunked_indexed_file(recording, tmp_path):
    out = tmp_path / "bag"
    assert main(["export", "rosbag2", str(recording), str(out)]) == 0
    (mcap_path,) = out.glob("*.mcap")
    with open(mcap_path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary.chunk_indexes and summary.statistics.message_count > 0
        schemas = {s.name: s for s in summary.schemas.values()}
        assert all(s.encoding == "ros2msg" for s in schemas.values())
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
        # a dependency's definition follows a line of '=' and 'MSG: pkg/Type'
        assert "MSG: geometry_msgs/Pose" in schemas["geometry_msgs/msg/PoseStamped"].data.decode()
        assert "MSG: aes_planner_msgs/ViewCandidate" in schemas["aes_planner_msgs/msg/ViewSuggestion"].data.decode()


def test_bad_paths_are_user_errors(recording, tmp_path, capsys):
    assert main(["export", "rosbag2", str(tmp_path / "missing.mcap"), str(tmp_path / "b")]) == 2
    assert "no such recording" in capsys.readouterr().err
    (tmp_path / "exists").mkdir()
    assert main(["export", "rosbag2", str(recording), str(tmp_path / "exists")]) == 2
    assert "exists" in capsys.readouterr().err


def test_the_shipped_interface_package_and_the_packaged_definitions_are_the_same_files():
    from aes_planner.ros2.bag import MSG_DIR as PACKAGED

    shipped = sorted(p.name for p in MSG_DIR.glob("*.msg"))
    assert shipped == ["ViewCandidate.msg", "ViewSuggestion.msg"]
    for name in shipped:
        assert (PACKAGED / name).read_bytes() == (MSG_DIR / name).read_bytes(), name


def test_a_demo_run_folder_gives_the_rig_for_tf_static(recording, tmp_path, capsys):
    import json

    (recording.parent / "summary.json").write_text(json.dumps({"scene": "indoor:3", "mode": "rig"}))
    out = tmp_path / "bag"
    assert main(["export", "rosbag2", str(recording), str(out)]) == 0
    assert "indoor:3" in capsys.readouterr().out
    with Reader(out) as reader:
        static = [c for c in reader.connections if c.topic == "/tf_static"]
        assert static
        ((_, _, raw),) = list(reader.messages(connections=static))
    msg = typestore().deserialize_cdr(raw, "tf2_msgs/msg/TFMessage")
    assert [(t.header.frame_id, t.child_frame_id) for t in msg.transforms] == [
        ("map", "gimbal_base"),
        ("gimbal_tilt", "camera_link"),
        ("camera_link", "camera_optical"),
    ]


def test_a_file_that_is_not_a_recording_leaves_no_folder(tmp_path, capsys):
    bad = tmp_path / "notes.mcap"
    bad.write_text("not an mcap file")
    assert main(["export", "rosbag2", str(bad), str(tmp_path / "bag")]) == 2
    assert "MCAP" in capsys.readouterr().err and not (tmp_path / "bag").exists()
