"""``ZenohBus``: the bus across processes and machines over Zenoh (peer mode).

Key space (``P`` = the configured prefix, ``aes`` by default)::

    P/<topic>                         data samples (attachment: "<publisher id>:<sequence>")
    P/@latched/<topic>                queryable of each latched publisher: its last sample
    P/@srv/<topic>                    queryable of a request/reply server
    P/@meta/pub/<Type>/<L>/<id>/<topic>   liveliness token per publisher (L = 1 if latched)
    P/@meta/sub/<id>/<topic>          liveliness token per subscription

``@`` chunks are verbatim in Zenoh: ``P/**`` (echo, record) sees data only.

Latched topics: a subscription watches the liveliness tokens of latched publishers of its topic
(with history, so ones that exist already count); each time one appears it asks
``P/@latched/<topic>`` for the last sample. That query can be answered before the new
subscription's route reaches the publisher, and a sample put in between would be lost to it, so a
latched publisher also watches the subscription tokens of its topic and puts its last sample again
when one appears (the token follows the subscriber's declaration, so the route exists by then). A
sample is delivered once: the subscription keeps the last sequence seen per publisher id and drops
repeats. A publisher that restarts has a new id.

Threads: Zenoh calls our callbacks on its own threads; they only append bytes to a bounded
per-subscription inbox (keep-last: the oldest are dropped and counted) and wake the dispatcher
thread, which decodes, queues or calls the user's callback, runs catch-up queries and request
handlers. Nothing blocks or calls Zenoh inside a Zenoh callback. ``close()`` undeclares
everything and closes the session, so processes never hang at exit (an ``atexit`` hook closes
buses left open).
"""

from __future__ import annotations

import atexit
import itertools
import json
import logging
import os
import threading
import uuid
import weakref
from collections import deque

import zenoh

from aes_planner.messages import Message, MessageError, decode, peek_header
from aes_planner.transport.bus import (
    Bus,
    Publisher,
    RemoteError,
    RequestTimeout,
    Server,
    Subscription,
    TopicInfo,
    TransportError,
    validate_topic,
)
from aes_planner.transport.config import DEFAULT_PORT, ZENOH_ROUTER_PORT, ZenohConfig

__all__ = ["ZenohBus", "zenoh_config"]

log = logging.getLogger(__name__)

_OPEN_BUSES: weakref.WeakSet = weakref.WeakSet()
# A hub's lease (Zenoh's default is 10 s): how long a link may stay silent before the session is
# closed and what it had queued is dropped. The link between two machines' hubs is the one a
# network cut hits; with 30 s, 100 % of a 25 Hz reliable stream crossed a 15 s cut (with 10 s,
# everything from the cut's start was lost). A machine that vanishes is noticed 30 s late.
HUB_LEASE_MS = 30_000


def zenoh_config(cfg: ZenohConfig) -> zenoh.Config:
    """The Zenoh session configuration for ``cfg``: peer mode (router for a graph's hub, see
    :class:`ZenohConfig`), explicit endpoints, no multicast scouting unless asked (gossip scouting
    over the connected peers stays on)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(cfg.mode))
    if cfg.mode == "router":  # a hub: the link between machines outlives short network cuts
        conf.insert_json5("transport/link/tx/lease", str(HUB_LEASE_MS))
    conf.insert_json5("connect/endpoints", json.dumps(list(cfg.connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(cfg.listen)))
    conf.insert_json5("scouting/multicast/enabled", "true" if cfg.multicast_scouting else "false")
    # Retry unreachable endpoints every 0.2-1 s (Zenoh's default backs off to 4 s): a peer that
    # starts late or restarts is picked up within a second.
    conf.insert_json5("connect/retry", '{"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}')
    return conf


def _split_endpoint(endpoint: str) -> tuple[str, str, int]:
    proto, _, rest = endpoint.partition("/")
    host, _, port = rest.rpartition(":")
    return proto, host.strip("[]"), int(port)


def _port_taken(endpoint: str) -> bool:
    """Whether another program already holds ``endpoint``'s TCP port (bind fails with EADDRINUSE)."""
    import errno
    import socket

    proto, host, port = _split_endpoint(endpoint)
    if proto != "tcp" or port == 0:
        return False
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Zenoh's listener: TIME_WAIT is no clash
        try:
            s.bind((host, port))
        except OSError as exc:
            return exc.errno == errno.EADDRINUSE
    return False


def _taken_hint(endpoints: list[str]) -> str:
    ports = {_split_endpoint(ep)[2] for ep in endpoints}
    who = "another program holds the port (another `aes-planner launch --processes`?"
    if ZENOH_ROUTER_PORT in ports:
        who += (
            f" {ZENOH_ROUTER_PORT} is also the port of a Zenoh router: zenohd, ROS 2's rmw_zenohd "
            "(`ros2 run rmw_zenoh_cpp rmw_zenohd`) or a zenoh-bridge"
        )
    return (
        f"{who}); stop it, or choose another port with --listen tcp/HOST:PORT "
        f"(the default is {DEFAULT_PORT}); `ss -ltnp` shows which process holds it"
    )


def _warn_router_port(cfg: ZenohConfig) -> None:
    for ep in cfg.listen:
        if _split_endpoint(ep)[2] == ZENOH_ROUTER_PORT:
            log.warning(
                "listening on %s: port %d is the default of zenohd and ROS 2's rmw_zenohd router, which will "
                "fail to start on this machine while this runs; the graph's default port is %d",
                ep,
                ZENOH_ROUTER_PORT,
                DEFAULT_PORT,
            )


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__


class _Inbox:
    """Bytes waiting for the dispatcher, bounded to the subscription's depth."""

    def __init__(self, sub: Subscription) -> None:
        self.sub = sub
        self.items: deque = deque()
        self.seen: dict[str, int] = {}  # publisher id -> last sequence delivered


def _zenoh_timeout(err) -> bool:
    """Whether a reply error is zenoh's own timeout: when a query matched a server that did not
    answer in time, zenoh ends it with the error text ``"Timeout"``, encoded ``zenoh/string`` by
    the asking session or ``zenoh/bytes`` when a router's timeout fires first (both seen on
    loopback). Our servers' errors are other texts ("handler failed: ...", "dropped: ...")."""
    return err.payload.to_bytes() == b"Timeout"


class ZenohBus(Bus):
    """One Zenoh session; one per process is plenty (nodes of a process may share it)."""

    def __init__(self, config: ZenohConfig | None = None) -> None:
        super().__init__()
        self.config = config or ZenohConfig()
        self.prefix = self.config.prefix
        try:
            self.session = zenoh.open(zenoh_config(self.config))
        except zenoh.ZError as exc:
            taken = [ep for ep in self.config.listen if _port_taken(ep)]
            if taken:
                raise TransportError(f"cannot listen on {', '.join(taken)}: {_taken_hint(taken)}") from None
            raise TransportError(
                f"could not open a Zenoh session ({_first_line(exc)}); check the listen/connect endpoints"
            ) from None
        _warn_router_port(self.config)
        self.id = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._lock = threading.RLock()
        self._work = threading.Condition()
        self._inboxes: dict[int, _Inbox] = {}
        self._dirty: set[int] = set()
        self._tasks: deque = deque()
        self._handles: dict[int, list] = {}  # id(entity) -> zenoh objects to undeclare
        self._pubs: dict[int, Publisher] = {}
        self._subs: dict[int, Subscription] = {}
        self._servers: dict[int, Server] = {}
        self._latched: dict[int, tuple[bytes, bytes]] = {}  # id(pub) -> (data, attachment)
        self._seq: dict[int, int] = {}
        self._stop = False
        self._counter = itertools.count(1)
        self._thread = threading.Thread(target=self._dispatch, name="aes-zenoh-dispatch", daemon=True)
        self._thread.start()
        _OPEN_BUSES.add(self)

    def _key(self, topic: str, space: str = "") -> str:
        return f"{self.prefix}/{space}/{topic}" if space else f"{self.prefix}/{topic}"

    # -- declarations ----------------------------------------------------------------------------

    def _declare_publisher(self, pub: Publisher) -> None:
        congestion = zenoh.CongestionControl.BLOCK if pub.reliable else zenoh.CongestionControl.DROP
        z_pub = self.session.declare_publisher(self._key(pub.topic), congestion_control=congestion)
        handles: list = [z_pub]
        pub_id = f"{self.id}-{next(self._counter)}"
        pub._zenoh_id = pub_id  # type: ignore[attr-defined]
        if pub.latched:
            handles.append(
                self.session.declare_queryable(
                    self._key(pub.topic, "@latched"), lambda q, p=pub: self._post(self._answer_latched, p, q)
                )
            )
            handles.append(  # a new subscription: put the last sample again (module docstring)
                self.session.liveliness().declare_subscriber(
                    self._key(f"*/{pub.topic}", "@meta/sub"),
                    lambda s, p=pub: self._post(self._repeat_latched, p) if s.kind == zenoh.SampleKind.PUT else None,
                )
            )
        token_key = self._key(
            f"{pub.msg_type.TYPE_NAME}/{int(pub.latched)}/{pub_id}/{pub.topic}",
            "@meta/pub",
        )
        handles.append(self.session.liveliness().declare_token(token_key))
        with self._lock:
            self._pubs[id(pub)] = pub
            self._handles[id(pub)] = handles
            self._seq[id(pub)] = 0
        pub._z_pub = z_pub  # type: ignore[attr-defined]

    def _declare_subscription(self, sub: Subscription) -> None:
        inbox = _Inbox(sub)
        key = self._key(sub.topic)
        prefix_len = len(self.prefix) + 1

        def on_sample(sample, inbox=inbox) -> None:  # Zenoh's thread: copy bytes, queue, return
            topic = str(sample.key_expr)[prefix_len:]
            att = sample.attachment.to_bytes() if sample.attachment is not None else b""
            self._enqueue(inbox, topic, sample.payload.to_bytes(), att)

        handles: list = [self.session.declare_subscriber(key, on_sample)]
        # Late joiners: ask each latched publisher of the topic (pattern) for its last sample.
        watch = self._key(f"*/1/*/{sub.topic}", "@meta/pub")
        if sub.catch_up:
            handles.append(
                self.session.liveliness().declare_subscriber(
                    watch,
                    lambda s, inbox=inbox: (
                        self._post(self._catch_up, inbox) if s.kind == zenoh.SampleKind.PUT else None
                    ),
                    history=True,
                )
            )
        if not sub.raw:
            handles.append(
                self.session.liveliness().declare_token(self._key(f"{self.id}-{id(sub)}/{sub.topic}", "@meta/sub"))
            )
        with self._lock:
            self._subs[id(sub)] = sub
            self._inboxes[id(sub)] = inbox
            self._handles[id(sub)] = handles

    def _declare_server(self, server: Server) -> None:
        def on_query(query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            self._post(self._serve_one, server, query, payload)

        q = self.session.declare_queryable(self._key(server.topic, "@srv"), on_query)
        with self._lock:
            self._servers[id(server)] = server
            self._handles[id(server)] = [q]

    def _undeclare(self, entity) -> None:
        with self._lock:
            handles = self._handles.pop(id(entity), [])
            self._pubs.pop(id(entity), None)
            self._subs.pop(id(entity), None)
            self._servers.pop(id(entity), None)
            self._inboxes.pop(id(entity), None)
            self._latched.pop(id(entity), None)
        for h in handles:
            try:
                h.undeclare()
            except Exception as exc:  # the session may already be closed
                log.debug("undeclare failed: %s", exc)

    _unpublish = _unsubscribe = _unserve = _undeclare

    # -- publishing ------------------------------------------------------------------------------

    def _send(self, pub: Publisher, data: bytes) -> None:
        self._check_open()
        with self._lock:
            seq = self._seq.get(id(pub), 0) + 1
            self._seq[id(pub)] = seq
            att = f"{pub._zenoh_id}:{seq}".encode()  # type: ignore[attr-defined]
            if pub.latched:
                self._latched[id(pub)] = (data, att)
        try:
            pub._z_pub.put(data, attachment=att)  # type: ignore[attr-defined]
        except zenoh.ZError as exc:
            raise TransportError(f"{pub.topic}: publish failed: {exc}") from None

    def _repeat_latched(self, pub: Publisher) -> None:
        with self._lock:
            last = self._latched.get(id(pub))
            z_pub = getattr(pub, "_z_pub", None)
        if last is None or z_pub is None:
            return
        try:
            z_pub.put(last[0], attachment=last[1])  # same sequence: subscribers that had it drop it
        except zenoh.ZError as exc:
            log.debug("%s: repeating the latched sample failed: %s", pub.topic, exc)

    def _answer_latched(self, pub: Publisher, query) -> None:
        try:
            last = self._latched.get(id(pub))
            if last is not None:
                query.reply(self._key(pub.topic, "@latched"), last[0], attachment=last[1])
        finally:
            query.drop()

    # -- receiving -------------------------------------------------------------------------------

    def _enqueue(self, inbox: _Inbox, topic: str, data: bytes, att: bytes) -> None:
        sub = inbox.sub
        with self._work:
            if len(inbox.items) >= sub.depth:
                inbox.items.popleft()
                sub._dropped_unseen()
            inbox.items.append((topic, data, att))
            self._dirty.add(id(sub))
            self._work.notify()

    def _post(self, fn, *args) -> None:
        with self._work:
            self._tasks.append((fn, args))
            self._work.notify()

    def _catch_up(self, inbox: _Inbox) -> None:
        sub = inbox.sub
        if sub.closed:
            return
        prefix_len = len(self.prefix) + len("/@latched/")
        try:
            replies = self.session.get(self._key(sub.topic, "@latched"), timeout=self.config.open_timeout_s)
            for reply in replies:
                if reply.ok is None:
                    continue
                s = reply.ok
                att = s.attachment.to_bytes() if s.attachment is not None else b""
                self._enqueue(inbox, str(s.key_expr)[prefix_len:], s.payload.to_bytes(), att)
        except zenoh.ZError as exc:
            log.debug("%s: latched catch-up failed: %s", sub.topic, exc)

    def _deliver_inbox(self, inbox: _Inbox) -> None:
        sub = inbox.sub
        while True:
            with self._work:
                if not inbox.items:
                    return
                topic, data, att = inbox.items.popleft()
            if att:
                pub_id, _, seq_text = att.decode("ascii", "replace").rpartition(":")
                try:
                    seq = int(seq_text)
                except ValueError:
                    seq = None
                if seq is not None and pub_id:
                    if seq <= inbox.seen.get(pub_id, 0):
                        continue  # already delivered (a latched catch-up of a sample we had)
                    inbox.seen[pub_id] = seq
                    if len(inbox.seen) > 1024:
                        inbox.seen.pop(next(iter(inbox.seen)))
            sub._deliver(topic, data)

    def _serve_one(self, server: Server, query, payload: bytes) -> None:
        key = self._key(server.topic, "@srv")

        def respond(reply: bytes | None, error: str) -> None:
            try:
                if reply is not None:
                    query.reply(key, reply)
                else:
                    query.reply_err(error.encode())
            except zenoh.ZError as exc:
                log.debug("%s: reply failed: %s", server.topic, exc)
            finally:
                query.drop()

        server._handle(payload, respond)

    def _dispatch(self) -> None:
        while True:
            with self._work:
                while not (self._stop or self._tasks or self._dirty):
                    self._work.wait()
                if self._stop:
                    return
                tasks = list(self._tasks)
                self._tasks.clear()
                dirty = [self._inboxes.get(i) for i in self._dirty]
                self._dirty.clear()
            for fn, args in tasks:
                try:
                    fn(*args)
                except Exception:
                    log.exception("zenoh bus task failed")
            for inbox in dirty:
                if inbox is not None:
                    try:
                        self._deliver_inbox(inbox)
                    except Exception:
                        log.exception("zenoh bus delivery failed")

    # -- request/reply, topics, close ---------------------------------------------------------

    def request(self, topic: str, msg: Message, reply_type: type[Message], timeout_s: float = 2.0) -> Message:
        self._check_open()
        topic = validate_topic(topic)
        try:
            replies = self.session.get(
                self._key(topic, "@srv"),
                payload=msg.encode(),
                timeout=timeout_s,
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            for reply in replies:
                if reply.ok is None:
                    if _zenoh_timeout(reply.err):  # a server matched but did not answer in time
                        break
                    raise RemoteError(f"{topic}: {reply.err.payload.to_bytes().decode('utf-8', 'replace')[:500]}")
                try:
                    return decode(reply.ok.payload.to_bytes(), reply_type)
                except MessageError as exc:
                    raise TransportError(f"{topic}: bad reply: {exc}") from None
        except zenoh.ZError as exc:
            raise TransportError(f"{topic}: request failed: {exc}") from None
        raise RequestTimeout(f"{topic}: no reply within {timeout_s:g} s; is the serving node running and reachable?")

    def topics(self, timeout_s: float = 1.0) -> list[TopicInfo]:
        """Topics with a live publisher or subscription anywhere on the network."""
        self._check_open()
        infos: dict[str, TopicInfo] = {}
        for space in ("pub", "sub"):
            for reply in self.session.liveliness().get(self._key("**", f"@meta/{space}"), timeout=timeout_s):
                if reply.ok is None:
                    continue
                parts = str(reply.ok.key_expr).split("/")[3:]  # after P/@meta/<space>
                if space == "pub" and len(parts) >= 4:
                    type_name, latched, topic = parts[0], parts[1] == "1", "/".join(parts[3:])
                    info = infos.setdefault(topic, TopicInfo(topic, type_name))
                    info.type_name = info.type_name or type_name
                    info.publishers += 1
                    info.latched = info.latched or latched
                elif space == "sub" and len(parts) >= 2:
                    topic = "/".join(parts[1:])
                    infos.setdefault(topic, TopicInfo(topic)).subscribers += 1
        return sorted(infos.values(), key=lambda i: i.topic)

    def close(self) -> None:
        if self.closed:
            return
        with self._lock:
            entities = list(self._pubs.values()) + list(self._subs.values()) + list(self._servers.values())
        for e in entities:
            e.closed = True
            self._undeclare(e)
        with self._work:
            self._stop = True
            self._work.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        try:
            self.session.close()
        except zenoh.ZError as exc:
            log.debug("session close: %s", exc)
        _OPEN_BUSES.discard(self)
        super().close()


def _close_all() -> None:
    for bus in list(_OPEN_BUSES):
        bus.close()


atexit.register(_close_all)


def header_type(data: bytes) -> str:
    """The type name in a message header, or ``"?"`` when the bytes are not a message."""
    try:
        return peek_header(data).type_name
    except MessageError:
        return "?"
