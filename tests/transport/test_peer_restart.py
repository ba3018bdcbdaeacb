"""Peers that die and come back are picked up again without restarting the others; a killed peer
never hangs the survivors."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from aes_planner.messages import GimbalState, PlannerRequest
from aes_planner.transport import RequestTimeout, ZenohConfig
from tests.helpers import wait_for

PEER = Path(__file__).with_name("peer_process.py")


def start(endpoint, mode, tag):
    proc = subprocess.Popen([sys.executable, str(PEER), endpoint, mode, tag], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    return proc


def kill(proc):
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    proc.stdout.close()


def statuses_within(sub, tag, timeout_s=20.0):
    return wait_for(lambda: any(m.status == tag for m in sub.take()), timeout_s=timeout_s, poll_s=0.05)


def query(bus, tag_expected, timeout_s=20.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            if bus.request("gimbal/query", PlannerRequest(), GimbalState, timeout_s=0.5).status == tag_expected:
                return True
        except RequestTimeout:
            pass
        time.sleep(0.1)
    return False


@pytest.mark.parametrize("peer_mode", ["connect", "listen"])
def test_a_killed_peer_comes_back(endpoint, peer_mode):
    """``connect``: we are the hub and the peer restarts; ``listen``: the hub itself restarts and
    we (connected to it) pick it up again."""
    from aes_planner.transport.zenoh_bus import ZenohBus

    ours = ZenohConfig(listen=(endpoint,), connect=()) if peer_mode == "connect" else ZenohConfig(connect=(endpoint,))
    with ZenohBus(ours) as bus:
        sub = bus.subscribe("gimbal/state", GimbalState, depth=50)
        first = start(endpoint, peer_mode, "first")
        try:
            assert statuses_within(sub, "first")
            assert query(bus, "first")
        finally:
            kill(first)
        t0 = time.monotonic()
        with pytest.raises(RequestTimeout):
            bus.request("gimbal/query", PlannerRequest(), GimbalState, timeout_s=0.5)
        assert time.monotonic() - t0 < 5  # the dead peer does not hang us
        sub.take()
        second = start(endpoint, peer_mode, "second")
        try:
            assert statuses_within(sub, "second")
            assert query(bus, "second")
            assert sub.rejected == 0
        finally:
            kill(second)


def test_test_endpoints_lie_below_the_ephemeral_range():
    """A restarted peer's port must not be one an outgoing connection can take as its local port
    (the survivor's reconnects would then connect to themselves and hold it: a flake seen under load)."""
    from .conftest import ephemeral_low, free_port

    ports = {free_port() for _ in range(50)}
    assert all(20000 <= p < ephemeral_low() for p in ports)
    assert len(ports) > 1  # drawn, not fixed: concurrent suites do not queue on one port
