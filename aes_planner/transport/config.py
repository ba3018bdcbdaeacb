"""``BusConfig`` / ``ZenohConfig``: the ``bus:`` block of a launch file and the CLI's bus flags.

Settings only: :func:`aes_planner.transport.open_bus` builds a bus from them."""

from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass, field
from typing import Literal

from aes_planner.config import ConfigError, require

__all__ = [
    "BusConfig",
    "ZenohConfig",
    "DEFAULT_ENDPOINT",
    "DEFAULT_PORT",
    "DOMAIN_ENV",
    "EPHEMERAL_ENDPOINT",
    "MAX_DOMAIN",
    "domain_prefix",
    "graph_domain",
    "hub_endpoint",
    "hub_port",
]

# The graph's hub port. Not Zenoh's 7447: zenohd, ROS 2's rmw_zenohd router and the zenoh-bridge-*
# tools all listen there by default, so a ROS 2 rmw_zenoh system and a launch on the same machine
# would each fail when started second. 7390 is also below 7400, the RTPS port base: every port a
# DDS participant of any domain binds is 7400 + 250 x domain + offset (7447 itself is a Fast DDS
# participant's unicast port in domain 0), so the ROS 2 bridge's DDS never takes it either; it is
# not 7446 (Zenoh's multicast scouting), and below the kernel's ephemeral range (32768-60999), so
# no outgoing connection's local port takes it.
DEFAULT_PORT = 7390
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
ZENOH_ROUTER_PORT = 7447  # zenohd's and rmw_zenohd's default: named when a clash looks likely
EPHEMERAL_ENDPOINT = "tcp/127.0.0.1:0"

# A graph's domain (as ROS 2's ROS_DOMAIN_ID) separates graphs on one machine: the one setting from
# which the hub's port and the key prefix follow (docs/guides/graphs.md):
#     hub port = 7390 - N        key prefix = "aes" (N = 0) or "aes<N>"
# for N in 0..232 (ROS 2's range), so ports 7158-7390: all below 7400, the RTPS port base, so no DDS
# participant of any domain binds one (the ROS 2 bridge of the same graph uses DDS domain N too).
DOMAIN_ENV = "AES_PLANNER_DOMAIN"
MAX_DOMAIN = 232


def graph_domain(domain: int | None = None, key: str = "domain") -> int:
    """``domain``, else ``AES_PLANNER_DOMAIN``, else 0; checked to be in 0..232."""
    if domain is None:
        text = os.environ.get(DOMAIN_ENV, "").strip()
        if not text:
            return 0
        require(
            text.isdigit() and int(text) <= MAX_DOMAIN,
            DOMAIN_ENV,
            f"must be an integer in 0..{MAX_DOMAIN}, got {text!r}",
        )
        return int(text)
    require(
        isinstance(domain, int) and not isinstance(domain, bool) and 0 <= domain <= MAX_DOMAIN,
        key,
        f"must be an integer in 0..{MAX_DOMAIN} (as ROS_DOMAIN_ID), got {domain!r}",
    )
    return domain


def hub_port(domain: int) -> int:
    return DEFAULT_PORT - domain


def hub_endpoint(domain: int) -> str:
    """Where the hub of domain ``domain``'s graph listens on this machine."""
    return f"tcp/127.0.0.1:{hub_port(domain)}"


def domain_prefix(domain: int) -> str:
    return "aes" if domain == 0 else f"aes{domain}"


_ENDPOINT = re.compile(r"^(tcp|udp|quic|tls)/(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9.\-]+):(\d{1,5})$")


def _endpoint_host(endpoint: str, key: str) -> str:
    m = _ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
    require(m is not None, key, f"endpoint must look like 'tcp/127.0.0.1:7390', got {endpoint!r}")
    require(int(m.group(3)) <= 65535, key, f"port out of range in {endpoint!r}")
    return m.group(2).strip("[]")


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class ZenohConfig:
    """How a process joins the Zenoh network (peer mode).

    * ``domain``: the graph's domain (default: ``AES_PLANNER_DOMAIN``, else 0); the defaults of
      ``connect`` and ``prefix`` follow from it (:func:`hub_endpoint`, :func:`domain_prefix`).
    * ``connect``: endpoints to connect to (retried in the background until they answer, so a
      peer that restarts is picked up again). By default the domain's hub on loopback.
    * ``listen``: endpoints to listen on. Non-loopback addresses need ``allow_remote: true``.
      By default an ephemeral loopback port: the peers learn each other's address from the one
      they connect to (gossip) and then talk directly, so the graph survives any one of them.
    * ``mode``: ``peer`` (a node process, a tool) or ``router`` (a graph's hub: the launcher).
      Peers exchange the addresses they listen on (gossip) and talk directly; they do not forward
      for each other. That meets on one machine, where every address is loopback, but not across
      machines: a node on host A hears of a node on host B at B's loopback address and cannot reach
      it. A router forwards between everything connected to it, so two hubs connected to each other
      carry the graph between hosts, while each node process still listens on loopback only.
      A router's link lease is 30 s (Zenoh's default 10 s), so a network cut shorter than that
      pauses the graph and loses nothing reliable.
    * ``multicast_scouting``: discover peers by UDP multicast on the LAN; off by default.
    * ``prefix``: key prefix of every topic: buses with different prefixes do not see each other.
      By default the domain's.
    * ``open_timeout_s``: how long a ``request`` or a latched catch-up waits for peers.
    """

    connect: tuple[str, ...] | None = None
    listen: tuple[str, ...] = (EPHEMERAL_ENDPOINT,)
    multicast_scouting: bool = False
    allow_remote: bool = False
    mode: Literal["peer", "router"] = "peer"
    prefix: str | None = None
    open_timeout_s: float = 2.0
    domain: int | None = None

    def __post_init__(self):
        self.domain = graph_domain(self.domain)
        self.connect = (hub_endpoint(self.domain),) if self.connect is None else tuple(self.connect)
        self.prefix = domain_prefix(self.domain) if self.prefix is None else self.prefix
        self.listen = tuple(self.listen)
        for i, ep in enumerate(self.connect):
            _endpoint_host(ep, f"connect[{i}]")
        for i, ep in enumerate(self.listen):
            host = _endpoint_host(ep, f"listen[{i}]")
            require(
                self.allow_remote or _is_loopback(host),
                f"listen[{i}]",
                f"{ep} listens beyond loopback; set allow_remote: true (or --allow-remote) if you mean it",
            )
        require(self.mode in ("peer", "router"), "mode", f"must be 'peer' or 'router', got {self.mode!r}")
        require(
            not self.multicast_scouting or self.allow_remote,
            "multicast_scouting",
            "multicast scouting reaches the LAN; set allow_remote: true as well if you mean it",
        )
        require(
            isinstance(self.prefix, str) and re.fullmatch(r"[A-Za-z0-9_\-]{1,64}", self.prefix) is not None,
            "prefix",
            f"must be 1-64 letters, digits, '_' or '-', got {self.prefix!r}",
        )
        require(0 < self.open_timeout_s <= 60, "open_timeout_s", f"must be in (0, 60], got {self.open_timeout_s}")


@dataclass
class BusConfig:
    """``backend``: ``inprocess`` (one process) or ``zenoh`` (processes and machines)."""

    backend: Literal["inprocess", "zenoh"] = "inprocess"
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)

    def __post_init__(self):
        if self.backend not in ("inprocess", "zenoh"):
            raise ConfigError("backend", f"must be 'inprocess' or 'zenoh', got {self.backend!r}")
