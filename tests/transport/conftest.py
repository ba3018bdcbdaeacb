"""Zenoh buses on loopback only, on a free port, closed after each test (no hang at exit)."""

import socket

import pytest

from aes_planner.transport import ZenohConfig


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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
