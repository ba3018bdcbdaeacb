"""The soak: frames at 30 Hz into a passive planner for a while, with garbage on every topic.

Used by the short soak test (``make test``), its long form (``@pytest.mark.slow``) and
``aes-planner bench node``. A publisher thread sends frames of a simulated rig scene (a fixed set
rendered once, re-stamped and cycled, so the field keeps changing) at ``rate_hz``; another sends
malformed and oversized payloads on every topic of the planner at ``garbage_hz``; the planner
(passive: it suggests on every field change, at most every ``min_suggest_period_s``) runs in its
thread loop over the in-process bus. A recorder subscribes to everything the planner publishes
and checks every number is finite.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from aes_planner.graph.runner import NodeRunner
from aes_planner.messages import Diagnostics, PlannerRequest, PosedFrame, ViewSuggestion
from aes_planner.node.planner import PlannerConfig, PlannerNode
from aes_planner.platform import RigPlatformConfig

log = logging.getLogger(__name__)

__all__ = ["OVERSIZED_MB", "SoakResult", "rss_mb", "run_soak"]

OVERSIZED_MB = 70  # MiB of zeros appended to a good frame: the oversized garbage on camera/frame


def rss_mb() -> float:
    """Resident set size of this process, MB (Linux /proc)."""
    with open(f"/proc/{os.getpid()}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@dataclass
class SoakResult:
    duration_s: float
    frames_sent: int
    frames_in: int
    frames_dropped: int  # by the planner (batch) + by the subscription queue
    frames_used: int
    suggestions: int
    garbage_sent: int
    rejected: dict[str, int]
    rss_start_mb: float
    rss_end_mb: float
    latency_p50_s: float
    latency_p95_s: float
    field_frames_max: int
    nonfinite: int
    step_errors: int
    rss_samples_mb: list[float] = field(default_factory=list)


def _frames(scene: str, n: int, width: int) -> list[PosedFrame]:
    from aes_planner.sim import SimCamera, SimCameraConfig, load_scene

    sc = load_scene(scene)
    cam = SimCamera(sc, SimCameraConfig(width=width, height=width * 3 // 4))
    joints = sc.rig.kinematics().sweep(n)
    return [cam.capture_joints(p, t, stamp_s=float(i)) for i, (p, t) in enumerate(joints)]


def _finite(msg) -> bool:
    if isinstance(msg, ViewSuggestion):
        return all(
            np.isfinite(c.cam2world).all() and np.isfinite(c.score) and all(np.isfinite(list(c.terms.values())))
            for c in msg.candidates
        )
    if isinstance(msg, Diagnostics):
        return all(np.isfinite(v) for v in msg.values.values())
    return True


def run_soak(
    duration_s: float = 8.0,
    rate_hz: float = 30.0,
    scene: str = "indoor:3",
    scorer: str = "rgb",
    preset: str = "fast",
    width: int = 64,
    max_frames: int = 8,
    garbage_hz: float = 5.0,
    views: int = 12,
    min_suggest_period_s: float = 0.2,
) -> SoakResult:
    from aes_planner.transport import InProcessBus

    frames = _frames(scene, views, width)
    bus = InProcessBus()
    planner = PlannerNode(
        PlannerConfig(
            scorer=scorer,
            preset=preset,
            active=False,
            max_frames=max_frames,
            min_suggest_period_s=min_suggest_period_s,
            diagnostics_period_s=0.5,
            platform=RigPlatformConfig(),
        ),
        node_id="planner",
        context=_context(scene),
    )
    runner = NodeRunner(planner, bus)
    runner.open()
    planner.start()
    seen = {"suggestions": 0, "nonfinite": 0}
    field_max = [0]

    def record(msg):
        seen["suggestions"] += isinstance(msg, ViewSuggestion)
        if not _finite(msg):
            seen["nonfinite"] += 1

    subs = [
        bus.subscribe("planner/suggestion", ViewSuggestion, callback=record),
        bus.subscribe("planner/diagnostics", Diagnostics, callback=record),
    ]
    frame_pub = bus.publisher("camera/frame", PosedFrame, reliable=False)
    raw_pubs = {t: bus.publisher(t, m) for t, m in (("gimbal/state", _gs()), ("planner/request", PlannerRequest))}
    raw_pubs["camera/frame"] = frame_pub
    stop = threading.Event()
    sent = {"frames": 0, "garbage": 0}

    def send_frames():
        period, i, t_next = 1.0 / rate_hz, 0, time.time()
        while not stop.is_set():
            f = frames[i % len(frames)]
            msg = PosedFrame(f.image, f.intrinsics, f.cam2world, time.time(), f.depth_m, f.frame_id, sequence=i)
            frame_pub.publish(msg)
            sent["frames"] += 1
            i += 1
            t_next += period
            stop.wait(max(0.0, t_next - time.time()))

    rng = np.random.default_rng(0)
    good = frames[0].encode() if hasattr(frames[0], "encode") else b""

    def send_garbage():
        while not stop.wait(1.0 / garbage_hz):
            for topic, pub in raw_pubs.items():
                kind = sent["garbage"] % 4
                if kind == 0:
                    data = rng.integers(0, 256, 64, dtype=np.uint8).tobytes()  # noise
                elif kind == 1:
                    data = good[: len(good) // 2]  # truncated
                elif kind == 2:
                    big = topic == "camera/frame"
                    data = good + bytes(OVERSIZED_MB << 20) if big else good  # oversized / wrong type
                else:
                    b = bytearray(good)
                    b[len(b) // 3] ^= 0xFF  # a bit flip
                    data = bytes(b)
                pub.publish_raw(data)
                sent["garbage"] += 1

    threads = [threading.Thread(target=send_frames, daemon=True), threading.Thread(target=send_garbage, daemon=True)]
    runner.start_thread()
    t0 = time.time()
    for t in threads:
        t.start()
    rss_samples = []
    # warm-up: until the first suggestion is out (kernels loaded, allocator primed), at most half the run
    warm_until = t0 + duration_s / 2
    while time.time() < warm_until and not (seen["suggestions"] and time.time() - t0 > 2.0):
        time.sleep(0.1)
    rss_start = rss_mb()
    while time.time() - t0 < duration_s:
        time.sleep(0.25)
        rss_samples.append(rss_mb())
        field_max[0] = max(field_max[0], planner.proposer.size)
    stop.set()
    for t in threads:
        t.join(5)
    runner.request_stop()
    runner.join(60.0)  # a suggestion may be under way
    rss_end = rss_mb()
    c = planner.counters
    sub_stats = {name: s.stats() for name, s in runner.subs.items()}
    runner.close()
    for s in subs:
        s.close()
    planner.stop()
    bus.close()
    return SoakResult(
        duration_s=time.time() - t0,
        frames_sent=sent["frames"],
        frames_in=c["frames_in"],
        frames_dropped=c["frames_dropped"] + sub_stats["camera/frame"]["dropped"],
        frames_used=c["frames_used"],
        suggestions=seen["suggestions"],
        garbage_sent=sent["garbage"],
        rejected={name: st["rejected"] for name, st in sub_stats.items()},
        rss_start_mb=rss_start,
        rss_end_mb=rss_end,
        latency_p50_s=(float(np.percentile(planner.latencies_s, 50)) if len(planner.latencies_s) else 0.0),
        latency_p95_s=(float(np.percentile(planner.latencies_s, 95)) if len(planner.latencies_s) else 0.0),
        field_frames_max=field_max[0],
        nonfinite=seen["nonfinite"],
        step_errors=runner.step_errors,
        rss_samples_mb=rss_samples,
    )


def _gs():
    from aes_planner.messages import GimbalState

    return GimbalState


def _context(scene: str):
    from aes_planner.graph.base import LaunchContext

    return LaunchContext(scene=scene)
