"""The bridge's outbound topics as a stock ROS 2 Jazzy subscriber sees them over DDS.

The subscriber's types come from rosbags' Jazzy typestore (tests/ros2/stock.py); every sample is
decoded from its CDR bytes by rosbags' deserialiser, never by the bridge's own type code.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.messages.samples import sample_messages
from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
from aes_planner.ros2.dds import DdsConfig
from tests.helpers import wait_for
from tests.ros2.stock import Peer, domain_for_tests, typestore

RIG = PanTiltConfig(base_xyz_m=(0.5, -0.2, 1.2), tilt_offset_m=(0.0, 0.0, 0.05), lever_arm_m=(0.03, 0.0, 0.02))


@pytest.fixture
def bridge():
    cfg = Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), rig=RIG)
    node = Ros2BridgeNode(cfg)
    node.start()
    yield node
    node.stop()


@pytest.fixture
def peer():
    p = Peer(domain_for_tests())
    yield p
    p.close()


def _collect(peer, reader, name, n=1, push=None, timeout_s=10.0):
    """Decode samples from ``reader`` with rosbags until ``n`` arrived (``push()`` publishes again)."""
    got = []

    def enough():
        if push is not None:
            push()
        got.extend(typestore().deserialize_cdr(b, name) for b in Peer.take_raw(reader))
        return len(got) >= n

    assert wait_for(enough, timeout_s, 0.05), f"no {name} arrived"
    return got


def _stamp(t) -> float:
    return t.sec + t.nanosec * 1e-9


def test_suggestion_topics_carry_the_best_pose_the_ranked_list_and_everything_else(bridge, peer):
    msg = sample_messages()["ViewSuggestion"]
    bridge.step({"planner/suggestion": [msg]}, now=10.0)
    # latched: readers that join after the publication still get it
    ps = _collect(
        peer,
        peer.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched"),
        "geometry_msgs/msg/PoseStamped",
    )[0]
    pa = _collect(
        peer,
        peer.reader("/planner/suggestions", "geometry_msgs/msg/PoseArray", "latched"),
        "geometry_msgs/msg/PoseArray",
    )[0]
    vs = _collect(
        peer,
        peer.reader("/planner/view_suggestion", "aes_planner_msgs/msg/ViewSuggestion", "latched"),
        "aes_planner_msgs/msg/ViewSuggestion",
    )[0]
    assert ps.header.frame_id == "map" and _stamp(ps.header.stamp) == pytest.approx(msg.stamp_s)
    best = msg.candidates[0].cam2world
    q = ps.pose.orientation
    assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, abs_tol=1e-9)
    R = _rotation(q)
    assert np.allclose(R, best[:3, :3], atol=1e-9)
    assert np.allclose([ps.pose.position.x, ps.pose.position.y, ps.pose.position.z], best[:3, 3])
    assert len(pa.poses) == 2 and pa.header.frame_id == "map"
    assert np.allclose(_rotation(pa.poses[1].orientation), msg.candidates[1].cam2world[:3, :3], atol=1e-9)
    assert (vs.sequence_number, vs.field_version, vs.mode, vs.kind) == (2, 4, 0, 0)
    c0, c1 = vs.candidates
    assert (c0.rank, c1.rank) == (0, 1)
    assert c0.score == pytest.approx(0.8) and c0.coverage == pytest.approx(0.95)
    assert c0.has_joints and (c0.pan, c0.tilt) == pytest.approx((0.3, -0.1)) and not c1.has_joints
    assert dict(zip(c0.term_names, c0.term_values)) == pytest.approx({"thirds": 0.4, "balance": -0.1})
    assert (c0.yaw, c0.pitch) == pytest.approx(tuple(msg.candidates[0].view[3:]))
    # schema 3's coverage and exploratory candidate: a flag beside the value, a sequence of at most one
    assert vs.has_covered_fraction and vs.covered_fraction == pytest.approx(0.625)
    (ex,) = vs.explore
    assert (ex.rank, ex.score, ex.coverage) == pytest.approx((0, 0.3, 0.2))
    assert ex.has_joints and (ex.pan, ex.tilt) == pytest.approx((2.5, 0.1))
    assert _rotation(ex.pose.orientation) == pytest.approx(msg.explore.cam2world[:3, :3], abs=1e-9)


def _rotation(q) -> np.ndarray:
    from transforms3d.quaternions import quat2mat

    return quat2mat([q.w, q.x, q.y, q.z])


def test_late_transient_local_subscriber_gets_the_last_suggestion_only(bridge, peer):
    msgs = sample_messages()
    first = msgs["ViewSuggestion"]
    bridge.step({"planner/suggestion": [first]}, now=1.0)
    second = type(first)(7.5, first.candidates[1:], 5, 3, "world", "free")
    bridge.step({"planner/suggestion": [second]}, now=2.0)
    reader = peer.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched")
    got = _collect(peer, reader, "geometry_msgs/msg/PoseStamped")
    assert len(got) == 1 and _stamp(got[0].header.stamp) == pytest.approx(7.5)
    # a volatile reader joining late gets nothing: the latching is the writer's durability
    volatile = peer.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "reliable")
    assert not wait_for(lambda: Peer.take_raw(volatile), 0.5)


def test_frames_become_jpeg_camera_info_and_tf_at_the_capture_stamp(bridge, peer):
    frame = sample_messages()["PosedFrame"]
    img = peer.reader("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", "sensor_data")
    info = peer.reader("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data")
    tf = peer.reader("/tf", "tf2_msgs/msg/TFMessage", "reliable")
    push = lambda: bridge.step({"camera/frame": [frame]}, now=99.0)  # noqa: E731 (best effort: resend until seen)
    im = _collect(peer, img, "sensor_msgs/msg/CompressedImage", push=push)[0]
    ci = _collect(peer, info, "sensor_msgs/msg/CameraInfo", push=push)[0]
    tfs = _collect(peer, tf, "tf2_msgs/msg/TFMessage", push=push)[0]
    assert im.format == "jpeg" and _stamp(im.header.stamp) == pytest.approx(2.5)
    assert im.header.frame_id == "camera_optical"
    decoded = cv2.imdecode(np.frombuffer(im.data.tobytes(), np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (6, 8, 3)
    k = frame.intrinsics
    assert ci.distortion_model == "plumb_bob" and (ci.width, ci.height) == (8, 6)
    assert list(ci.k) == pytest.approx([k.fx, 0, k.cx - 0.5, 0, k.fy, k.cy - 0.5, 0, 0, 1])
    assert list(ci.p) == pytest.approx([k.fx, 0, k.cx - 0.5, 0, 0, k.fy, k.cy - 0.5, 0, 0, 0, 1, 0])
    assert list(ci.r) == pytest.approx(np.eye(3).ravel().tolist()) and len(ci.d) == 5
    # rig known: the joints at the frame's stamp; composed with /tf_static they give the frame's pose
    names = [(t.header.frame_id, t.child_frame_id) for t in tfs.transforms]
    assert names == [("gimbal_base", "gimbal_pan"), ("gimbal_pan", "gimbal_tilt")]
    assert all(_stamp(t.header.stamp) == pytest.approx(2.5) for t in tfs.transforms)
    static = peer.reader("/tf_static", "tf2_msgs/msg/TFMessage", "latched")
    st = _collect(peer, static, "tf2_msgs/msg/TFMessage")[0]
    chain = {t.child_frame_id: t for t in [*st.transforms, *tfs.transforms]}
    pose = np.eye(4)
    child = "camera_optical"
    while child in chain:
        t = chain[child]
        m = np.eye(4)
        m[:3, :3] = _rotation(t.transform.rotation)
        m[:3, 3] = [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
        pose = m @ pose
        child = t.header.frame_id
    assert child == "map"
    from aes_planner.geometry.pantilt import PanTilt

    assert np.allclose(pose, PanTilt(RIG).forward(0.3, -0.1), atol=1e-9)


def test_without_a_rig_tf_is_world_to_the_optical_frame(peer):
    frame = sample_messages()["PosedFrame"]
    node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), world_frame="odom"))
    node.start()
    try:
        tf = peer.reader("/tf", "tf2_msgs/msg/TFMessage", "reliable")
        got = _collect(peer, tf, "tf2_msgs/msg/TFMessage", push=lambda: node.step({"camera/frame": [frame]}, 1.0))[0]
    finally:
        node.stop()
    (t,) = got.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "camera_optical")
    assert np.allclose(_rotation(t.transform.rotation), frame.cam2world[:3, :3], atol=1e-9)


def test_joint_states_and_diagnostics(bridge, peer):
    msgs = sample_messages()
    js = peer.reader("/gimbal/joint_states", "sensor_msgs/msg/JointState", "reliable")
    diag = peer.reader("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "reliable")
    s0 = msgs["GimbalState"]
    s1 = type(s0)(0.3, 0.1, 0.3, 0.4, True, stamp_s=4.5)
    state = iter([s0, s1])

    def push():
        nxt = next(state, None)
        bridge.step({"gimbal/state": [nxt] if nxt else [], "planner/diagnostics": [msgs["Diagnostics"]]}, now=50.0)

    got = _collect(peer, js, "sensor_msgs/msg/JointState", n=2, push=push)
    assert list(got[1].name) == ["pan", "tilt"]
    assert list(got[1].position) == pytest.approx([0.3, 0.1])
    assert list(got[1].velocity) == pytest.approx([(0.3 - 0.1) / 0.5, (0.1 - 0.2) / 0.5])
    assert _stamp(got[1].header.stamp) == pytest.approx(4.5)
    arrays = _collect(peer, diag, "diagnostic_msgs/msg/DiagnosticArray", n=1, push=push)
    planner = [s for a in arrays for s in a.status if s.name == "aes_planner: planner"]
    assert planner and planner[0].message == "exploring" and planner[0].level == 0
    assert {kv.key: kv.value for kv in planner[0].values}["frames_in"] == "10"
    diag_values = bridge.diagnostics(60.0).values
    assert diag_values["subscribers.joint_states"] == 1.0 and diag_values["subscribers.image"] == 0.0


_LISTENER = r"""
import sys, time
sys.path.insert(0, sys.argv[2])
from tests.ros2.stock import Peer, typestore
p = Peer(int(sys.argv[1]))
r = p.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched")
end = time.time() + 30
while time.time() < end:
    raw = Peer.take_raw(r)
    if raw:
        m = typestore().deserialize_cdr(raw[-1], "geometry_msgs/msg/PoseStamped")
        q = m.pose.orientation
        print(m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec, q.x, q.y, q.z, q.w, flush=True)
        break
    time.sleep(0.02)
"""


def test_a_subscriber_process_on_a_loopback_unicast_config_gets_the_latched_suggestion(bridge, tmp_path):
    """Over RTPS on loopback between processes (not Cyclone's in-process delivery), with the
    subscriber's CYCLONEDDS_URI a loopback-only unicast configuration, as a ROS 2 user would set it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    cfg = tmp_path / "cyclone.xml"
    cfg.write_text(
        '<CycloneDDS><Domain><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
        "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
        '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
    )
    msg = sample_messages()["ViewSuggestion"]
    bridge.step({"planner/suggestion": [msg]}, now=1.0)  # published before the subscriber exists
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "CYCLONEDDS_URI": cfg.as_uri()}
    out = subprocess.run(
        [sys.executable, "-c", _LISTENER, str(domain_for_tests()), root],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    fields = out.stdout.split()
    assert fields, out.stderr[-2000:]
    assert fields[0] == "map" and int(fields[1]) + int(fields[2]) * 1e-9 == pytest.approx(msg.stamp_s)
    q = np.array([float(v) for v in fields[3:7]])
    assert np.linalg.norm(q) == pytest.approx(1.0)


def test_localhost_range_meets_a_ros2_node_run_with_localhost_discovery(tmp_path):
    """discovery_range localhost is rmw_cyclonedds's own LOCALHOST configuration: a subscriber
    process configured as a ROS 2 node with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (default
    interface, unicast to localhost) receives from it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from aes_planner.ros2.dds import cyclone_config

    domain = domain_for_tests() + 1  # a domain this process has not configured yet
    node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain, discovery_range="localhost")))
    node.start()
    try:
        msg = sample_messages()["ViewSuggestion"]
        node.step({"planner/suggestion": [msg]}, now=1.0)
        env = {**os.environ, "CYCLONEDDS_URI": cyclone_config("localhost", (), False, None)}
        root = str(Path(__file__).resolve().parents[2])
        out = subprocess.run(
            [sys.executable, "-c", _LISTENER, str(domain), root], capture_output=True, text=True, timeout=60, env=env
        )
    finally:
        node.stop()
    assert out.stdout.split()[:1] == ["map"], out.stderr[-2000:]


def test_a_drones_waypoint_is_told_apart_and_kept_off_the_suggestion_topics(bridge, peer):
    msgs = sample_messages()
    search = msgs["ViewSuggestion"]
    waypoint = type(search)(9.0, search.candidates[:1], 4, 3, "world", "free", kind="waypoint")
    bridge.step({"planner/suggestion": [search]}, now=1.0)
    bridge.step({"planner/suggestion": [waypoint]}, now=2.0)
    ps = _collect(
        peer,
        peer.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched"),
        "geometry_msgs/msg/PoseStamped",
    )
    assert _stamp(ps[-1].header.stamp) == pytest.approx(search.stamp_s)  # still the search result
    vs = _collect(
        peer,
        peer.reader("/planner/view_suggestion", "aes_planner_msgs/msg/ViewSuggestion", "latched"),
        "aes_planner_msgs/msg/ViewSuggestion",
    )
    assert (vs[-1].kind, vs[-1].mode, vs[-1].sequence_number) == (1, 1, 3)
    assert not vs[-1].has_covered_fraction and vs[-1].covered_fraction == 0.0 and list(vs[-1].explore) == []


def test_images_are_best_effort_and_volatile(bridge, peer):
    """A reliable reader does not match the image writer (sensor-data QoS is best effort), and a
    best-effort reader that joins after a frame does not get it (volatile)."""
    frame = sample_messages()["PosedFrame"]
    bridge.step({"camera/frame": [frame]}, now=1.0)
    late = peer.reader("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", "sensor_data")
    reliable = peer.reader("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", "reliable")
    assert not wait_for(lambda: Peer.take_raw(late), 0.5)
    got = _collect(
        peer, late, "sensor_msgs/msg/CompressedImage", push=lambda: bridge.step({"camera/frame": [frame]}, 2.0)
    )
    assert got and not Peer.take_raw(reliable)
    assert not reliable.get_matched_publications()


def test_the_bridge_announces_itself_on_the_ros2_graph(peer):
    """With ros_graph set, ros_discovery_info (rmw_dds_common, stock Jazzy type) names the bridge's
    node and lists the GIDs of its writers, which are the DDS GUIDs a ROS 2 graph cache sees."""
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from tests.ros2.stock import idl_class, qos

    node = Ros2BridgeNode(
        Ros2BridgeConfig(
            dds=DdsConfig(domain_id=domain_for_tests()),
            outbound=("suggestion",),
            ros_graph="jazzy",
            ros_node_name="aes",
        )
    )
    node.start()
    try:
        name = "rmw_dds_common/msg/ParticipantEntitiesInfo"
        reader = DataReader(
            peer.participant, Topic(peer.participant, "ros_discovery_info", idl_class(name)), qos("latched")
        )
        infos = _collect(peer, reader, name)
        pubs = BuiltinDataReader(peer.participant, BuiltinTopicDcpsPublication)
        seen = []
        assert wait_for(
            lambda: seen.extend(pubs.take(64)) or any(p.topic_name == "rt/planner/suggestion" for p in seen)
        )
    finally:
        node.stop()
    (node_info,) = infos[-1].node_entities_info_seq
    assert (node_info.node_namespace, node_info.node_name) == ("/", "aes")
    writer_gids = {bytes(g.data) for g in node_info.writer_gid_seq}
    suggestion = next(p for p in seen if p.topic_name == "rt/planner/suggestion")
    assert suggestion.key.bytes in writer_gids
    assert suggestion.participant_key.bytes == bytes(infos[-1].gid.data)


def test_the_bus_counters_reach_dds_diagnostics(bridge, peer):
    """A ROS 2 user watching /diagnostics sees what the bus under the bridge counts: its inputs'
    received/dropped and the session's health (a lost session shows there, not only on the graph)."""
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.transport.inprocess import InProcessBus

    bus = InProcessBus()
    bus.health = lambda: {"session_ok": 0, "session_losses": 2, "last_outage_ms": 5100}
    runner = NodeRunner(bridge, bus)
    runner.open()
    try:
        bus.publisher("planner/suggestion", type(sample_messages()["ViewSuggestion"]), latched=True).publish(
            sample_messages()["ViewSuggestion"]
        )
        assert wait_for(lambda: runner.subs["planner/suggestion"].received == 1)
        diag = peer.reader("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "reliable")
        now = iter(range(100, 10**6, 2))
        arrays = _collect(
            peer, diag, "diagnostic_msgs/msg/DiagnosticArray", push=lambda: bridge.step({}, float(next(now)))
        )
        ours = [s for a in arrays for s in a.status if s.name == f"aes_planner: {bridge.node_id}"]
        values = {kv.key: kv.value for kv in ours[0].values}
        assert values["bus.session_ok"] == "0" and values["bus.session_losses"] == "2"
        assert values["planner/suggestion.received"] == "1" and values["step_errors"] == "0"
    finally:
        runner.close()
