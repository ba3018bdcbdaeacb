"""Bad-input sweep of the node topics: every input topic of the gimbal, sim camera and
sim drone nodes gets noise, a truncated message, a message of another type, an oversized one and
extreme-but-valid values. The node keeps stepping, counts each rejection, never fails a step, and
publishes only finite values. (The planner's topics are soaked in tests/bench/test_soak.py.)"""

import time

import numpy as np
import pytest

from aes_planner.graph import LaunchContext, make_node
from aes_planner.graph.base import input_specs, output_specs
from aes_planner.graph.runner import Launch
from aes_planner.messages import Diagnostics, GimbalCommand, GimbalState, PosedFrame, ViewSuggestion
from aes_planner.messages.samples import sample_messages
from tests.helpers import wait_for

SMALL_CAMERA = {"width": 16, "height": 12, "supersample": 1}
NODES = {
    "gimbal": ({"rate_hz": 50, "device": {"type": "sim_pan_tilt"}}, None),
    "sim_camera": ({"rate_hz": 30, "camera": SMALL_CAMERA}, "indoor:3"),
    "sim_drone": ({"rate_hz": 30, "camera": SMALL_CAMERA}, "indoor:3"),
}


def garbage(good: bytes, other: bytes, max_bytes: int) -> list[bytes]:
    flipped = bytearray(good)
    flipped[len(flipped) // 2] ^= 0xFF
    return [
        np.random.default_rng(0).integers(0, 256, 64, dtype=np.uint8).tobytes(),  # noise
        good[: len(good) // 2],  # truncated
        other,  # another message type
        good + bytes(max_bytes + 1),  # oversized
        b"",  # empty
    ]


def extreme(msg_type):
    """Valid messages with extreme values: the node must clamp or ignore them, not fail."""
    samples = sample_messages()
    if msg_type is GimbalCommand:
        return [
            GimbalCommand("move", 1e6, -1e6),
            GimbalCommand("move", 0.1, 0.1, speed_rad_s=1e-300),
            GimbalCommand("move", 0.1, 0.1, speed_rad_s=1e300),
            GimbalCommand("stop"),
            GimbalCommand("reboot"),
        ]
    if msg_type is GimbalState:
        s = samples["GimbalState"]
        # beyond any joint limit but within two turns (a state past that is rejected as implausible)
        return [type(s)(**{**s.__dict__, "pan_rad": 12.0, "tilt_rad": -12.0, "stamp_s": 1e12})]
    if msg_type is ViewSuggestion:
        s = samples["ViewSuggestion"]
        pose = np.eye(4)
        pose[:3, 3] = [1e6, -1e6, 1e6]  # far outside any flight box
        far = [type(c)(**{**c.__dict__, "cam2world": pose, "pan_rad": None, "tilt_rad": None}) for c in s.candidates]
        return [type(s)(**{**s.__dict__, "candidates": far})]
    raise AssertionError(msg_type)


def finite(msg) -> bool:
    if isinstance(msg, PosedFrame):
        return bool(np.isfinite(msg.cam2world).all()) and msg.image.size > 0
    if isinstance(msg, GimbalState):
        return all(np.isfinite([msg.pan_rad, msg.tilt_rad]))
    if isinstance(msg, Diagnostics):
        return all(np.isfinite(list(msg.values.values())))
    return True


@pytest.mark.parametrize("node_type", sorted(NODES))
def test_node_topics_survive_malformed_oversized_and_extreme_messages(node_type, deadline):
    config, scene = NODES[node_type]
    node = make_node(node_type, config, node_type, LaunchContext(scene=scene))
    launch = Launch([(node, {})])
    runner = launch.runners[0]
    bus = launch.bus
    seen = []
    for topic, (msg_type, *_qos) in output_specs(node).items():
        bus.subscribe(topic, msg_type, depth=64, callback=seen.append)
    samples = sample_messages()
    with deadline(60):
        launch.start()
        try:
            time.sleep(0.3)
            steps_before = runner.steps
            sent = {}
            for topic, (msg_type, _depth) in input_specs(node).items():
                good = samples[msg_type.__name__].encode()
                other = (samples["Diagnostics"] if msg_type is not Diagnostics else samples["GimbalState"]).encode()
                raw = bus.publisher(topic, msg_type)
                bad = garbage(good, other, msg_type.MAX_BYTES)
                for data in bad:
                    raw.publish_raw(data)
                for msg in extreme(msg_type):
                    raw.publish(msg)
                sent[topic] = len(bad)
            # Wait on what must happen (bad messages counted, the node stepping and publishing), not a fixed time.
            wait_for(
                lambda: (
                    runner.steps > steps_before
                    and bool(seen)  # and it has published since
                    and all(runner.subs[topic].rejected >= n - 1 for topic, n in sent.items())
                ),
                timeout_s=30.0,
            )
            assert runner.error is None and runner.step_errors == 0
            assert runner.steps > steps_before  # still stepping
            for topic, n in sent.items():
                assert runner.subs[topic].rejected >= n - 1, (topic, runner.subs[topic].stats())  # empty may be dropped
        finally:
            launch.stop()
    assert seen and all(finite(m) for m in seen)
    if node_type == "sim_drone":  # a target far outside the flight box: the drone stays inside it
        lo, hi = np.asarray(node.drone.box.bounds_min_m), np.asarray(node.drone.box.bounds_max_m)
        frames = [m for m in seen if isinstance(m, PosedFrame)]
        assert frames and all(
            ((lo - 1e-6 <= f.cam2world[:3, 3]) & (f.cam2world[:3, 3] <= hi + 1e-6)).all() for f in frames
        )
    if node_type == "gimbal":  # commands far outside the joints were clamped inside them
        states = [m for m in seen if isinstance(m, GimbalState)]
        assert all(abs(s.pan_rad) < 2 * np.pi and abs(s.tilt_rad) < np.pi for s in states)


CONFIG_BOUNDS = [
    ("planner", {"top_k": 65}, "top_k"),  # over a suggestion's candidate cap: every publish failed
    ("planner", {"explore_views": 10**6}, "explore_views"),
    ("planner", {"max_frames": 10**9}, "max_frames"),
    ("planner", {"settle_s": 1e9}, "settle_s"),
    ("planner", {"move_timeout_s": 1e9}, "move_timeout_s"),
    ("planner", {"fault_timeout_s": 1e9}, "fault_timeout_s"),
    ("planner", {"diagnostics_period_s": 1e9}, "diagnostics_period_s"),
    ("sim_camera", {"rate_hz": 1e-9}, "rate_hz"),
    ("sim_drone", {"rate_hz": 1e-9}, "rate_hz"),
    ("gimbal", {"rate_hz": 1e-9, "device": {"type": "sim_pan_tilt"}}, "rate_hz"),
    ("gimbal", {"diagnostics_period_s": 1e9, "device": {"type": "sim_pan_tilt"}}, "diagnostics_period_s"),
    ("camera", {"state_history_s": 1e9}, "state_history_s"),
    ("sim_camera", {"frame_id": "x" * 5000}, "frame_id"),  # over a frame's id cap: the loop died
    ("camera", {"frame_id": "a\x1b[2J"}, "frame_id"),
    ("sim_camera", {"camera": {"latency_s": 1e9}}, "latency_s"),  # no frame would ever come
]


@pytest.mark.parametrize("node_type, config, key", CONFIG_BOUNDS, ids=range(len(CONFIG_BOUNDS)))
def test_node_config_knobs_are_bounded(node_type, config, key, clean_error):
    clean_error(make_node, node_type, config, "n", LaunchContext(scene="indoor:3"), "nodes[0]", match=key)
