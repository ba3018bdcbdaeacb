"""Benchmark group ``transport``: the soak of the multi-process closed loop with the ROS 2 bridge, under load.

Each run starts two busy processes (``while True: pass``, one per core of a 2-core machine), the
closed loop ``aes-planner launch sim_closed_loop --processes --clock wall`` (real time, as on a
robot: the simulated clock pauses the whole graph while the planner searches, which is no
transport silence) in a free domain of its own, and
beside it, in this process, the ROS 2 bridge (the ``ros2_bridge`` node on a Zenoh bus of its own,
as ``aes-planner ros2 bridge`` runs it) and a raw Zenoh subscriber of every topic; a DDS reader
process reads the bridge's ``/planner/view_suggestion`` (latched; every suggestion, with or without
candidates) and ``/gimbal/joint_states``. Then:

* every suggestion the planner publishes must reach the raw subscriber and, through the bridge,
  the DDS reader (``suggestions_delivered_pct`` / ``suggestions_forwarded_pct``);
* ``max_silence_s``: the longest gap between two messages of a topic while its publisher runs
  (the raw subscriber's topics at 5 Hz or more, and the DDS joint states);
* ``<Type>.latency_p50_ms`` / ``_p99_ms``: bus latency per message type, the raw subscriber's
  arrival time minus the message's ``stamp_s`` (one machine, one clock; a suggestion is stamped
  when its planner step began, so its figure includes the search).

The ``soak_loss_5s`` case repeats the runs with a 5 s session loss injected into the bridge when the
first suggestion is out: :meth:`~aes_planner.transport.zenoh_bus.ZenohBus.simulate_session_loss`
closes the bridge's session under it (as a link lost for good leaves it) and lets no new one open
for 5 s. Figures: ``loss_reported_pct`` (runs whose bridge reported the loss, ``session_ok`` 0),
``detect_s`` (from the loss to the report), ``recover_s`` (to heartbeats heard again) and the
suggestions forwarded (the latched one published during the loss must arrive by catch-up).
``runs`` is 10 (2 with ``--quick``): ``aes-planner bench transport``. Figures are taken under load by construction.
"""

from __future__ import annotations

import json
import logging
import os
import random
import statistics
import subprocess
import sys
import threading
import time

import numpy as np

from aes_planner.bench import Recorder

log = logging.getLogger(__name__)

__all__ = ["SoakRun", "run", "soak_run"]

_DDS_READER = r"""
import json, sys, time
from aes_planner.ros2 import idl
from aes_planner.ros2.dds import DdsConfig, DdsParticipant
dds = DdsParticipant(DdsConfig(domain_id=int(sys.argv[1])))
sug = dds.reader("/planner/view_suggestion", idl.ROS_TYPES["aes_planner_msgs/msg/ViewSuggestion"], "latched")
js = dds.reader("/gimbal/joint_states", idl.ROS_TYPES["sensor_msgs/msg/JointState"], "reliable")
print("ready", flush=True)
while True:
    now = time.time()
    for s in sug.take(16):
        if getattr(s, "header", None) is None:  # an invalid sample (a writer disposed at the end)
            continue
        print(json.dumps({"t": now, "sug": s.header.stamp.sec + s.header.stamp.nanosec * 1e-9}), flush=True)
    if js.take(64):
        print(json.dumps({"t": now, "js": 1}), flush=True)
    time.sleep(0.01)
"""


class SoakRun:
    """What one run saw (see the module docstring)."""

    def __init__(self) -> None:
        self.published: set[float] = set()  # suggestion stamps seen on the bus
        self.sequences: set[int] = set()  # their sequence numbers (the planner counts from 1)
        self.forwarded: set[float] = set()  # suggestion stamps the DDS reader got
        self.arrivals: dict[str, list[float]] = {}  # topic -> arrival times (raw subscriber)
        self.latency_s: dict[str, list[float]] = {}  # type -> arrival - stamp
        self.dds_js: list[float] = []
        self.launch_rc: int | None = None
        self.loss_at: float | None = None
        self.loss_wall: float = 0.0
        self.detected_at: float | None = None
        self.recovered_at: float | None = None

    def delivered_pct(self) -> float:
        """Suggestions the raw subscriber got of those the planner published (its sequence
        numbers count them: a gap is a suggestion lost)."""
        return 0.0 if not self.sequences else 100.0 * len(self.sequences) / max(self.sequences)

    def forwarded_pct(self) -> float:
        if not self.published:
            return 0.0
        got = sum(1 for s in self.published if any(abs(s - f) < 1e-6 for f in self.forwarded))
        return 100.0 * got / len(self.published)

    def summary(self) -> dict:
        """One line of figures for the log."""
        skip = None if self.loss_at is None else (self.loss_wall - 0.5, self.loss_wall + 15)
        return {
            "launch_rc": self.launch_rc,
            "suggestions": sorted(self.sequences),
            "delivered_pct": self.delivered_pct(),
            "forwarded_pct": self.forwarded_pct(),
            "max_silence_s": {k: round(v, 2) for k, v in self.max_silence_s(skip).items()},
            "detect_s": None if self.detected_at is None else round(self.detected_at - self.loss_at, 2),
            "recover_s": None if self.recovered_at is None else round(self.recovered_at - self.loss_at, 2),
        }

    def max_silence_s(self, skip: tuple[float, float] | None = None) -> dict[str, float]:
        """Per stream at 5 Hz or more: the longest gap between two arrivals (``skip``: a window
        whose gaps are not counted, the injected loss)."""
        out = {}
        streams = dict(self.arrivals)
        states = self.arrivals.get("gimbal/state", [])
        if states:  # while the gimbal publishes (a last state may cross as it shuts down)
            streams["dds:/gimbal/joint_states"] = [t for t in self.dds_js if t <= states[-1] + 0.5]
        for topic, times in streams.items():
            if len(times) < 10 or (times[-1] - times[0]) <= 0 or len(times) / (times[-1] - times[0]) < 5:
                continue
            gaps = [b - a for a, b in zip(times, times[1:]) if skip is None or b < skip[0] or a > skip[1]]
            out[topic] = max(gaps, default=0.0)
        return out


def _free_domain() -> int:
    from aes_planner.transport.config import hub_endpoint
    from aes_planner.transport.zenoh_bus import _port_taken

    for d in random.sample(range(100, 233), 133):
        if not _port_taken(hub_endpoint(d)):
            return d
    raise RuntimeError("no free domain on this machine")


def soak_run(loss_s: float = 0.0, busy: int = 2, timeout_s: float = 400.0) -> SoakRun:
    """One run (module docstring); ``loss_s`` > 0 injects a session loss that long into the bridge."""
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.messages import MessageError, decode
    from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
    from aes_planner.ros2.dds import DdsConfig
    from aes_planner.transport import ZenohConfig
    from aes_planner.transport.zenoh_bus import ZenohBus

    res = SoakRun()
    domain = _free_domain()
    env = dict(os.environ, PYTHONUNBUFFERED="1", CYCLONEDDS_URI="")
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    reader = subprocess.Popen(
        [sys.executable, "-c", _DDS_READER, str(domain)], stdout=subprocess.PIPE, text=True, env=env
    )
    procs.append(reader)
    first_suggestion = threading.Event()

    def on_raw(sample) -> None:
        now = time.time()
        res.arrivals.setdefault(sample.topic, []).append(now)
        try:
            msg = decode(sample.data)
        except MessageError:
            return
        stamp = getattr(msg, "stamp_s", None)
        if stamp is not None and abs(now - stamp) < 60:  # stamped on this machine's wall clock
            res.latency_s.setdefault(type(msg).__name__, []).append(now - stamp)
        if sample.topic == "planner/suggestion":
            res.published.add(msg.stamp_s)
            res.sequences.add(msg.sequence)
            first_suggestion.set()

    def read_dds() -> None:
        for line in reader.stdout:
            if line.startswith("{"):
                d = json.loads(line)
                if "sug" in d:
                    res.forwarded.add(d["sug"])
                else:
                    res.dds_js.append(d["t"])

    raw_bus = bridge_bus = runner = node = launch = None
    try:
        assert reader.stdout is not None
        if reader.stdout.readline().strip() != "ready":
            raise RuntimeError("the DDS reader did not start")
        threading.Thread(target=read_dds, daemon=True).start()
        launch = subprocess.Popen(
            [sys.executable, "-m", "aes_planner", "launch", "sim_closed_loop", "--processes"]
            + ["--clock", "wall", "--domain", str(domain), "--timeout", str(timeout_s)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
            start_new_session=True,
        )
        procs.append(launch)
        raw_bus = ZenohBus(ZenohConfig(domain=domain))
        raw_bus.subscribe_raw("**", depth=100_000, callback=on_raw)
        bridge_bus = ZenohBus(ZenohConfig(domain=domain))
        node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain)))
        runner = NodeRunner(node, bridge_bus)
        runner.open()
        node.start()
        runner.start_thread()
        end = time.monotonic() + timeout_s + 30
        while launch.poll() is None and time.monotonic() < end:
            if loss_s > 0 and res.loss_at is None and first_suggestion.is_set() and bridge_bus.heartbeats_heard:
                res.loss_at, res.loss_wall = time.monotonic(), time.time()
                bridge_bus.simulate_session_loss(loss_s)
            if res.loss_at is not None:
                now = time.monotonic()
                if res.detected_at is None and not bridge_bus.session_ok:
                    res.detected_at = now
                if res.detected_at is not None and res.recovered_at is None and bridge_bus.session_ok:
                    res.recovered_at = now
            time.sleep(0.02)
        res.launch_rc = launch.poll()
        settle = time.monotonic() + 15  # the last suggestion through the bridge to DDS
        while time.monotonic() < settle and res.forwarded_pct() < 100:
            if res.loss_at is not None and res.recovered_at is None and bridge_bus.session_ok:
                res.recovered_at = time.monotonic()
            time.sleep(0.1)
    finally:
        if runner is not None:
            runner.request_stop()
            runner.join()
            node.stop()
            runner.close()
        for bus in (bridge_bus, raw_bus):
            if bus is not None:
                bus.close()
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    return res


def run(rec: Recorder, quick: bool) -> None:
    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        log.warning("soak: skipped (needs the ros2 extra: pip install 'aes-planner[ros2]')")
        return
    runs = 2 if quick else 10
    for case, loss_s in (("soak", 0.0), ("soak_loss_5s", 5.0)):
        results = []
        for i in range(runs):
            r = soak_run(loss_s)
            results.append(r)
            log.info("transport %s run %d: %s", case, i + 1, json.dumps(r.summary()))
        key = f"transport.{case}"
        rec.record(f"{key}.runs_completed", sum(r.launch_rc == 0 for r in results), "runs", runs)
        rec.record(f"{key}.suggestions_published", sum(len(r.published) for r in results), "msgs", runs)
        rec.record(f"{key}.suggestions_delivered_pct", min(r.delivered_pct() for r in results), "%", runs)
        rec.record(f"{key}.suggestions_forwarded_pct", min(r.forwarded_pct() for r in results), "%", runs)
        rec.record(
            f"{key}.runs_all_forwarded",
            sum(bool(r.published) and r.forwarded_pct() == 100 for r in results),
            "runs",
            runs,
        )
        silences = [
            max(
                r.max_silence_s(None if r.loss_at is None else (r.loss_wall - 0.5, r.loss_wall + loss_s + 10)).values(),
                default=0.0,
            )
            for r in results
        ]
        rec.record(f"{key}.max_silence_s", max(silences), "s", runs)
        lat: dict[str, list[float]] = {}
        for r in results:
            for t, v in r.latency_s.items():
                lat.setdefault(t, []).extend(v)
        for t, v in sorted(lat.items()):
            rec.record(f"{key}.{t}.latency_p50_ms", (float(np.percentile(v, 50)) if len(v) else 0.0) * 1e3, "ms", runs)
            rec.record(f"{key}.{t}.latency_p99_ms", (float(np.percentile(v, 99)) if len(v) else 0.0) * 1e3, "ms", runs)
        if loss_s:
            reported = [r for r in results if r.detected_at is not None]
            rec.record(f"{key}.loss_reported_pct", 100.0 * len(reported) / runs, "%", runs)
            if reported:
                rec.record(f"{key}.detect_s", statistics.median(r.detected_at - r.loss_at for r in reported), "s", runs)
            recovered = [r for r in reported if r.recovered_at is not None]
            rec.record(f"{key}.recovered_pct", 100.0 * len(recovered) / runs, "%", runs)
            if recovered:
                rec.record(
                    f"{key}.recover_s", statistics.median(r.recovered_at - r.loss_at for r in recovered), "s", runs
                )
