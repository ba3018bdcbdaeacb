"""The thin loop around a node core, and a launch: several nodes on one bus in one process.

:class:`NodeRunner` subscribes a node's inputs (keep-last depth as the node declares), declares
its outputs (latched and reliable or best-effort as the node declares them), and calls
``step`` with whatever arrived, at the node's period or as soon as an input arrives. A step that
raises is logged and counted; the node keeps running. Subscription counters (received, dropped,
rejected) are added to the node's own diagnostics as ``<topic>.<counter>``.

:class:`Launch` starts the nodes of a launch file in order, each in its own thread, and stops them
in reverse order (devices left safe) however the run ends. :func:`run_graph` runs a
:class:`Launch` or a :class:`~aes_planner.graph.supervisor.Supervisor` from start to stop under
:func:`~aes_planner.graph.signals.stop_on_signals`: what every entry point that launches a graph
(``aes-planner launch``, ``demo``) calls.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping

from aes_planner.graph.base import Node, input_specs, output_specs
from aes_planner.graph.signals import SignalStop, stop_on_signals
from aes_planner.messages import Diagnostics

log = logging.getLogger(__name__)

__all__ = ["Launch", "NodeRunner", "close_sinks", "run_graph"]


class NodeRunner:
    """Moves messages between ``bus`` and ``node.step``; ``remap`` maps default topic -> actual.

    ``clock``: a :class:`~aes_planner.graph.clock.ClockConfig`; on ``sim`` the node steps on the
    graph's simulated clock in lockstep (:class:`~aes_planner.graph.clock.Lockstep`), every output
    reliable (lockstep counts every message), else on the wall clock."""

    def __init__(self, node: Node, bus, remap: Mapping[str, str] | None = None, clock=None):
        self.node = node
        self.bus = bus
        self.remap = dict(remap or {})
        self.sim = bool(clock is not None and clock.sim)
        self.lockstep = None
        self.subs: dict = {}
        self.pubs: dict = {}
        self.step_errors = 0
        self.steps = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None

    def topic(self, name: str) -> str:
        return self.remap.get(name, name)

    def open(self) -> None:
        """Declare the node's subscriptions and publishers on the bus."""
        for name, spec in input_specs(self.node).items():
            self.subs[name] = self.bus.subscribe(self.topic(name), spec.msg_type, depth=spec.depth)
        for name, spec in output_specs(self.node).items():
            self.pubs[name] = self.bus.publisher(
                self.topic(name), spec.msg_type, latched=spec.latched, reliable=spec.reliable or self.sim
            )
        self.node.transport_counters = self.transport_counters  # type: ignore[method-assign]
        if self.sim:
            from aes_planner.graph.clock import Lockstep

            topics = {name: self.topic(name) for name in self.subs}
            self.lockstep = Lockstep(self.bus, self.node.node_id, self.subs, topics)

    def close(self) -> None:
        for s in self.subs.values():
            s.close()
        for p in self.pubs.values():
            p.close()
        if self.lockstep is not None:
            self.lockstep.close()

    def run_once(self, now: float | None = None, inputs: dict[str, list] | None = None) -> dict[str, int]:
        """One step with ``inputs`` (default: whatever arrived); returns how many messages it
        published per actual topic."""
        now = time.time() if now is None else now
        if inputs is None:
            inputs = {name: sub.take() for name, sub in self.subs.items()}
        sent: dict[str, int] = {}
        try:
            outputs = self.node.step(inputs, now)
        except Exception:
            self.step_errors += 1
            log.exception("%s: step failed (%d so far); the node keeps running", self.node.node_id, self.step_errors)
            return sent
        self.steps += 1
        for name, msgs in outputs.items():
            pub = self.pubs.get(name)
            if pub is None:
                continue
            for msg in msgs:
                if isinstance(msg, Diagnostics):
                    self._add_transport_counters(msg)
                pub.publish(msg)
                sent[pub.topic] = sent.get(pub.topic, 0) + 1
        return sent

    def transport_counters(self) -> dict[str, int]:
        """The node's inputs' counters, its step errors and the bus session's health (:meth:`Node.transport_counters`)."""
        counters: dict[str, int] = {}
        for name, sub in self.subs.items():
            for key, value in sub.stats().items():
                if key != "callback_errors":
                    counters[f"{name}.{key}"] = int(value)
        counters["step_errors"] = self.step_errors
        counters.update({f"bus.{k}": int(v) for k, v in self.bus.health().items()})  # a lost session shows here
        if self.lockstep is not None:
            counters["clock_stalls"] = self.lockstep.stalls
        return counters

    def _add_transport_counters(self, msg: Diagnostics) -> None:
        msg.counters = dict(list({**msg.counters, **self.transport_counters()}.items())[:128])

    def loop(self) -> None:
        """Step until :meth:`request_stop`: on the simulated clock, or on the wall clock."""
        if self.lockstep is not None:
            self.lockstep_loop()
        else:
            self.wall_loop()

    def lockstep_loop(self) -> None:
        """Each tick of the simulated clock: the inputs published before it, a step when one
        arrived or the node's period is due, then "done up to this tick"."""
        ls = self.lockstep
        period_ns = max(1, int(round(self.node.period_s * 1e9)))
        next_ns = 0
        while ls.next_tick(self._stop) is not None:
            inputs = ls.inputs(self._stop)
            if inputs is None:
                return
            sent: dict[str, int] = {}
            if ls.now_ns >= next_ns or any(inputs.values()):
                sent = self.run_once(ls.now_ns / 1e9, inputs)
                next_ns = ls.now_ns + period_ns
            ls.ack(sent, next_ns)

    def wall_loop(self) -> None:
        """Step at the node's period on the wall clock, and as soon as an input arrives."""
        from aes_planner.transport.bus import wait_any

        next_s = time.time()
        subs = list(self.subs.values())
        while not self._stop.is_set():
            self.run_once()
            # The period's schedule moves on only when its time has come. A step woken by an input
            # does not push it: it once did, by a period per input, so a node fed faster than its
            # period (the ROS 2 bridge: 40 inputs/s, 0.2 s) ran tens of seconds ahead of the clock
            # and then slept there with its inputs queued (issue 42).
            now = time.time()
            if now >= next_s:
                next_s = next_s + self.node.period_s if next_s + self.node.period_s > now else now + self.node.period_s
            # until an input is pending (one that came during the step included) or the period is
            # due; in slices, so a stop request is seen however long the node's period is
            while not self._stop.is_set() and not wait_any(subs, min(0.1, max(0.0, next_s - time.time()))):
                if time.time() >= next_s:
                    break

    def start_thread(self) -> None:
        def target():
            try:
                self.loop()
            except BaseException as exc:  # reported by Launch.run
                self.error = exc
                log.exception("%s: loop died", self.node.node_id)

        self._thread = threading.Thread(target=target, name=f"node-{self.node.node_id}", daemon=True)
        self._thread.start()

    def request_stop(self) -> None:
        self._stop.set()

    def join(self, timeout_s: float = 5.0) -> None:
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("%s: loop did not stop within %.1f s", self.node.node_id, timeout_s)


class Launch:
    """Nodes (``[(node, remap)]``) on one bus, each in a thread; use as a context manager.

    ``clock``: a :class:`~aes_planner.graph.clock.ClockConfig` (default: the wall clock). On a
    simulated clock the launch also runs the graph's :class:`~aes_planner.graph.clock.ClockMaster`
    for its nodes, unless ``clock_master`` is False (a supervisor runs it for the whole graph)."""

    def __init__(self, nodes: list[tuple[Node, Mapping[str, str]]], bus=None, clock=None, clock_master: bool = True):
        if bus is None:
            from aes_planner.transport import InProcessBus

            bus = InProcessBus()
        self.bus = bus
        self.clock = clock
        self.runners = [NodeRunner(node, bus, remap, clock) for node, remap in nodes]
        self._started: list[NodeRunner] = []
        self.master = None
        self._own_master = bool(clock is not None and clock.sim and clock_master)

    def node(self, node_id: str) -> Node:
        for r in self.runners:
            if r.node.node_id == node_id:
                return r.node
        raise KeyError(node_id)

    def start(self) -> None:
        try:
            for r in self.runners:
                r.open()
            for r in self.runners:
                r.node.start()
                self._started.append(r)
            for r in self.runners:
                r.start_thread()
            if self._own_master:
                from aes_planner.graph.clock import ClockMaster

                self.master = ClockMaster(self.bus, [r.node.node_id for r in self.runners], self.clock).start()
        except BaseException:
            self.stop()
            raise

    @property
    def sim_time_s(self) -> float | None:
        """Where the simulated clock this launch runs stands (None on the wall clock or when a
        supervisor runs the clock)."""
        return self.master.now_s if self.master is not None else None

    @property
    def finished(self) -> bool:
        """True when there are nodes that can finish (:meth:`Node.can_finish`) and all have."""
        finishing = [r.node for r in self.runners if r.node.can_finish()]
        return bool(finishing) and all(n.finished for n in finishing)

    @property
    def failed(self) -> bool:
        """True when a node's loop (or the simulated clock) died."""
        return any(r.error is not None for r in self.runners) or (
            self.master is not None and self.master.error is not None
        )

    def run(self, timeout_s: float | None = None, until=None, poll_s: float = 0.05) -> bool:
        """Wait until every node that can finish has finished (or ``until()`` is true); False on
        timeout or when a node's loop died."""
        deadline = None if timeout_s is None else time.time() + timeout_s
        while True:
            if self.failed:
                return False
            if until is not None and until():
                return True
            if self.finished:
                time.sleep(poll_s * 2)  # let the last messages out
                return True
            if deadline is not None and time.time() > deadline:
                return False
            time.sleep(poll_s)

    def stop(self) -> None:
        if self.master is not None:
            self.master.stop()
        for r in self.runners:
            r.request_stop()
        for r in self.runners:
            r.join()
        for r in reversed(self._started):
            try:
                r.node.stop()
            except Exception:
                log.exception("%s: stop failed", r.node.node_id)
        self._started.clear()
        for r in self.runners:
            r.close()

    def __enter__(self) -> Launch:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def close_sinks(sinks) -> None:
    """Close what watched a run (recorders, live views), newest first; a failure is logged."""
    for s in reversed(list(sinks)):
        try:
            s.close()
        except Exception:
            log.exception("closing %s failed", type(s).__name__)


def run_graph(graph, *, timeout_s: float | None = None, until=None, open_sinks=None) -> tuple[bool, SignalStop]:
    """Start ``graph`` (a :class:`Launch` or a :class:`~aes_planner.graph.supervisor.Supervisor`),
    run it until its nodes finish, ``until()`` is true, ``timeout_s`` passes or the first SIGINT /
    SIGTERM arrives, then stop it (torque off), under
    :func:`~aes_planner.graph.signals.stop_on_signals`: later signals are counted and logged and
    cannot cut the stop short.

    ``open_sinks(bus) -> [sink]``: viewers attached as soon as the graph's bus exists (before
    the nodes start for a :class:`Launch`), closed after the nodes stop. Returns ``(finished,
    stop)``: ``finished`` is False when a signal, the timeout or a failure ended the run;
    ``stop.exit_code`` is ``128 + the first signal`` (None without one).
    """
    with stop_on_signals() as stop:
        sinks, opened, finished = [], open_sinks is None, False
        try:
            if not opened and getattr(graph, "bus", None) is not None:
                sinks, opened = open_sinks(graph.bus), True
            graph.start()
            if not opened:
                sinks = open_sinks(graph.bus)
            finished = graph.run(timeout_s=timeout_s, until=lambda: stop.is_set() or (until is not None and until()))
        finally:
            try:
                graph.stop()
            finally:
                close_sinks(sinks)
    return finished and not stop.is_set(), stop
