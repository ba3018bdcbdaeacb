"""Two hosts for real: two network namespaces joined by a veth pair, each with
its own loopback, as two machines on a cable. The graph splits as docs/guides/topics.md's multi-machine
set-up says: the rig's launch (gimbal on the servo emulator, camera) on one host joins the
planner's launch on the other through their hubs.

Peer-mode hubs never met across hosts: peers only talk directly, and each learnt the other host's
node processes at their loopback addresses. The hubs are Zenoh routers now (ZenohConfig.mode).

Needs root (CI runs as root) and iproute2; elsewhere the tests skip, saying which. Every namespace
and process is removed at teardown, whatever the test did; names are unique per run.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.helpers import wait_for

PEER = Path(__file__).with_name("netns_peer.py")
PORT = 7390


class TwoHosts:
    """Namespaces ``a`` and ``b``, veth ``dev_a`` (in a, ``addr_a``) <-> ``dev_b`` (in b, ``addr_b``)."""

    def __init__(self) -> None:
        tag = f"aes{os.getpid() % 100000}{secrets.token_hex(2)}"  # <= 12 chars: interface names take 15
        self.a, self.b = f"{tag}a", f"{tag}b"
        self.dev_a, self.dev_b = f"{tag}x", f"{tag}y"
        net = secrets.randbelow(250) + 1
        self.addr_a, self.addr_b = f"10.231.{net}.1", f"10.231.{net}.2"
        self.procs: list[subprocess.Popen] = []
        self.made: list[str] = []

    def up(self) -> None:
        for ns in (self.a, self.b):
            _ip("netns", "add", ns)
            self.made.append(ns)
        _ip("link", "add", self.dev_a, "type", "veth", "peer", "name", self.dev_b)
        _ip("link", "set", self.dev_a, "netns", self.a)
        _ip("link", "set", self.dev_b, "netns", self.b)
        for ns, dev, addr in ((self.a, self.dev_a, self.addr_a), (self.b, self.dev_b, self.addr_b)):
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")

    def run(self, ns: str, argv: list[str]) -> subprocess.Popen:
        """``argv`` inside namespace ``ns``, its output read line by line into ``proc.lines``."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        proc = subprocess.Popen(
            ["ip", "netns", "exec", ns, *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            env=env,
            start_new_session=True,
        )
        proc.lines = []  # type: ignore[attr-defined]

        def read() -> None:
            for line in proc.stdout:
                proc.lines.append(line.rstrip("\n"))  # type: ignore[attr-defined]

        threading.Thread(target=read, daemon=True).start()
        self.procs.append(proc)
        return proc

    def peer(self, ns: str, *args: str) -> subprocess.Popen:
        proc = self.run(ns, [sys.executable, str(PEER), *args])
        assert wait_for(lambda: "ready" in proc.lines or proc.poll() is not None, timeout_s=60.0), proc.lines
        assert "ready" in proc.lines, proc.lines
        return proc

    def link(self, up: bool) -> None:
        _ip("-n", self.a, "link", "set", self.dev_a, "up" if up else "down")

    def down(self) -> None:
        for proc in reversed(self.procs):  # only what this object started, by pid
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in reversed(self.procs):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        for ns in self.made:  # deleting a namespace deletes the veth end inside it
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        self.made.clear()


def _ip(*args: str) -> None:
    out = subprocess.run(["ip", *args], capture_output=True, text=True)
    if out.returncode != 0:
        raise OSError(f"ip {' '.join(args)}: {out.stderr.strip()}")


@pytest.fixture
def two_hosts():
    if os.geteuid() != 0:
        pytest.skip("network namespaces need root (CI runs as root)")
    if shutil.which("ip") is None:
        pytest.skip("the ip command (iproute2) is not installed")
    hosts = TwoHosts()
    try:
        try:
            hosts.up()
        except OSError as exc:
            pytest.skip(f"cannot make network namespaces here: {exc}")
        yield hosts
    finally:
        hosts.down()
        assert not any(
            ns in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
            for ns in (hosts.a, hosts.b)
        )


def _rows(proc) -> list[dict]:
    return [json.loads(line) for line in list(proc.lines) if line.startswith("{")]


def test_two_hosts_meet_through_their_hubs_and_a_cut_link_loses_nothing(two_hosts):
    """The transport alone (no planner): a node process on each host, each joined to its own
    host's hub on loopback, the rig's hub connected to the planner's across the link. 100 reliable
    messages at 25 Hz with the link cut for 5 s after the 25th: all arrive, once, in order."""
    h = two_hosts
    hub = f"tcp/{h.addr_a}:{PORT}"
    h.peer(h.a, "hub", hub)
    h.peer(h.b, "hub", f"tcp/127.0.0.1:{PORT}", hub)
    watch = h.peer(h.b, "watch", f"tcp/127.0.0.1:{PORT}", "t/seq")
    pub = h.peer(h.a, "pub", hub, "100", "25")  # as a launcher's child: its hub's own address
    assert wait_for(lambda: len(_rows(watch)) >= 25, timeout_s=60.0), (pub.lines[-3:], watch.lines[-3:])
    h.link(False)
    cut_s = time.time()
    time.sleep(5.0)  # the cut itself, not a wait for a result
    h.link(True)
    restored_s = time.time()
    assert wait_for(lambda: len(_rows(watch)) >= 100, timeout_s=60.0), watch.lines[-3:]
    time.sleep(0.5)  # anything delivered twice would show up now
    rows = _rows(watch)
    assert [r["seq"] for r in rows] == list(range(1, 101))
    during = [r for r in rows if cut_s + 0.2 < r["t"] < restored_s - 0.2]
    assert not during  # the link was really cut: nothing crossed while it was down


def test_the_launchers_hub_is_a_router(endpoint):
    """What makes the launches of two machines meet (the tests above and below run it for real)."""
    from aes_planner.graph.supervisor import Supervisor

    assert Supervisor("sim_closed_loop", endpoint=endpoint).hub_config.mode == "router"


def test_a_hubs_link_outlives_short_network_cuts():
    """Hubs (routers) keep a silent link for 30 s, node processes (peers, on loopback) Zenoh's 10 s."""
    from aes_planner.transport import ZenohConfig
    from aes_planner.transport.zenoh_bus import zenoh_config

    def lease_ms(mode):
        return json.loads(zenoh_config(ZenohConfig(mode=mode, connect=())).get_json("transport/link/tx/lease"))

    assert lease_ms("router") == 30_000 and lease_ms("peer") == 10_000


# A short loop: the point is where it runs, not how well it frames.
SHORT_LOOP = ("planner.max_moves=2", "planner.explore_views=3", "planner.polish_captures=0")


def _launch(h: TwoHosts, ns: str, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "aes_planner", "launch", "sim_closed_loop", "--processes", "--timeout", "400"]
    for s in SHORT_LOOP:
        cmd += ["--set", s]
    return h.run(ns, [*cmd, *args])


@pytest.mark.slow
@pytest.mark.parametrize("cut", [False, True], ids=["steady", "cut_5s"])
def test_the_split_graph_closes_its_loop_across_two_hosts(two_hosts, cut):
    """docs/guides/topics.md's two-machine set-up: the planner's launch listens on its host's address, the
    rig's (gimbal on the servo emulator + sim camera) connects to it. The loop completes; with the
    link cut for 5 s once the gimbal has moved, it pauses and completes, the gimbal holds, every
    command the planner sent arrives once and in order, and none lies outside the joint limits."""
    from aes_planner.sim import load_scene

    h = two_hosts
    hub = f"tcp/{h.addr_a}:{PORT}"
    planner = _launch(
        h, h.a, "--set", "gimbal.type=external", "--set", "camera.type=external", "--listen", hub, "--allow-remote"
    )
    rig = _launch(h, h.b, "--set", "planner.type=external", "--connect", hub)
    sent = h.peer(h.a, "watch", hub, "gimbal/command")  # what the planner published
    got = h.peer(h.b, "watch", f"tcp/127.0.0.1:{PORT}", "gimbal/command", "gimbal/state")  # what the rig saw
    window = None
    if cut:
        moved = lambda: any(r["topic"] == "gimbal/command" and r["kind"] == "move" for r in _rows(got))  # noqa: E731
        assert wait_for(moved, timeout_s=300.0), planner.lines[-5:] + rig.lines[-5:]
        h.link(False)
        start = time.time()
        time.sleep(5.0)  # the cut itself
        h.link(True)
        window = (start, time.time())
    assert wait_for(lambda: planner.poll() is not None, timeout_s=400.0, poll_s=0.5), planner.lines[-10:]
    assert planner.returncode == 0, planner.lines[-20:] + rig.lines[-20:]
    assert any("planner: done" in line for line in planner.lines), planner.lines[-20:]
    time.sleep(1.0)  # the last state messages
    commands_sent = [r for r in _rows(sent) if r["topic"] == "gimbal/command"]
    rows = _rows(got)
    commands = [r for r in rows if r["topic"] == "gimbal/command"]
    states = [r for r in rows if r["topic"] == "gimbal/state"]
    assert commands_sent and [r["seq"] for r in commands] == [r["seq"] for r in commands_sent]
    rig_cfg = load_scene("indoor:3").rig.pan_tilt
    (plo, phi), (tlo, thi) = rig_cfg.pan_limits_deg, rig_cfg.tilt_limits_deg
    eps = 1e-6
    for r in commands:
        if r["kind"] == "move":
            assert (
                plo - eps <= math.degrees(r["pan"]) <= phi + eps and tlo - eps <= math.degrees(r["tilt"]) <= thi + eps
            )
    assert states and all(s["status"] == "ok" for s in states)
    if window is not None:
        start, end = window
        assert not [c for c in commands if start + 0.2 < c["t"] < end - 0.2]  # nothing crossed the cut
        held = [s for s in states if start + 2.0 < s["t"] < end]  # states published on the rig meanwhile
        assert held, "the rig's gimbal kept publishing its state during the cut"
        goals = {(round(s["goal_pan"], 4), round(s["goal_tilt"], 4)) for s in held}
        assert len(goals) == 1  # it holds the last goal it was given
        last = held[-1]
        assert not last["moving"] and abs(last["pan"] - last["goal_pan"]) < 0.02
        assert abs(last["tilt"] - last["goal_tilt"]) < 0.02
    rig.send_signal(signal.SIGTERM)
    rig.wait(timeout=60)
