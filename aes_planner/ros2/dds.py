"""Joining a ROS 2 DDS domain as rmw_cyclonedds_cpp does: domain id, discovery range, QoS.

* Domain: ``domain_id`` in the config, else ``ROS_DOMAIN_ID``, else the graph's domain
  (``AES_PLANNER_DOMAIN``, ``--domain``), else 0 (0-232, as ROS 2 allows).
* Discovery range: ``discovery_range`` in the config, else ``ROS_AUTOMATIC_DISCOVERY_RANGE``
  (``LOCALHOST``, ``SUBNET``, ``OFF``, ``SYSTEM_DEFAULT``; ``ROS_LOCALHOST_ONLY=1`` of Humble
  means ``LOCALHOST``), else **loopback**: this package's default, stricter than ROS 2's (which
  is ``SUBNET``): this package opens no listener beyond loopback unless told to. Static peers from
  ``static_peers`` or ``ROS_STATIC_PEERS`` (``;``-separated), as rmw_cyclonedds adds them.
* The Cyclone configuration is rmw_cyclonedds_cpp's fragment for that range: multicast off,
  ``ParticipantIndex auto``, ``MaxAutoParticipantIndex 32`` and the peer ``localhost`` for
  ``localhost``; ``loopback`` is the same with the loopback interface as the only network
  interface (unless ``CYCLONEDDS_URI`` is set: Cyclone would select it twice, and the user's file
  decides) and the peer ``127.0.0.1``. Then ``CYCLONEDDS_URI`` is appended after a comma exactly
  as rmw_cyclonedds does, so the user's file overrides what it sets. Ranges beyond the machine
  need ``allow_remote`` (the explicit option).

  ``loopback`` and ``localhost`` differ for peers on the default interface: a participant on the
  loopback interface alone does not reach one that advertises the host's other address (a ROS 2
  node with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` on rmw_cyclonedds, measured here), while a
  ``localhost`` participant reaches both kinds; in exchange its data socket is bound to the
  default interface's address (discovery still only asks this machine). Setting
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (as for the ROS 2 nodes) picks ``localhost``.
* QoS profiles (:data:`QOS_PROFILES`): ``latched`` (reliable, transient local, keep last 1),
  ``reliable`` (reliable, volatile, keep last 10: ROS 2's default), ``sensor_data`` (best effort,
  volatile, keep last 5: ``rclcpp::SensorDataQoS``). Every reader and writer pins the XCDR1
  data representation, as rmw_cyclonedds does.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field

from aes_planner.config import ConfigError, require
from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)

__all__ = [
    "DdsConfig",
    "DdsError",
    "DdsParticipant",
    "QOS_PROFILES",
    "cyclone_config",
    "resolve_domain_id",
    "resolve_range",
]

RANGES = ("loopback", "localhost", "subnet", "off", "system_default")
QOS_PROFILES = ("latched", "reliable", "sensor_data")
MAX_DOMAIN_ID = 232


class DdsError(AesPlannerError):
    """The DDS side cannot start as configured (domain, discovery, Cyclone configuration)."""


@dataclass
class DdsConfig:
    """* ``domain_id``: -1 = ``ROS_DOMAIN_ID`` (else 0).
    * ``discovery_range``: ``""`` = ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (else loopback).
    * ``static_peers``: extra unicast peers (addresses), as ``ROS_STATIC_PEERS``.
    * ``allow_remote``: needed for a range or a peer beyond this machine.
    """

    domain_id: int = -1
    discovery_range: str = ""
    static_peers: tuple[str, ...] = ()
    allow_remote: bool = False

    def __post_init__(self):
        require(
            isinstance(self.domain_id, int) and -1 <= self.domain_id <= MAX_DOMAIN_ID,
            "domain_id",
            f"must be in 0..{MAX_DOMAIN_ID} (or -1 for ROS_DOMAIN_ID), got {self.domain_id!r}",
        )
        require(
            self.discovery_range == "" or str(self.discovery_range).lower() in RANGES,
            "discovery_range",
            f"must be one of {', '.join(RANGES)} (or empty for ROS_AUTOMATIC_DISCOVERY_RANGE), "
            f"got {self.discovery_range!r}",
        )
        self.discovery_range = str(self.discovery_range).lower()
        self.static_peers = tuple(self.static_peers)
        for i, p in enumerate(self.static_peers):
            require(
                isinstance(p, str) and 0 < len(p) <= 255 and all(c.isalnum() or c in ".:-[]" for c in p),
                f"static_peers[{i}]",
                f"must be a host name or address, got {p!r}",
            )


def resolve_domain_id(config: DdsConfig, env: dict | None = None) -> int:
    env = os.environ if env is None else env
    if config.domain_id >= 0:
        return config.domain_id
    text = env.get("ROS_DOMAIN_ID", "").strip()
    if not text:  # the graph's domain (docs/guides/graphs.md): a bridge of graph N meets DDS domain N
        text = env.get("AES_PLANNER_DOMAIN", "").strip() or "0"
    if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
        raise DdsError(f"ROS_DOMAIN_ID must be an integer in 0..{MAX_DOMAIN_ID}, got {text!r}")
    return int(text)


def resolve_range(config: DdsConfig, env: dict | None = None) -> tuple[str, tuple[str, ...]]:
    """(discovery range, static peers) from the config, else the ROS 2 environment."""
    env = os.environ if env is None else env
    rng = config.discovery_range
    if not rng:
        text = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().lower()
        if text and text not in RANGES[1:]:
            raise DdsError(f"ROS_AUTOMATIC_DISCOVERY_RANGE must be one of {', '.join(r.upper() for r in RANGES[1:])}")
        localhost_only = env.get("ROS_LOCALHOST_ONLY", "")
        if not text and localhost_only not in ("", "1", "0"):
            raise DdsError("ROS_LOCALHOST_ONLY must be 0 or 1")
        rng = text or ("localhost" if localhost_only == "1" else "loopback")
    peers = config.static_peers or tuple(p for p in env.get("ROS_STATIC_PEERS", "").split(";") if p.strip())
    return rng, tuple(p.strip() for p in peers)


def _is_local(host: str) -> bool:
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def cyclone_config(rng: str, peers: tuple[str, ...], allow_remote: bool, uri: str | None) -> str:
    """The Cyclone DDS configuration string for a discovery range (see the module docstring)."""
    if rng not in RANGES:
        raise ConfigError("discovery_range", f"must be one of {', '.join(RANGES)}, got {rng!r}")
    remote = [p for p in peers if not _is_local(p)]
    if (rng in ("subnet", "system_default") or remote) and not allow_remote:
        raise DdsError(
            f"discovery range {rng!r}{' with peers ' + ', '.join(remote) if remote else ''} reaches beyond this "
            "machine; pass --allow-remote-dds (or dds.allow_remote: true in the bridge's config) if you mean it"
        )
    if rng == "system_default":
        frag = ""
    else:
        general = "<AllowMulticast>false</AllowMulticast>" if rng in ("loopback", "localhost", "off") else ""
        if rng == "loopback" and not uri:  # a user's CYCLONEDDS_URI picks its own interfaces
            general = '<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>' + general
        local = {"loopback": ["127.0.0.1"], "localhost": ["localhost"]}.get(rng, [])
        peer_list = local + (list(peers) if rng != "off" else [])
        if rng == "off":
            disc = f"<ParticipantIndex>none</ParticipantIndex><Tag>ros_discovery_off_{os.getpid()}</Tag>"
        else:
            disc = "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
        if peer_list:
            disc += "<Peers>" + "".join(f'<Peer address="{p}"/>' for p in peer_list) + "</Peers>"
        frag = (
            "<CycloneDDS><Domain>"
            + (f"<General>{general}</General>" if general else "")
            + f"<Discovery>{disc}</Discovery></Domain></CycloneDDS>"
        )
    return ",".join(x for x in (frag, uri or "") if x)


def _qos(profile: str, depth: int | None = None):
    from cyclonedds.qos import Policy, Qos

    xcdr1 = Policy.DataRepresentation(use_cdrv0_representation=True)
    if profile == "latched":
        return Qos(
            Policy.Reliability.Reliable(max_blocking_time=100_000_000),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(depth or 1),
            xcdr1,
        )
    if profile == "reliable":
        return Qos(
            Policy.Reliability.Reliable(max_blocking_time=100_000_000),
            Policy.Durability.Volatile,
            Policy.History.KeepLast(depth or 10),
            xcdr1,
        )
    if profile == "sensor_data":
        return Qos(
            Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(depth or 5), xcdr1
        )
    raise ConfigError("qos", f"must be one of {', '.join(QOS_PROFILES)}, got {profile!r}")


def ros_topic(name: str) -> str:
    """``/planner/suggestion`` -> ``rt/planner/suggestion`` (a ROS 2 topic's DDS name)."""
    return "rt/" + name.lstrip("/")


@dataclass
class DdsParticipant:
    """One DDS participant on the resolved domain; writers and readers by ROS 2 topic name."""

    config: DdsConfig = field(default_factory=DdsConfig)

    def __post_init__(self):
        from cyclonedds.core import DDSException
        from cyclonedds.domain import Domain, DomainParticipant

        self.domain_id = resolve_domain_id(self.config)
        rng, peers = resolve_range(self.config)
        self.discovery_range = rng
        xml = cyclone_config(rng, peers, self.config.allow_remote, os.environ.get("CYCLONEDDS_URI"))
        self._domain = None
        try:
            self._domain = Domain(self.domain_id, xml or None)
        except DDSException as exc:
            # this process already created the domain (another bridge, a test's peer): join it
            log.debug("DDS domain %d exists in this process (%s); joining it", self.domain_id, exc)
        try:
            self.participant = DomainParticipant(self.domain_id)
        except DDSException as exc:
            raise DdsError(
                f"cannot join DDS domain {self.domain_id}: {exc}; check CYCLONEDDS_URI and ROS_DOMAIN_ID"
            ) from None
        self._topics: dict[str, object] = {}
        self.writers: list = []
        self.readers: list = []
        self._graph_writer = None

    def _topic(self, name: str, idl_type: type, raw: bool = False):
        from cyclonedds.topic import Topic

        key = name if raw else ros_topic(name)
        top = self._topics.get(key)
        if top is None:
            top = self._topics[key] = Topic(self.participant, key, idl_type)
        elif top.data_type is not idl_type:
            raise DdsError(f"DDS topic {key} is already used with {top.data_type.__idl_typename__}")
        return top

    def writer(self, name: str, idl_type: type, profile: str, depth: int | None = None):
        from cyclonedds.pub import DataWriter

        w = DataWriter(self.participant, self._topic(name, idl_type), _qos(profile, depth))
        self.writers.append(w)
        return w

    def reader(self, name: str, idl_type: type, profile: str, depth: int | None = None):
        from cyclonedds.sub import DataReader

        r = DataReader(self.participant, self._topic(name, idl_type), _qos(profile, depth))
        self.readers.append(r)
        return r

    def announce_node(self, node_name: str, distro: str = "jazzy", namespace: str = "/") -> None:
        """Publish this participant's node on ``ros_discovery_info`` as rmw_dds_common does, so
        ``ros2 node list`` lists it and ``ros2 topic info -v`` names it: the participant's GID and
        its readers' and writers' GIDs (DDS GUIDs; Humble's GID type is 24 bytes, zero-padded).
        Reliable, transient local, depth 1, no ``rt/`` prefix; published again after each change."""
        from cyclonedds.pub import DataWriter

        from aes_planner.ros2 import idl

        humble = distro == "humble"
        gid_t = idl.GidHumble if humble else idl.Gid
        info_t = idl.ParticipantEntitiesInfoHumble if humble else idl.ParticipantEntitiesInfo
        node_t = idl.NodeEntitiesInfoHumble if humble else idl.NodeEntitiesInfo
        size = 24 if humble else 16

        def gid(entity):
            return gid_t(list(entity.get_guid().bytes) + [0] * (size - 16))

        if self._graph_writer is None:
            self._graph_writer = DataWriter(
                self.participant, self._topic("ros_discovery_info", info_t, raw=True), _qos("latched")
            )
        node = node_t(namespace, node_name, [gid(r) for r in self.readers], [gid(w) for w in self.writers])
        self._graph_writer.write(info_t(gid(self.participant), [node]))

    def close(self) -> None:
        """Delete the participant (and its readers and writers); safe to call twice."""
        p, self.participant = getattr(self, "participant", None), None
        if p is not None:
            p.__del__()  # cyclonedds deletes an entity (and its readers and writers) in __del__; idempotent
        self._topics = {}
        self.writers, self.readers, self._graph_writer = [], [], None


def take_checked(reader, idl_type: type, max_n: int = 64) -> tuple[list, list[str]]:
    """Take up to ``max_n`` samples, deserialising each on its own: (samples, errors). A sample
    that does not deserialise as ``idl_type`` (another writer's malformed CDR) becomes an error
    string instead of failing the whole batch."""
    from cyclonedds._clayer import ddspy_take
    from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState

    ret = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, max_n)
    if isinstance(ret, int):
        raise DDSException(ret, "while taking samples")
    samples, errors = [], []
    for data, info in ret:
        if not info.valid_data:  # a writer went away: no data
            continue
        try:
            samples.append(idl_type.deserialize(data))
        except Exception as exc:  # the CDR machinery raises struct.error, IndexError, UnicodeDecodeError...
            errors.append(f"undecodable {idl_type.__idl_typename__}: {type(exc).__name__}: {exc}"[:200])
    return samples, errors
