"""Time for a graph: the wall clock, or a simulated clock in lockstep.

``clock: wall`` (real time): each node steps at its period on ``time.time()`` and as soon as a
message arrives; a result depends on how fast the machine is at that moment.

``clock: sim`` (ROS 2's ``use_sim_time`` with a ``/clock`` publisher, in lockstep): time is
simulated, starts at 0, and advances only when every node has handled what it was given, so a
result depends on the scene, the seed and the code, not on the load or on how the nodes are spread
over processes. One :class:`ClockMaster` per graph owns time:

1. it waits until every node has said it is ready (a :class:`~aes_planner.messages.ClockAck` of
   tick 0: subscribed and published, repeated until the first tick arrives);
2. it publishes :class:`~aes_planner.messages.Clock` tick ``k`` (time ``t``, and per topic how
   many messages the nodes published during tick ``k - 1``) on ``clock`` (latched);
3. each node (:class:`Lockstep`, inside :class:`~aes_planner.graph.runner.NodeRunner`) waits until
   it has received every message published to it before ``t`` (the counts; messages travel on
   their own topics and may arrive after the tick), steps when a message arrived or its period is
   due, publishes, and acknowledges tick ``k`` on ``clock/ack`` with what it published and when it
   next wants to step;
4. when every node has acknowledged, the master advances: to ``t + step_s`` when anything was
   published (it is delivered then), else to the earliest time a node wants to step (on the
   ``step_s`` grid), and publishes tick ``k + 1``.

A message published at ``t`` is handled at the next tick, never in the same one, wherever its
subscriber runs: the in-process :class:`~aes_planner.graph.runner.Launch` and the multi-process
:class:`~aes_planner.graph.supervisor.Supervisor` step the nodes through the same ticks with the
same inputs. Nodes that talk to the real world in real time (a camera, a real servo bus, a flight
stack, a ROS 2 graph) cannot run on it: :meth:`~aes_planner.graph.base.Node.sim_clock_problem`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from aes_planner.config import ConfigError, require
from aes_planner.messages import Clock, ClockAck
from aes_planner.messages.clock import NEVER_NS

log = logging.getLogger(__name__)

__all__ = [
    "ACK_TOPIC",
    "CLOCK_SOURCES",
    "CLOCK_TOPIC",
    "ClockConfig",
    "ClockMaster",
    "Lockstep",
    "parse_clock",
]

CLOCK_TOPIC = "clock"
ACK_TOPIC = "clock/ack"
CLOCK_SOURCES = ("sim", "wall")
#: How long (wall seconds) a node waits for messages the clock says were published before it says
#: so in the log; it goes on waiting (a message lost on the way would be a transport bug).
STALL_WARN_S = 30.0


@dataclass
class ClockConfig:
    """A launch file's ``clock:`` (``sim`` or ``wall``, or a mapping of these keys).

    * ``source``: ``wall`` (real time) or ``sim`` (simulated, lockstep);
    * ``step_s``: the simulated clock's resolution: a message reaches its subscribers this long
      after it was published, and the nodes' periods are rounded up to it.
    """

    source: str = "wall"
    step_s: float = 0.01

    def __post_init__(self):
        require(
            self.source in CLOCK_SOURCES,
            "source",
            f"expected one of {', '.join(CLOCK_SOURCES)}, got {self.source!r}",
        )
        require(
            isinstance(self.step_s, (int, float))
            and not isinstance(self.step_s, bool)
            and math.isfinite(self.step_s)
            and 1e-4 <= self.step_s <= 1.0,
            "step_s",
            f"must be a number of seconds in [0.0001, 1], got {self.step_s!r}",
        )

    @property
    def sim(self) -> bool:
        return self.source == "sim"

    @property
    def step_ns(self) -> int:
        return int(round(self.step_s * 1e9))


def parse_clock(value, key: str = "clock") -> ClockConfig:
    """``sim`` / ``wall`` / ``{source: sim, step_s: 0.01}`` / None (wall) -> :class:`ClockConfig`."""
    from aes_planner.config import from_dict

    if value is None:
        return ClockConfig()
    if isinstance(value, str):
        try:
            return ClockConfig(source=value)
        except ConfigError as exc:
            raise ConfigError(key, exc.message) from None
    if isinstance(value, Mapping):
        return from_dict(ClockConfig, value, key)
    raise ConfigError(key, f"expected sim, wall or a mapping with source and step_s, got {value!r}")


class Lockstep:
    """A node's side of the simulated clock (used by :class:`~aes_planner.graph.runner.NodeRunner`):
    wait for a tick, collect the inputs that belong to it, and acknowledge it.

    ``subs``: input name -> subscription; ``topics``: input name -> actual topic."""

    def __init__(self, bus, node_id: str, subs: Mapping, topics: Mapping[str, str]):
        self.node_id = node_id
        self.subs = dict(subs)
        self.topics = dict(topics)
        self.clock_sub = bus.subscribe(CLOCK_TOPIC, Clock, depth=16)
        self.ack_pub = bus.publisher(ACK_TOPIC, ClockAck)
        # per input: messages published to it so far. Nothing is published before the first tick
        # (a node that joins a running graph, respawned, does not wait for what came before it)
        self.expected = {name: sub.received for name, sub in self.subs.items()}
        self.started = False
        # joined a running graph (a respawn: its first tick is a latched one past 1): the next
        # tick's counts include what the others sent before this node subscribed, lost to it
        self.rejoined = False
        self.tick = 0
        self.now_ns = 0
        self.stalls = 0
        self._ready_at = -math.inf

    def close(self) -> None:
        self.clock_sub.close()
        self.ack_pub.close()

    def next_tick(self, stop: threading.Event) -> Clock | None:
        """The next tick of the clock (None once ``stop`` is set); says "ready" until the first."""
        while not stop.is_set():
            new = [c for c in self.clock_sub.take() if c.tick > self.tick]
            if new:
                if self.started:  # the first tick's counts are of the ticks before this node joined
                    for c in new:
                        for name in self.subs:
                            self.expected[name] += c.sent.get(self.topics[name], 0)
                    if self.rejoined:  # count only what reached it: waiting for the lost would stop time
                        self.rejoined = False
                        for name, sub in self.subs.items():
                            self.expected[name] = min(self.expected[name], sub.received)
                else:
                    self.rejoined = new[0].tick > 1
                self.started = True
                self.tick, self.now_ns = new[-1].tick, new[-1].stamp_ns
                return new[-1]
            if not self.started and time.monotonic() - self._ready_at > 0.5:
                self._ready_at = time.monotonic()
                self.ack_pub.publish(ClockAck(self.node_id, 0))
            self.clock_sub.wait(0.1)
        return None

    def inputs(self, stop: threading.Event) -> dict[str, list] | None:
        """Every message published to this node before the tick, per input (oldest first); the
        messages of this tick and later that arrived already stay queued. None once ``stop``."""
        from aes_planner.transport import wait_any

        started = time.monotonic()
        warned = False
        while True:
            short = [name for name, sub in self.subs.items() if sub.received < self.expected[name]]
            if not short:
                break
            if stop.is_set():
                return None
            if not warned and time.monotonic() - started > STALL_WARN_S:
                warned = True
                self.stalls += 1
                log.warning(
                    "%s: tick %d (t = %.3f s): still waiting for %s",
                    self.node_id,
                    self.tick,
                    self.now_ns / 1e9,
                    ", ".join(f"{self.topics[n]} ({self.subs[n].received}/{self.expected[n]})" for n in short),
                )
            wait_any([self.subs[n] for n in short], 0.05)
        out = {}
        for name, sub in self.subs.items():
            early = sub.received - self.expected[name]  # the newest in the queue: this tick's or later
            out[name] = sub.take(max(0, sub.pending - early))
        return out

    def ack(self, sent: Mapping[str, int], next_ns: int) -> None:
        self.ack_pub.publish(ClockAck(self.node_id, self.tick, min(max(0, int(next_ns)), NEVER_NS), dict(sent)))


class ClockMaster:
    """Owns a graph's simulated time (module docstring): publishes ``clock`` and advances it when
    every node in ``nodes`` (their ids) acknowledged the tick. Runs in a thread:
    :meth:`start` / :meth:`stop`; ``tick`` and :attr:`now_s` say where it is."""

    def __init__(self, bus, nodes: Iterable[str], config: ClockConfig | None = None):
        self.config = config or ClockConfig(source="sim")
        self.nodes = sorted(set(nodes))
        if not self.nodes:
            raise ConfigError("nodes", "a simulated clock needs at least one node to step")
        self.bus = bus
        self.tick = 0
        self.now_ns = 0
        self._acks: dict[int, dict[str, ClockAck]] = {}
        self._ready: set[str] = set()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self._pub = bus.publisher(CLOCK_TOPIC, Clock, latched=True)
        self._sub = bus.subscribe(ACK_TOPIC, ClockAck, depth=1024, callback=self._on_ack)

    @property
    def now_s(self) -> float:
        return self.now_ns / 1e9

    def _on_ack(self, ack: ClockAck) -> None:
        if ack.node not in self.nodes:
            return
        with self._cond:
            if ack.tick == 0:
                self._ready.add(ack.node)
            elif ack.tick >= self.tick:  # an old tick's (a respawned node's) is late news
                self._acks.setdefault(ack.tick, {})[ack.node] = ack
            self._cond.notify_all()

    def start(self) -> ClockMaster:
        self._thread = threading.Thread(target=self._run_safely, name="sim-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(5.0)
        self._sub.close()
        self._pub.close()

    def _run_safely(self) -> None:
        try:
            self.run()
        except BaseException as exc:
            self.error = exc
            log.exception("the simulated clock stopped")

    def _wait(self, done) -> bool:
        """Wait until ``done()`` (True) or stop (False); says in the log who holds time up."""
        started, said = time.monotonic(), 0
        with self._cond:
            while not done():
                if self._stop.is_set():
                    return False
                self._cond.wait(0.5)
                waited = time.monotonic() - started
                if waited > STALL_WARN_S * (said + 1):
                    said += 1
                    missing = [n for n in self.nodes if n not in self._ready] if self.tick == 0 else self._missing()
                    log.info(
                        "sim clock: tick %d (t = %.3f s) waits for %s (%.0f s)",
                        self.tick,
                        self.now_s,
                        ", ".join(missing),
                        waited,
                    )
        return True

    def _missing(self) -> list[str]:
        got = self._acks.get(self.tick, {})
        return [n for n in self.nodes if n not in got]

    def run(self) -> None:
        step = self.config.step_ns
        if not self._wait(lambda: self._ready >= set(self.nodes)):
            return
        log.info("sim clock: %s ready; time starts", ", ".join(self.nodes))
        sent: dict[str, int] = {}
        t, tick = 0, 1
        while not self._stop.is_set():
            with self._cond:
                self.tick, self.now_ns = tick, t
            self._pub.publish(Clock(t, tick, sent))
            if not self._wait(lambda: not self._missing()):
                return
            with self._cond:
                acks = self._acks.pop(tick, {})
                for old in [k for k in self._acks if k < tick]:
                    del self._acks[old]
            sent = {}
            for a in acks.values():
                for topic, n in a.sent.items():
                    if n:
                        sent[topic] = sent.get(topic, 0) + n
            if sent:
                t += step
            else:
                due = min(a.next_ns for a in acks.values())
                if due >= NEVER_NS:
                    t += step  # nobody has anything due: keep time moving (a device may)
                else:
                    t = max(t + step, -(-due // step) * step)
            tick += 1
