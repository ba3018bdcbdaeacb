"""Multi-process launch: one process per node over Zenoh, supervised.

:class:`Supervisor` opens the hub of the graph (a Zenoh peer listening on ``endpoint``, loopback
by default; the children connect to it and then find each other), starts one child process per
node of a launch file (``python -m aes_planner.graph.supervisor --child ...``), and:

* forwards each child's output line by line with a ``[node_id]`` prefix;
* reports a child that dies, and restarts it (after a short back-off, at most ``max_respawns``
  times) when its launch entry says ``respawn: true``; the others keep running and pick the new
  process up through Zenoh. A child that dies and will not be restarted ends the launch (a
  failure: the graph cannot do its job without it, and the others would run, torque on, until
  the timeout);
* ends when a node finishes (the planner settled: its process exits 0 by itself), on Ctrl-C /
  SIGTERM, or at ``timeout_s``: children get SIGTERM in reverse launch order (so devices are
  left safe), then SIGKILL after ``grace_s``. A child that hangs never hangs the launch.

A child runs its single node with the node package's own runner on a :class:`ZenohBus` and exits
0 when its node finishes, 128 + the signal on SIGTERM/SIGINT after stopping it cleanly, 1 when
its loop fails, 2 on a configuration error.
On a simulated clock (the launch's ``clock: sim``) the supervisor runs the graph's
:class:`~aes_planner.graph.clock.ClockMaster` on its hub: every node, in a child or here, steps in
lockstep on it, so the run reproduces the in-process one (:mod:`aes_planner.graph.clock`).
Nodes can also stay in the supervising process (``in_process``: e.g. the demo keeps the planner
to read its result, or ``local_nodes`` built by the caller); they share :attr:`Supervisor.bus`.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

from aes_planner.errors import AesPlannerError
from aes_planner.transport.config import ZenohConfig, domain_prefix, graph_domain, hub_endpoint

__all__ = ["Supervisor", "ChildSpec", "main_child"]

log = logging.getLogger(__name__)


@dataclass
class ChildSpec:
    """One supervised node process."""

    node_id: str
    respawn: bool = False
    proc: subprocess.Popen | None = None
    restarts: int = 0
    exit_codes: list[int] = field(default_factory=list)
    finished: bool = False
    next_start_s: float = 0.0
    reader: threading.Thread | None = None


class Supervisor:
    """See the module docstring. Use as a context manager or call :meth:`start` / :meth:`shutdown`."""

    def __init__(
        self,
        launch_file: str,
        overrides: Sequence[str] = (),
        *,
        endpoint: str | None = None,
        connect: Sequence[str] = (),
        allow_remote: bool = False,
        in_process: Sequence[str] = (),
        local_nodes: Sequence = (),
        max_respawns: int = 5,
        respawn_delay_s: float = 0.5,
        grace_s: float = 5.0,
        out=None,
        log_level: int = logging.WARNING,
    ) -> None:
        from aes_planner.graph import load_launch

        self.launch_file = launch_file
        self.overrides = list(overrides)
        self.spec = load_launch(launch_file, self.overrides)
        self._check_configs()
        # The hub listens for the children (and tools); ``connect`` joins other machines' graphs.
        # Arguments win over the launch file's ``bus:`` block, which wins over the defaults.
        file_bus = getattr(self.spec, "bus", None)
        if endpoint is None:
            endpoint = file_bus.listen[0] if file_bus is not None and file_bus.listen else hub_endpoint(graph_domain())
        if not connect and file_bus is not None and file_bus.connect != ZenohConfig().connect:
            connect = file_bus.connect
        allow_remote = allow_remote or bool(file_bus is not None and file_bus.allow_remote)
        self.prefix = file_bus.prefix if file_bus is not None else domain_prefix(graph_domain())
        self.endpoint = endpoint
        self.hub_config = ZenohConfig(  # a router: it carries the graph to the hubs of other machines
            listen=(endpoint,), connect=tuple(connect), allow_remote=allow_remote, prefix=self.prefix, mode="router"
        )
        if endpoint.rpartition(":")[2] == "0":  # the children must know where to connect
            from aes_planner.config import ConfigError

            raise ConfigError(
                "--listen", f"{endpoint}: a multi-process launch needs a fixed port (children connect to it)"
            )
        # the children's side: a bad endpoint fails here, not in each child
        ZenohConfig(connect=(_child_endpoint(endpoint),), prefix=self.prefix)
        self._prebuilt = list(local_nodes)  # [(node, remap)] built by the caller
        self.in_process = set(in_process) | {n.node_id for n, _ in self._prebuilt}
        self.max_respawns = max_respawns
        self.lost: str | None = None  # the first child that died for good (it ends the launch)
        self.respawn_delay_s = respawn_delay_s
        self.grace_s = grace_s
        self.out = out or sys.stdout
        self.log_level = log_level
        self.children = [
            ChildSpec(e.id, e.respawn) for e in self.spec.nodes if e.type != "external" and e.id not in self.in_process
        ]
        self.bus = None
        self.master = None  # the ClockMaster of a simulated clock
        self.local = None  # the Launch of the in-process nodes
        self.local_nodes: dict = {}
        self.events: list[str] = []
        self._out_lock = threading.Lock()
        self._stop = threading.Event()

    def _check_configs(self) -> None:
        """Every node's config parses here, so a typo fails once, naming the key, not in a child."""
        from aes_planner.config import ConfigError, from_dict
        from aes_planner.graph.base import node_class
        from aes_planner.graph.launch_file import check_remap

        for i, e in enumerate(self.spec.nodes):
            if e.type != "external":
                cls = node_class(e.type)
                from_dict(cls.config_class, e.config, f"nodes[{i}].config")
                check_remap(e, cls, f"nodes[{i}].remap")
                if cls.needs_scene and self.spec.scene is None:
                    raise ConfigError(f"nodes[{i}]", f"a {e.type} node needs a scene: add 'scene: FAMILY:SEED'")

    # -- children ----------------------------------------------------------------------------------

    def _command(self, child: ChildSpec) -> list[str]:
        cmd = [sys.executable, "-m", "aes_planner.graph.supervisor", "--child", child.node_id]
        cmd += ["--launch", self.launch_file, "--connect", _child_endpoint(self.endpoint), "--prefix", self.prefix]
        cmd += ["--log-level", str(self.log_level)]
        for s in self.overrides:
            cmd += ["--set", s]
        return cmd

    def _spawn(self, child: ChildSpec) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        child.proc = subprocess.Popen(
            self._command(child),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # Ctrl-C reaches the supervisor only; it stops the children in order
        )
        child.reader = threading.Thread(target=self._forward, args=(child, child.proc), daemon=True)
        child.reader.start()
        self._say(f"started {child.node_id} (pid {child.proc.pid})")

    def _forward(self, child: ChildSpec, proc: subprocess.Popen) -> None:
        for raw in proc.stdout:
            line = raw.decode("utf-8", "replace").rstrip("\n")
            self._emit(f"[{child.node_id}] {line}")
        proc.stdout.close()

    def _say(self, text: str) -> None:
        self.events.append(text)
        self._emit(f"[launch] {text}")

    def _emit(self, line: str) -> None:
        """One line on the supervisor's output stream (the launch's console), whole, in order."""
        with self._out_lock:
            self.out.write(line + "\n")
            self.out.flush()

    def start(self) -> Supervisor:
        from aes_planner.transport.zenoh_bus import ZenohBus

        try:
            self.bus = ZenohBus(self.hub_config)
        except AesPlannerError as exc:
            raise AesPlannerError(f"the graph's hub ({self.endpoint}): {exc}") from None  # says what holds the port
        if self.spec.clock.sim:  # time starts once every node, here and in the children, is ready
            from aes_planner.graph.clock import ClockMaster

            ids = [c.node_id for c in self.children] + sorted(self.in_process)
            self.master = ClockMaster(self.bus, ids, self.spec.clock).start()
        for child in self.children:
            self._spawn(child)
        if self.in_process:
            from aes_planner.graph import Launch, build_nodes

            nodes = list(self._prebuilt)
            missing = self.in_process - {n.node_id for n, _ in nodes}
            if missing:
                nodes += [(n, r) for n, r in build_nodes(self.spec) if n.node_id in missing]
            self.local_nodes = {n.node_id: n for n, _ in nodes}
            self.local = Launch(nodes, bus=self.bus, clock=self.spec.clock, clock_master=False)
            self.local.start()
        return self

    @property
    def sim_time_s(self) -> float | None:
        """Where the graph's simulated clock stands (None on the wall clock)."""
        return self.master.now_s if self.master is not None else None

    def node(self, node_id: str):
        """An in-process node (see ``in_process``); still readable after :meth:`shutdown`."""
        return self.local_nodes[node_id]

    def _local_done(self) -> bool:
        if self.local is None:
            return False
        if self.local.failed:
            self._say("an in-process node's loop died")
            return True
        return self.local.finished

    def poll(self) -> bool:
        """Check the children once: report deaths, respawn, notice a finished node. True when
        the launch should end (a node finished)."""
        now = time.monotonic()
        done = False
        for child in self.children:
            proc = child.proc
            if proc is None:
                if child.respawn and now >= child.next_start_s and not self._stop.is_set():
                    child.restarts += 1
                    self._say(f"respawning {child.node_id} (restart {child.restarts})")
                    self._spawn(child)
                continue
            code = proc.poll()
            if code is None:
                continue
            if child.reader is not None:
                child.reader.join(timeout=1.0)
            child.exit_codes.append(code)
            child.proc = None
            if code == 0:
                child.finished = True
                self._say(f"{child.node_id} finished")
                done = True
                continue
            self._say(f"{child.node_id} died (exit code {code})")
            if child.respawn and child.restarts < self.max_respawns:
                child.next_start_s = now + self.respawn_delay_s
            else:
                if child.respawn:
                    self._say(f"{child.node_id}: not respawning after {child.restarts} restarts")
                child.respawn = False
                self.lost = self.lost or child.node_id
        return done

    def run(self, timeout_s: float | None = None, until=None, poll_s: float = 0.1) -> bool:
        """Supervise until a node finishes (True), ``until()`` is true (True), Ctrl-C/SIGTERM or
        ``timeout_s`` (False)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._stop.is_set():
            if self.poll() or self._local_done():
                return True
            if self.lost is not None:
                self._say(f"ending the launch: {self.lost} is gone and does not respawn")
                return False
            if self.master is not None and self.master.error is not None:
                self._say("ending the launch: the simulated clock stopped")
                return False
            if until is not None and until():
                return True
            if deadline is not None and time.monotonic() > deadline:
                self._say(f"timeout after {timeout_s:g} s")
                return False
            if self.local is None and self.children and all(c.proc is None and not c.respawn for c in self.children):
                self._say("every node process has ended")
                return False
            self._stop.wait(poll_s)
        return False

    def request_stop(self) -> None:
        self._stop.set()

    def shutdown(self) -> None:
        """Stop the in-process nodes, then SIGTERM every child in reverse launch order and SIGKILL
        what is left after ``grace_s``."""
        self._stop.set()
        if self.master is not None:
            self.master.stop()  # time stands still while the nodes stop
        if self.local is not None:
            try:
                self.local.stop()
            finally:
                self.local = None
        for child in reversed(self.children):
            child.respawn = False
            if child.proc is not None and child.proc.poll() is None:
                try:
                    child.proc.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
        end = time.monotonic() + self.grace_s
        for child in reversed(self.children):
            proc = child.proc
            if proc is None:
                continue
            try:
                proc.wait(timeout=max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                self._say(f"{child.node_id} did not stop within {self.grace_s:g} s; killing it")
                proc.kill()
                proc.wait(timeout=5.0)
            if child.reader is not None:
                child.reader.join(timeout=1.0)
            child.exit_codes.append(proc.returncode)
            child.proc = None
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    stop = shutdown  # the same shape as aes_planner.graph.runner.Launch

    def __enter__(self) -> Supervisor:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.shutdown()


def _child_endpoint(listen: str) -> str:
    """Where a child on this machine reaches a hub listening on ``listen`` (0.0.0.0 -> loopback)."""
    proto, _, rest = listen.partition("/")
    host, _, port = rest.rpartition(":")
    if host in ("0.0.0.0", "[::]"):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


# -- the child process ----------------------------------------------------------------------------

ORPHAN_GRACE_S = 15.0  # after its supervisor vanished, a child gets this long to stop cleanly (torque off)


def _watch_for_orphaning(parent_pid: int, grace_s: float = ORPHAN_GRACE_S) -> None:
    """A supervisor killed outright leaves no orphan. A daemon thread watches for reparenting from
    the start (imports and connecting included, when the main loop is not yet polling): it then
    signals this process (SIGTERM: the node's clean shutdown) and ends it if that has not finished
    within ``grace_s``."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(grace_s)
        os._exit(128 + signal.SIGHUP)

    threading.Thread(target=watch, daemon=True, name="orphan-watch").start()


def main_child(argv: Sequence[str] | None = None) -> int:
    """Run one node of a launch file on a Zenoh bus until it finishes or is signalled."""
    p = argparse.ArgumentParser(prog="aes_planner.graph.supervisor")
    p.add_argument("--child", required=True, metavar="NODE_ID")
    p.add_argument("--launch", required=True)
    p.add_argument("--connect", required=True)
    p.add_argument("--prefix", default="aes")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--log-level", type=int, default=logging.WARNING)
    args = p.parse_args(argv)
    parent = os.getppid()  # a supervisor killed outright leaves no orphan: we watch for reparenting
    logging.basicConfig(level=args.log_level, format="%(levelname)s %(name)s: %(message)s")
    outcome = logging.getLogger("aes_planner.outcome")  # the run's result: shown at any level, without a label
    shown = logging.StreamHandler()
    shown.setFormatter(logging.Formatter("%(message)s"))
    outcome.addHandler(shown)
    outcome.setLevel(logging.INFO)
    outcome.propagate = False

    from aes_planner.graph.signals import stop_on_signals

    # the first SIGTERM/SIGINT (the supervisor's, or our own when orphaned) stops the node; later
    # ones wait until its stop() (torque off) and the Zenoh session's close have run
    with stop_on_signals() as stop:
        _watch_for_orphaning(parent)
        return _run_child(args, parent, stop, outcome)


def _run_child(args: argparse.Namespace, parent: int, stop, outcome: logging.Logger) -> int:
    orphaned = threading.Event()
    try:
        from aes_planner.graph import Launch, build_nodes, load_launch
        from aes_planner.transport.zenoh_bus import ZenohBus

        spec = load_launch(args.launch, args.set)
        entry = spec.entry(args.child)
        nodes = [(n, r) for n, r in build_nodes(spec) if n.node_id == entry.id]
        bus = ZenohBus(ZenohConfig(connect=(args.connect,), prefix=args.prefix))
    except AesPlannerError as exc:
        log.error("%s", exc)
        return 2
    try:
        launch = Launch(nodes, bus=bus, clock=spec.clock, clock_master=False)  # the supervisor runs the clock
        node = nodes[0][0]
        try:
            launch.start()

            def gone() -> bool:
                if os.getppid() != parent:
                    orphaned.set()
                return orphaned.is_set()

            launch.run(until=lambda: stop.is_set() or gone())
        finally:
            launch.stop()
        if launch.failed:
            return 1
        if stop.exit_code is not None:
            return stop.exit_code
        if node.can_finish() and node.finished:
            line = node.outcome() if hasattr(node, "outcome") else None
            if line is not None:
                outcome.info("%s", line)
            return 0
        return 128 + (signal.SIGHUP if orphaned.is_set() else signal.SIGTERM)
    except AesPlannerError as exc:
        log.error("%s", exc)
        return 2
    finally:
        bus.close()


if __name__ == "__main__":
    sys.exit(main_child())
