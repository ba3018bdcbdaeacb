"""The graph's default hub port does not clash with a ROS 2 rmw_zenoh router (7447), and a port
that is taken is named with what may hold it."""

import logging
import socket

import pytest

from aes_planner.cli import processes
from aes_planner.transport import TransportError, ZenohConfig
from aes_planner.transport.config import DEFAULT_ENDPOINT, DEFAULT_PORT
from aes_planner.transport.zenoh_bus import ZenohBus

from .conftest import free_port


def test_the_default_port_is_neither_zenohs_nor_any_dds_domains():
    assert DEFAULT_PORT not in (7446, 7447)  # Zenoh scouting; zenohd / rmw_zenohd / zenoh bridges
    assert 1024 < DEFAULT_PORT < 7400  # below the RTPS port base: no DDS participant of any domain binds it
    # the CLI's copy (kept literal so that --help imports nothing) and the consumers' default agree
    assert processes.DEFAULT_ENDPOINT == DEFAULT_ENDPOINT == f"tcp/127.0.0.1:{DEFAULT_PORT}"
    assert ZenohConfig().connect == (DEFAULT_ENDPOINT,)


def _holder(port: int) -> socket.socket:
    s = socket.socket()
    s.bind(("127.0.0.1", port))
    s.listen()
    return s


def test_a_taken_port_is_named_with_what_may_hold_it():
    port = free_port()
    with _holder(port), pytest.raises(TransportError) as err:
        ZenohBus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), connect=()))
    text = str(err.value)
    assert f"cannot listen on tcp/127.0.0.1:{port}" in text and "--listen" in text and "rmw_zenohd" not in text
    assert "\n" not in text and "cargo" not in text  # one line, not Zenoh's Rust source paths


def test_port_7447_taken_says_it_may_be_a_ros2_zenoh_router():
    try:
        holder = _holder(7447)
    except OSError:
        pytest.skip("port 7447 is in use on this host by something else; the message is checked on any port above")
    with holder, pytest.raises(TransportError, match="rmw_zenohd"):
        ZenohBus(ZenohConfig(listen=("tcp/127.0.0.1:7447",), connect=()))


def test_listening_on_7447_warns_that_a_ros2_router_would_fail(caplog):
    try:
        _holder(7447).close()
    except OSError:
        pytest.skip("port 7447 is in use on this host by something else")
    with caplog.at_level(logging.WARNING), ZenohBus(ZenohConfig(listen=("tcp/127.0.0.1:7447",), connect=())):
        pass
    assert any("rmw_zenohd" in r.getMessage() for r in caplog.records)
