"""Inbound: a ROS 2 camera and ros2_control gimbal (a fake rig in the test, typed from the stock Jazzy
definitions and fed by the simulator's renderer) drive the planner's closed loop through the bridge;
bad input arriving over DDS is rejected, counted and never crashes the bridge."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.graph.runner import Launch
from aes_planner.node.planner import PlannerConfig, PlannerNode
from aes_planner.platform import RigPlatformConfig
from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
from aes_planner.ros2.dds import DdsConfig
from aes_planner.sim import load_scene
from aes_planner.sim.raycast import render
from tests.helpers import wait_for
from tests.node.nodekit import FakeTeacher, ScriptedProposer
from tests.ros2.stock import Peer, domain_for_tests, make, typestore

K = Intrinsics.from_fov(32, 24, 60.0)


def _header(t_s: float, frame_id: str = "camera_optical") -> dict:
    sec = math.floor(t_s)
    return {"stamp": {"sec": sec, "nanosec": int((t_s - sec) * 1e9)}, "frame_id": frame_id}


def _camera_info(k=K, d=(0.0,) * 5, width=None):
    return make(
        "sensor_msgs/msg/CameraInfo",
        header=_header(0.0),
        height=k.height,
        width=width or k.width,
        distortion_model="plumb_bob",
        d=list(d),
        k=[k.fx, 0, k.cx - 0.5, 0, k.fy, k.cy - 0.5, 0, 0, 1],
        r=[1.0, 0, 0, 0, 1, 0, 0, 0, 1],
        p=[k.fx, 0, k.cx - 0.5, 0, 0, k.fy, k.cy - 0.5, 0, 0, 0, 1, 0],
        binning_x=0,
        binning_y=0,
        roi={"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    )


def _joint_state(t_s, names=("pan", "tilt"), pos=(0.0, 0.0), vel=None):
    return make(
        "sensor_msgs/msg/JointState",
        header=_header(t_s, ""),
        name=list(names),
        position=list(pos),
        velocity=list(vel) if vel is not None else [],
        effort=[],
    )


def _image(t_s, rgb, encoding="rgb8", step=None, width=None):
    h, w = rgb.shape[:2]
    data = rgb.tobytes() if encoding != "mono8" else rgb[..., 0].tobytes()
    ch = 1 if encoding == "mono8" else 3
    return make(
        "sensor_msgs/msg/Image",
        header=_header(t_s),
        height=h,
        width=width or w,
        encoding=encoding,
        is_bigendian=0,
        step=step or w * ch,
        data=list(data),
    )


class FakeRosRig:
    """usb_cam + ros2_control as a ROS 2 graph would show them: camera_info, image_raw,
    joint_states out; joint_trajectory_controller's topic in (moves take effect at once)."""

    def __init__(self, peer: Peer, scene):
        self.scene = scene
        self.kin = PanTilt(scene.rig.pan_tilt)
        self.pan = self.tilt = 0.0
        self.info = peer.writer("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data")
        self.image = peer.writer("/camera/image_raw", "sensor_msgs/msg/Image", "sensor_data")
        self.joints = peer.writer("/joint_states", "sensor_msgs/msg/JointState", "reliable")
        self.cmds = peer.reader("/joint_trajectory_controller/joint_trajectory", "trajectory_msgs/msg/JointTrajectory")
        self.commands = []

    def tick(self, t_s: float) -> None:
        for raw in Peer.take_raw(self.cmds):
            cmd = typestore().deserialize_cdr(raw, "trajectory_msgs/msg/JointTrajectory")
            self.commands.append(cmd)
            i, j = list(cmd.joint_names).index("pan"), list(cmd.joint_names).index("tilt")
            self.pan, self.tilt = float(cmd.points[-1].positions[i]), float(cmd.points[-1].positions[j])
        self.info.write(_camera_info())
        self.joints.write(_joint_state(t_s, pos=(self.pan, self.tilt), vel=(0.0, 0.0)))
        rgb = render(self.scene, self.kin.forward(self.pan, self.tilt), K).rgb
        self.image.write(_image(t_s, rgb))


@pytest.fixture
def peer():
    p = Peer(domain_for_tests())
    yield p
    p.close()


def test_a_ros2_rig_drives_the_closed_loop(peer):
    scene = load_scene("tabletop:1")
    rig = scene.rig.pan_tilt
    bridge = Ros2BridgeNode(
        Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), inbound=True, rig=rig, outbound=("suggestion",))
    )
    proposer = ScriptedProposer(rig, peak=(0.5, 0.1))
    planner = PlannerNode(
        PlannerConfig(platform=RigPlatformConfig(rig), settle_s=0.0, explore_views=3, max_moves=2, move_timeout_s=10.0),
        proposer=proposer,
        teacher=FakeTeacher(),
    )
    fake = FakeRosRig(peer, scene)
    suggestion = peer.reader("/planner/suggestion", "geometry_msgs/msg/PoseStamped", "latched")
    with Launch([(bridge, {}), (planner, {})]):
        t0 = time.time()

        def loop_done():
            fake.tick(time.time())
            return planner.finished

        assert wait_for(loop_done, 120.0, 0.05), f"planner state {planner.state}, bridge {bridge.counters}"
        elapsed = time.time() - t0
    assert planner.state == "done", planner.state
    assert fake.commands, "no JointTrajectory reached the rig"
    kin = PanTilt(rig)
    for cmd in fake.commands:
        pan, tilt = cmd.points[0].positions
        assert kin.within_limits(pan, tilt, 1e-9) and math.isfinite(pan) and math.isfinite(tilt)
        assert list(cmd.joint_names) == ["pan", "tilt"]
    # frames reached the planner posed by the kinematics at the joint angles of the ROS 2 rig
    assert proposer.frames and all(f.pan_rad is not None for f in proposer.frames)
    f = proposer.frames[-1]
    assert np.allclose(f.cam2world, kin.forward(f.pan_rad, f.tilt_rad))
    assert bridge.counters.get("sent.trajectory_out", 0) == len(fake.commands)
    assert not any(k.startswith("rejected.") for k in bridge.counters), bridge.counters
    assert Peer.take_raw(suggestion), "the planner's suggestion did not come back out over DDS"
    assert elapsed < 120


def test_bad_input_over_dds_is_rejected_and_counted(peer):
    rig = load_scene("tabletop:1").rig.pan_tilt
    node = Ros2BridgeNode(
        Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), inbound=True, rig=rig, outbound=())
    )
    node.start()
    try:
        info = peer.writer("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data")
        img = peer.writer("/camera/image_raw", "sensor_msgs/msg/Image", "sensor_data")
        js = peer.writer("/joint_states", "sensor_msgs/msg/JointState", "reliable")
        out: dict = {}

        def step():
            res = node.step({}, time.time())
            for k, v in res.items():
                out.setdefault(k, []).extend(v)

        good = np.full((K.height, K.width, 3), 100, np.uint8)
        bad = [
            (js, _joint_state(1.0, pos=(0.1,))),  # 2 names, 1 position
            (js, _joint_state(1.0, pos=(math.nan, 0.0))),  # NaN
            (js, _joint_state(1.0, names=("pan",), pos=(0.1,))),  # tilt missing
            (info, _camera_info(d=(math.inf, 0, 0, 0, 0))),
            (img, _image(1.0, good, step=K.width * 3 + 7)),  # data != step x height
            (img, _image(1.0, good, encoding="yuv422")),  # unknown encoding
            (img, _image(1.0, good, width=K.width + 1)),  # width x 3 > step
        ]
        expect = {"rejected.joint_states_in": 3, "rejected.camera_info_in": 1, "rejected.image_in": 3}

        def all_counted():
            for w, m in bad:
                w.write(m)
            step()
            return all(node.counters.get(k, 0) >= n for k, n in expect.items())

        assert wait_for(all_counted, 20.0, 0.05), node.counters
        assert not out.get("camera/frame") and not out.get("gimbal/state")
        # the bridge keeps running and takes good input afterwards
        before = dict(node.counters)

        def good_frame():
            info.write(_camera_info())
            js.write(_joint_state(time.time(), pos=(0.2, -0.1)))
            img.write(_image(time.time(), good, encoding="bgr8"))
            step()
            return bool(out.get("camera/frame"))

        assert wait_for(good_frame, 20.0, 0.05), node.counters
        frame = out["camera/frame"][-1]
        assert frame.image.shape == (K.height, K.width, 3) and (frame.pan_rad, frame.tilt_rad) == pytest.approx(
            (0.2, -0.1)
        )
        assert out["gimbal/state"][-1].pan_rad == pytest.approx(0.2)
        assert all(node.counters.get(k, 0) == before.get(k, 0) for k in expect), "good input was rejected"
        diag = node.diagnostics(time.time())
        assert diag.counters["rejected.image_in"] >= 3
    finally:
        node.stop()


def test_ros2_rig_launch_file_builds_an_inbound_bridge_and_a_planner():
    from aes_planner.graph.launch_file import build_nodes, load_launch

    nodes = [n for n, _ in build_nodes(load_launch("launch/ros2_rig.yaml"))]
    bridge, planner = nodes
    assert isinstance(bridge, Ros2BridgeNode) and bridge.config.inbound and bridge.links is not None
    assert "camera/frame" in bridge.outputs and "gimbal/command" in bridge.inputs
    assert bridge.config.rig == planner.config.rig


def test_compressed_and_mono_images_and_forward_position_commands(peer):
    import cv2

    from aes_planner.messages import GimbalCommand

    rig = load_scene("tabletop:1").rig.pan_tilt
    cfg = Ros2BridgeConfig(
        dds=DdsConfig(domain_id=domain_for_tests()),
        inbound=True,
        rig=rig,
        outbound=(),
        image_transport="compressed",
        command_interface="forward_position",
    )
    node = Ros2BridgeNode(cfg)
    node.start()
    try:
        info = peer.writer("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data")
        img = peer.writer("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", "sensor_data")
        js = peer.writer("/joint_states", "sensor_msgs/msg/JointState", "reliable")
        cmds = peer.reader("/forward_position_controller/commands", "std_msgs/msg/Float64MultiArray")
        rgb = np.zeros((K.height, K.width, 3), np.uint8)
        rgb[:, : K.width // 2] = (200, 50, 10)
        ok, png = cv2.imencode(".png", rgb[..., ::-1])
        out: dict = {}

        def got_frame():
            info.write(_camera_info())
            js.write(_joint_state(time.time(), pos=(0.1, 0.05)))
            img.write(
                make(
                    "sensor_msgs/msg/CompressedImage",
                    header=_header(time.time()),
                    format="png",
                    data=list(png.tobytes()),
                )
            )
            for k, v in node.step({}, time.time()).items():
                out.setdefault(k, []).extend(v)
            return bool(out.get("camera/frame"))

        assert wait_for(got_frame, 20.0, 0.05), node.counters
        assert np.array_equal(out["camera/frame"][-1].image, rgb)  # png is lossless; colours stay RGB
        # a move beyond the limits goes out clamped, in the controller's joint order
        far = GimbalCommand("move", 100.0, -100.0)
        raw: list = []

        def got_command():
            node.step({"gimbal/command": [far]}, time.time())
            raw.extend(Peer.take_raw(cmds))
            return bool(raw)

        assert wait_for(got_command, 20.0, 0.05), node.counters
        pan, tilt = typestore().deserialize_cdr(raw[0], "std_msgs/msg/Float64MultiArray").data
        kin = PanTilt(rig)
        assert (pan, tilt) == pytest.approx(kin.clamp(100.0, -100.0))
    finally:
        node.stop()
    # mono8: grey replicated into RGB
    from aes_planner.ros2 import idl
    from aes_planner.ros2.convert import decode_image

    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    out_img = decode_image(idl.Image(idl.Header(), 3, 4, "mono8", 0, 4, grey.tobytes()))
    assert out_img.shape == (3, 4, 3) and np.array_equal(out_img[..., 1], grey)
