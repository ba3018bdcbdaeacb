"""Zenoh buses on loopback only, on a free port, closed after each test (no hang at exit)."""

import random
import socket
from pathlib import Path

import pytest

from aes_planner.transport import ZenohConfig

FREE_PORT_LOW = 20000  # above the fixed TCP ports the package uses (hub ports 7158-7390; DDS ports are UDP)


def ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range (the local ports outgoing connections take)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def free_port() -> int:
    """A free loopback TCP port below the ephemeral range. A port inside it (what binding port 0
    gives) can become an outgoing connection's local port: a bus that keeps reconnecting to a dead
    peer's port then, once in a few thousand tries, connects to itself (TCP simultaneous open) and
    holds the port, and the restarted peer cannot listen there. Real graphs never see this: their
    hub ports (7158-7390) are below the range too."""
    rng = random.SystemRandom()
    for _ in range(500):
        port = rng.randrange(FREE_PORT_LOW, min(ephemeral_low(), 65536))
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free loopback port in {FREE_PORT_LOW}..{ephemeral_low() - 1}")


@pytest.fixture
def endpoint():
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def zenoh_pair(endpoint):
    """A hub bus listening on loopback and a peer bus connected to it."""
    from aes_planner.transport.zenoh_bus import ZenohBus

    hub = ZenohBus(ZenohConfig(listen=(endpoint,), connect=()))
    peer = ZenohBus(ZenohConfig(connect=(endpoint,)))
    yield hub, peer
    peer.close()
    hub.close()
