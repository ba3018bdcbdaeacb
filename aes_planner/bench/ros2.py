"""Benchmark group ``ros2``: what the DDS bridge adds (needs the ``ros2`` extra).

The bridge node runs in its loop thread on an in-process bus, as in a launch; a DDS subscriber in
a separate process (loopback, a domain of its own) stamps each sample on arrival with the wall
clock and subtracts the sample's ``header.stamp``, which the bench sets to the wall clock when it
publishes on the bus. So the latency covers the bus hand-off, the conversion (JPEG encoding for
frames), CDR serialisation, DDS over loopback and deserialisation in the subscriber. Figures:

* ``ros2.suggestion.latency_p50_ms`` / ``_p95_ms``: a 4-candidate suggestion -> ``PoseStamped``
  (the three suggestion topics are written per message; the figure is the first);
* ``ros2.frame_640x480.latency_p50_ms`` / ``_p95_ms``: a 640x480 frame -> ``CompressedImage``;
* ``ros2.frame_640x480.received``: frames of those sent that arrived (best effort);
* ``ros2.frames_30hz.cpu_share_pct``: CPU of the bridge with 640x480 frames at 30 Hz, as a
  percentage of one core (the process's CPU time with the bridge minus without it, over wall time).
"""

from __future__ import annotations

import json
import math
import os
import queue
import subprocess
import sys
import threading
import time

from aes_planner.bench import Recorder

_SUBSCRIBER = r"""
import json, sys, time, threading
from cyclonedds.core import Listener
from aes_planner.ros2 import idl
from aes_planner.ros2.dds import DdsConfig, DdsParticipant
domain, topic, type_name, profile, n, timeout_s = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]), float(sys.argv[6])
lat, done, last = [], threading.Event(), [0.0]
def on_data(reader):
    now = last[0] = time.time()
    for s in reader.take(64):
        if getattr(s, "header", None) is not None:
            lat.append((now - (s.header.stamp.sec + s.header.stamp.nanosec * 1e-9)) * 1e3)
            print("got", flush=True)  # the publisher sends the next sample only after this one
    if len(lat) >= n:
        done.set()
dds = DdsParticipant(DdsConfig(domain_id=int(domain)))
from cyclonedds.sub import DataReader
from aes_planner.ros2.dds import _qos
reader = DataReader(dds.participant, dds._topic(topic, idl.ROS_TYPES[type_name]), _qos(profile), listener=Listener(on_data_available=on_data))
end = time.time() + 20
while not reader.get_matched_publications() and time.time() < end:
    time.sleep(0.01)
print("ready", flush=True)
end = time.time() + timeout_s
while not done.wait(0.2) and time.time() < end:
    if lat and time.time() - last[0] > 2.0:  # best effort: the rest was dropped
        break
print(json.dumps(lat[-n:]), flush=True)
"""


def _measure(domain: int, key: str, make_msg, bus_topic: str, n: int, rate_hz: float):
    """Latencies (ms) of ``n`` messages published at ``rate_hz`` through a bridge to a subscriber process."""
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.ros2.bridge import OUTBOUND, Ros2BridgeConfig, Ros2BridgeNode
    from aes_planner.ros2.dds import DdsConfig
    from aes_planner.transport import InProcessBus

    topic, type_name, profile = OUTBOUND[key]
    sub = subprocess.Popen(
        [sys.executable, "-c", _SUBSCRIBER, str(domain), topic, type_name, profile, str(n), "60"],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "CYCLONEDDS_URI": ""},
    )
    bus = InProcessBus()
    node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain), outbound=(key,)))
    runner = NodeRunner(node, bus)
    runner.open()
    node.start()
    runner.start_thread()
    try:
        assert sub.stdout is not None
        if sub.stdout.readline().strip() != "ready":
            raise RuntimeError("the DDS subscriber did not start")
        _wait_matched(node, key, timeout_s=30.0)
        pub = bus.publisher(bus_topic, type(make_msg(0.0)))
        # One sample in flight at a time: the latched profile keeps the last sample only (writer
        # and reader), so a sample written before the subscriber took the one before may replace
        # it; on a loaded host that lost 1 of 3 at 20 Hz. The next goes when the last arrived (or
        # after a period and 5 s more, counted as lost).
        lines: queue.Queue[str] = queue.Queue()
        reader = threading.Thread(target=lambda: [lines.put(line) for line in sub.stdout], daemon=True)
        reader.start()
        period = 1.0 / rate_hz
        for _ in range(n):
            t0 = time.perf_counter()
            pub.publish(make_msg(time.time()))
            try:
                while lines.get(timeout=5.0).strip() != "got":
                    pass
            except queue.Empty:
                pass
            time.sleep(max(0.0, period - (time.perf_counter() - t0)))
        sub.wait(timeout=60)
        reader.join(timeout=10.0)  # every line read (the process's stdout is closed)
        out = []
        while not lines.empty():
            out.append(lines.get())
        return json.loads([line for line in out if line.strip().startswith("[")][-1])
    finally:
        if sub.poll() is None:
            sub.kill()
        runner.request_stop()
        runner.join()
        node.stop()
        runner.close()
        bus.close()


def _wait_matched(node, key: str, timeout_s: float) -> None:
    """Wait until the bridge's writer for ``key`` has matched the subscriber. The subscriber says
    "ready" once its reader matched the writer; discovery runs both ways, and a volatile writer
    drops what it writes before it has matched the reader (on a loaded host that gap lost 2 of 3
    samples)."""
    end = time.monotonic() + timeout_s
    writer = node._writers[key]
    while not writer.get_matched_subscriptions():
        if time.monotonic() > end:
            raise RuntimeError(f"the bridge's {key} writer matched no DDS subscriber within {timeout_s:g} s")
        time.sleep(0.01)


def _frame_cpu(domain: int, make_frame, seconds: float) -> float:
    """Percent of one core the bridge uses with frames at 30 Hz (process CPU with minus without)."""
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
    from aes_planner.ros2.dds import DdsConfig
    from aes_planner.transport import InProcessBus

    def run(with_bridge: bool) -> float:
        bus = InProcessBus()
        runner = node = None
        if with_bridge:
            node = Ros2BridgeNode(
                Ros2BridgeConfig(dds=DdsConfig(domain_id=domain), outbound=("image", "camera_info", "tf"))
            )
            runner = NodeRunner(node, bus)
            runner.open()
            node.start()
            runner.start_thread()
        pub = bus.publisher("camera/frame", type(make_frame(0.0)), reliable=False)
        c0, t0 = time.process_time(), time.perf_counter()
        next_t = t0
        while time.perf_counter() - t0 < seconds:
            pub.publish(make_frame(time.time()))
            next_t += 1 / 30
            time.sleep(max(0.0, next_t - time.perf_counter()))
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        if runner is not None:
            runner.request_stop()
            runner.join()
            node.stop()
            runner.close()
        bus.close()
        return cpu / wall

    return max(0.0, run(True) - run(False)) * 100.0


def run(rec: Recorder, quick: bool) -> None:
    import numpy as np

    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        from aes_planner.errors import AesPlannerError

        raise AesPlannerError("bench ros2 needs the ros2 extra (cyclonedds): pip install 'aes-planner[ros2]'") from None

    from aes_planner.geometry import Intrinsics, view_to_cam2world
    from aes_planner.messages import Candidate, PosedFrame, ViewSuggestion
    from aes_planner.sim import load_scene
    from aes_planner.sim.raycast import render

    domain = 150 + os.getpid() % 80
    c2w = view_to_cam2world(np.array([0.0, 0.0, 1.3, 0.4, -0.1]))
    cands = [Candidate(c2w, 0.9 - 0.1 * i, 0.9, 0.4, -0.1, {"thirds": 0.3, "balance": 0.1}) for i in range(4)]
    k = Intrinsics.from_fov(640, 480, 60.0)
    rgb = render(load_scene("indoor:3"), c2w, k).rgb  # a real scene: JPEG size as in use

    def suggestion(t: float) -> ViewSuggestion:
        return ViewSuggestion(t, cands, 1, 1, "world", "rig")

    def frame(t: float) -> PosedFrame:
        return PosedFrame(rgb, k, c2w, stamp_s=t, frame_id="bench", pan_rad=0.4, tilt_rad=-0.1)

    n = 20 if quick else 100
    rec.meta["backends"]["ros2"] = "cyclonedds, loopback, subscriber in another process; in-process bus"
    lat = _measure(domain, "suggestion", suggestion, "planner/suggestion", n, 20.0)
    rec.record("ros2.suggestion.latency_p50_ms", (float(np.percentile(lat, 50)) if len(lat) else 0.0), "ms", len(lat))
    rec.record("ros2.suggestion.latency_p95_ms", (float(np.percentile(lat, 95)) if len(lat) else 0.0), "ms", len(lat))
    lat = _measure(domain, "image", frame, "camera/frame", n, 30.0)
    rec.record(
        "ros2.frame_640x480.latency_p50_ms", (float(np.percentile(lat, 50)) if len(lat) else 0.0), "ms", len(lat)
    )
    rec.record(
        "ros2.frame_640x480.latency_p95_ms", (float(np.percentile(lat, 95)) if len(lat) else 0.0), "ms", len(lat)
    )
    rec.record("ros2.frame_640x480.received", len(lat), "frames", n)
    share = _frame_cpu(domain, frame, 3.0 if quick else 10.0)
    rec.record("ros2.frames_30hz.cpu_share_pct", share if math.isfinite(share) else 0.0, "%")
