"""Graphs on one machine: a domain number (``--domain N`` / ``AES_PLANNER_DOMAIN``) from which the
hub's port and the key prefix follow; graphs in two domains never see each other, and a second
graph in a taken domain is refused naming what holds it."""

import json
import random

import pytest

from aes_planner.cli import main
from aes_planner.config import ConfigError
from aes_planner.messages import ViewSuggestion
from aes_planner.transport import TransportError, ZenohConfig
from aes_planner.transport.config import DOMAIN_ENV, domain_prefix, graph_domain, hub_endpoint, hub_port
from aes_planner.transport.zenoh_bus import ZenohBus, _port_taken
from tests.helpers import wait_for


def free_domains(n: int) -> list[int]:
    """Domains whose hub port is free now (other runs on this machine may hold some)."""
    found = [d for d in random.sample(range(100, 233), 133) if not _port_taken(hub_endpoint(d))]
    assert len(found) >= n, "no free domain ports on this machine"
    return found[:n]


def test_the_formula_and_the_setting(monkeypatch):
    monkeypatch.delenv(DOMAIN_ENV, raising=False)
    assert graph_domain() == 0 and hub_port(0) == 7390 and domain_prefix(0) == "aes"
    assert ZenohConfig().connect == ("tcp/127.0.0.1:7390",) and ZenohConfig().prefix == "aes"
    monkeypatch.setenv(DOMAIN_ENV, "7")
    cfg = ZenohConfig()
    assert (cfg.domain, cfg.connect, cfg.prefix) == (7, ("tcp/127.0.0.1:7383",), "aes7")
    assert ZenohConfig(domain=3).connect == ("tcp/127.0.0.1:7387",)  # the config's own wins
    assert all(7158 <= hub_port(d) < 7400 for d in (0, 232))  # below the RTPS ports of every DDS domain
    monkeypatch.setenv(DOMAIN_ENV, "233")
    with pytest.raises(ConfigError, match=DOMAIN_ENV):
        ZenohConfig()
    with pytest.raises(ConfigError, match="domain"):
        ZenohConfig(domain=-1)


def test_two_domains_side_by_side_never_see_each_other(monkeypatch):
    monkeypatch.delenv(DOMAIN_ENV, raising=False)
    a, b = free_domains(2)
    buses = []
    try:
        hubs = {
            d: ZenohBus(ZenohConfig(domain=d, listen=(hub_endpoint(d),), connect=(), mode="router")) for d in (a, b)
        }
        buses += hubs.values()
        peers = {d: ZenohBus(ZenohConfig(domain=d)) for d in (a, b)}  # each finds its hub by its domain alone
        buses += peers.values()
        # a tool of domain a pointed at b's hub by hand still sees nothing of b: the prefixes differ
        stray = ZenohBus(ZenohConfig(domain=a, connect=(hub_endpoint(b),)))
        buses.append(stray)
        subs = {d: peers[d].subscribe("planner/suggestion", ViewSuggestion) for d in (a, b)}
        stray_sub = stray.subscribe("planner/suggestion", ViewSuggestion)
        for d in (a, b):
            hubs[d].publisher("planner/suggestion", ViewSuggestion, latched=True).publish(
                ViewSuggestion(1.0, sequence=d)
            )
        assert wait_for(lambda: all(s.received for s in subs.values()))
        assert wait_for(lambda: peers[a].heartbeats_heard > 3 and peers[b].heartbeats_heard > 3)
        assert [m.sequence for m in subs[a].take()] == [a] and [m.sequence for m in subs[b].take()] == [b]
        assert stray_sub.received == 0 and {i.topic for i in stray.topics(0.3)} <= {"planner/suggestion"}
        assert all(i.publishers == 0 for i in stray.topics(0.3))
    finally:
        for bus in reversed(buses):
            bus.close()


def test_a_second_graph_in_a_taken_domain_is_refused_naming_the_holder(monkeypatch):
    monkeypatch.delenv(DOMAIN_ENV, raising=False)
    (d,) = free_domains(1)
    first = ZenohBus(ZenohConfig(domain=d, listen=(hub_endpoint(d),), connect=(), mode="router"))
    try:
        with pytest.raises(TransportError) as err:
            ZenohBus(ZenohConfig(domain=d, listen=(hub_endpoint(d),), connect=(), mode="router"))
        text = str(err.value)
        assert "held by pid" in text and "--domain" in text and f"domain {d}'s hub port" in text and "\n" not in text
    finally:
        first.close()


def test_the_tools_take_the_domain(monkeypatch, capsys):
    monkeypatch.delenv(DOMAIN_ENV, raising=False)
    (d,) = free_domains(1)
    hub = ZenohBus(ZenohConfig(domain=d, listen=(hub_endpoint(d),), connect=(), mode="router"))
    try:
        hub.publisher("planner/suggestion", ViewSuggestion, latched=True).publish(ViewSuggestion(1.0, sequence=5))
        assert main(["echo", "planner/suggestion", "--domain", str(d), "--once", "--json", "--timeout", "60"]) == 0
        assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["sequence"] == 5
        assert DOMAIN_ENV not in __import__("os").environ  # the setting lasted the command only
        assert main(["topics", "--domain", "300"]) == 2
        assert "--domain: must be an integer in 0..232" in capsys.readouterr().err
    finally:
        hub.close()


def test_the_bridge_meets_dds_in_the_graphs_domain_unless_told_otherwise():
    pytest.importorskip("cyclonedds")
    from aes_planner.ros2.dds import DdsConfig, resolve_domain_id

    assert resolve_domain_id(DdsConfig(), {DOMAIN_ENV: "5"}) == 5
    assert resolve_domain_id(DdsConfig(), {DOMAIN_ENV: "5", "ROS_DOMAIN_ID": "9"}) == 9  # ROS 2's own setting wins
    assert resolve_domain_id(DdsConfig(domain_id=2), {DOMAIN_ENV: "5"}) == 2  # and the bridge's config
    assert resolve_domain_id(DdsConfig(), {}) == 0
