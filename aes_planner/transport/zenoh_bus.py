"""``ZenohBus``: the bus across processes and machines over Zenoh (peer mode).

Key space (``P`` = the configured prefix, ``aes`` by default)::

    P/<topic>                         data samples (attachment: "<publisher id>:<sequence>")
    P/@latched/<topic>                queryable of each latched publisher: its last sample
    P/@srv/<topic>                    queryable of a request/reply server
    P/@meta/pub/<Type>/<L>/<id>.g<N>/<topic>   liveliness token per publisher (L = 1 if latched;
                                      N: the bus's session generation, see Liveness)
    P/@meta/sub/<id>/<topic>          liveliness token per subscription
    P/@hub/<id>                       heartbeat of a hub (a bus listening on a fixed port)

``@`` chunks are verbatim in Zenoh: ``P/**`` (echo, record) sees data only.

Latched topics: a subscription watches the liveliness tokens of latched publishers of its topic
(with history, so ones that exist already count); for each one that appears it asks
``P/@latched/<topic>`` for the last sample, and asks again (0.05 s, doubling to 1 s) until that
publisher answers or its token goes: a query sent before the queryable's route reaches the asking
session goes unanswered (a fresh peer session answered 3 of 10 such queries), so the catch-up is
a mechanism, not a matter of timing. A latched publisher answers every query, with an empty
sample when it has published nothing yet ("reached, nothing to catch up"). A sample put between
the answer and the new subscription's route would be lost to it, so a latched publisher also
watches the subscription tokens of its topic and puts its last sample again when one appears
(the token follows the subscriber's declaration, so the route exists by then). A sample is
delivered once: the subscription keeps the last sequence seen per publisher id and drops repeats.
A publisher that restarts has a new id.

Liveness: a bus listening on a fixed port (a graph's hub) puts a heartbeat on ``P/@hub/<id>``
every :data:`HEARTBEAT_PERIOD_S`; a bus that connects to one watches them (in a ring buffer Zenoh
fills on its own threads, so a busy interpreter does not look like a dead link). After
:data:`STALL_AFTER_S` without one, the bus reports the session stalled (a warning,
``session_ok: 0`` and ``session_losses`` in :meth:`ZenohBus.health`, which the node runner adds to
every node's diagnostics) and says when heartbeats are back and after how long. A link that is
only stalled is left to Zenoh, which delivers what was queued once it resumes. A session that is
wedged (closed under the bus, its link to the hub gone and not connected again within
:data:`REOPEN_AFTER_S`, or silent past its lease) is replaced: a new session, every publisher,
subscription, server and token declared again (publisher ids and sequences kept, so nothing is
delivered twice) and the latched topics caught up; retried, backing off to
:data:`MAX_REOPEN_PERIOD_S`, until heartbeats come back.

Threads: Zenoh calls our callbacks on its own threads; they only append bytes to a bounded
per-subscription inbox (keep-last: the oldest are dropped and counted) and wake the dispatcher
thread, which decodes, queues or calls the user's callback, runs catch-up queries and request
handlers. Nothing blocks or calls Zenoh inside a Zenoh callback. ``close()`` undeclares
everything and closes the session, so processes never hang at exit (an ``atexit`` hook closes
buses left open).
"""

from __future__ import annotations

import atexit
import heapq
import itertools
import json
import logging
import os
import threading
import time
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
from aes_planner.transport.config import DEFAULT_PORT, MAX_DOMAIN, ZENOH_ROUTER_PORT, ZenohConfig

__all__ = ["ZenohBus", "port_holder", "zenoh_config"]

log = logging.getLogger(__name__)

_OPEN_BUSES: weakref.WeakSet = weakref.WeakSet()
# A hub's lease (Zenoh's default is 10 s): how long a link may stay silent before the session is
# closed and what it had queued is dropped. The link between two machines' hubs is the one a
# network cut hits; with 30 s, 100 % of a 25 Hz reliable stream crossed a 15 s cut (with 10 s,
# everything from the cut's start was lost). A machine that vanishes is noticed 30 s late.
HUB_LEASE_MS = 30_000
#: A hub's heartbeat period, and how long a connected bus waits without one before it reports the
#: session stalled, then opens a new one (see the module docstring, Liveness).
HEARTBEAT_PERIOD_S = 0.2
STALL_AFTER_S = 1.5
REOPEN_AFTER_S = 3.0
PEER_LEASE_MS = 10_000  # Zenoh's default link lease, which node processes and tools keep
MAX_REOPEN_PERIOD_S = 8.0
#: A latched catch-up query is repeated after this long, doubling up to the second figure.
CATCH_UP_RETRY_S = (0.05, 1.0)


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


def port_holder(port: int) -> str:
    """``"pid N (command line)"`` of the process listening on TCP ``port`` on this machine, or ``""``
    when that cannot be told (another user's process, no /proc): read from /proc/net/tcp{,6} and
    the processes' open sockets, as ``ss -ltnp`` does."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as f:
                next(f, None)
                for line in f:
                    cols = line.split()
                    if len(cols) > 9 and cols[3] == "0A" and int(cols[1].rpartition(":")[2], 16) == port:
                        inodes.add(f"socket:[{cols[9]}]")
        except (OSError, ValueError):
            continue
    if not inodes:
        return ""

    def holds(pid: str) -> bool:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:  # gone, or another user's
            return False
        for fd in fds:
            try:
                if os.readlink(f"/proc/{pid}/fd/{fd}") in inodes:
                    return True
            except OSError:  # closed meanwhile
                continue
        return False

    for pid in sorted((p for p in os.listdir("/proc") if p.isdigit()), key=int):
        if holds(pid):
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmd = f.read().replace(b"\0", b" ").decode("utf-8", "replace")
            except OSError:
                cmd = "?"
            return f"pid {pid} ({' '.join(cmd.split())[:160]})"
    return ""


def _taken_hint(endpoints: list[str]) -> str:
    ports = {_split_endpoint(ep)[2] for ep in endpoints}
    holders = [h for h in (port_holder(p) for p in sorted(ports)) if h]
    who = f"held by {', '.join(holders)}" if holders else "another program holds the port"
    who += " (the hub of another graph: an `aes-planner launch --processes` in this domain?"
    if ZENOH_ROUTER_PORT in ports:
        who += (
            f" {ZENOH_ROUTER_PORT} is also the port of a Zenoh router: zenohd, ROS 2's rmw_zenohd "
            "(`ros2 run rmw_zenoh_cpp rmw_zenohd`) or a zenoh-bridge"
        )
    domains = [DEFAULT_PORT - p for p in ports if 0 <= DEFAULT_PORT - p <= MAX_DOMAIN]
    where = f"domain {domains[0]}'s hub port" if domains else "that port"
    return (
        f"{who}); stop it, or run this graph in another domain with --domain N (or AES_PLANNER_DOMAIN=N: "
        f"{where} is taken; hub port = {DEFAULT_PORT} - N), or choose a port with --listen tcp/HOST:PORT"
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
        self.latched_pubs: set[str] = set()  # tokens (<id>.g<N>) of the latched publishers alive


def _zenoh_timeout(err) -> bool:
    """Whether a reply error is zenoh's own timeout: when a query matched a server that did not
    answer in time, zenoh ends it with the error text ``"Timeout"``, encoded ``zenoh/string`` by
    the asking session or ``zenoh/bytes`` when a router's timeout fires first (both seen on
    loopback). Our servers' errors are other texts ("handler failed: ...", "dropped: ...")."""
    return err.payload.to_bytes() == b"Timeout"


def _pub_token(token_key: str, prefix: str) -> str:
    """``<id>.g<N>`` of a publisher token's key (``P/@meta/pub/<Type>/<L>/<id>.g<N>/<topic>``): the
    publisher's id and the generation of the session that declared it."""
    parts = token_key[len(prefix) + len("/@meta/pub/") :].split("/")
    return parts[2] if len(parts) > 2 else ""


def _split_attachment(att: bytes) -> tuple[str, int | None]:
    pub_id, _, seq_text = att.decode("ascii", "replace").rpartition(":")
    try:
        return pub_id, int(seq_text)
    except ValueError:
        return pub_id, None


class ZenohBus(Bus):
    """One Zenoh session; one per process is plenty (nodes of a process may share it)."""

    def __init__(self, config: ZenohConfig | None = None) -> None:
        super().__init__()
        self.config = config or ZenohConfig()
        self.prefix = self.config.prefix
        self.session = self._open_session()
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
        # liveness (module docstring): a hub beats, a bus that connects to one watches
        self.generation = 0  # bumped by each new session
        self.session_losses = 0
        self.session_ok = True
        self.last_outage_s = 0.0
        self.heartbeats_heard = 0
        self._beats = any(_split_endpoint(ep)[2] != 0 for ep in self.config.listen)
        self._watches = bool(self.config.connect)
        self._own: list = []  # the heartbeat's publisher and subscriber of the current session
        self._hub_zids: set[str] = set()  # Zenoh ids of the hubs heard
        self._reopen_blocked_until = 0.0  # simulate_session_loss
        self._heard = None  # RingChannel handler of the hubs' heartbeats
        self._declare_liveness()
        self._catch_ups: list = []  # heap of (due_s, n, inbox, pub_id, attempt)
        self._catch_up_wake = threading.Condition()
        self._thread = threading.Thread(target=self._dispatch, name="aes-zenoh-dispatch", daemon=True)
        self._thread.start()
        self._catch_up_thread = threading.Thread(target=self._catch_up_loop, name="aes-zenoh-catch-up", daemon=True)
        self._catch_up_thread.start()
        self._watch_thread = None
        if self._beats or self._watches:
            self._watch_thread = threading.Thread(target=self._watch, name="aes-zenoh-watch", daemon=True)
            self._watch_thread.start()
        _OPEN_BUSES.add(self)

    def _open_session(self):
        try:
            return zenoh.open(zenoh_config(self.config))
        except zenoh.ZError as exc:
            taken = [ep for ep in self.config.listen if _port_taken(ep)]
            if taken:
                raise TransportError(f"cannot listen on {', '.join(taken)}: {_taken_hint(taken)}") from None
            raise TransportError(
                f"could not open a Zenoh session ({_first_line(exc)}); check the listen/connect endpoints"
            ) from None

    def _key(self, topic: str, space: str = "") -> str:
        return f"{self.prefix}/{space}/{topic}" if space else f"{self.prefix}/{topic}"

    def health(self) -> dict[str, int]:
        """The session's state for diagnostics: ``session_ok`` (0 while stalled or lost),
        ``session_losses`` (so far) and ``last_outage_ms`` (the last loss, from the last heartbeat
        heard to the first one heard again)."""
        return {
            "session_ok": int(self.session_ok),
            "session_losses": self.session_losses,
            "last_outage_ms": int(round(self.last_outage_s * 1000)),
        }

    # -- declarations ----------------------------------------------------------------------------

    def _declare_publisher(self, pub: Publisher) -> None:
        congestion = zenoh.CongestionControl.BLOCK if pub.reliable else zenoh.CongestionControl.DROP
        z_pub = self.session.declare_publisher(self._key(pub.topic), congestion_control=congestion)
        handles: list = [z_pub]
        pub_id = getattr(pub, "_zenoh_id", None) or f"{self.id}-{next(self._counter)}"
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
            f"{pub.msg_type.TYPE_NAME}/{int(pub.latched)}/{pub_id}.g{self.generation}/{pub.topic}",
            "@meta/pub",
        )
        handles.append(self.session.liveliness().declare_token(token_key))
        with self._lock:
            self._pubs[id(pub)] = pub
            self._handles[id(pub)] = handles
            self._seq.setdefault(id(pub), 0)
        pub._z_pub = z_pub  # type: ignore[attr-defined]

    def _declare_subscription(self, sub: Subscription) -> None:
        # The inbox is registered before anything is declared: a sample can arrive as soon as the
        # subscriber is (a latched publisher repeats its last one when the token appears), and
        # the dispatcher looks the inbox up by id — one it could not find was marked clean and its
        # sample stayed queued, undelivered, until the next one came (a late joiner got nothing).
        with self._lock:
            inbox = self._inboxes.get(id(sub)) or _Inbox(sub)
            self._inboxes[id(sub)] = inbox
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
                    watch, lambda s, inbox=inbox: self._latched_token(inbox, s), history=True
                )
            )
        if not sub.raw:
            handles.append(
                self.session.liveliness().declare_token(
                    self._key(f"{self.id}-{id(sub)}.g{self.generation}/{sub.topic}", "@meta/sub")
                )
            )
        with self._lock:
            self._subs[id(sub)] = sub
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
            z_pub = pub._z_pub  # type: ignore[attr-defined]
        try:
            z_pub.put(data, attachment=att)
        except zenoh.ZError as exc:
            # the session is gone under us (its link lost for good): the liveness watch replaces it;
            # the node goes on, and a latched value is kept for the catch-up
            log.log(logging.WARNING if self.session_ok else logging.DEBUG, "%s: not published: %s", pub.topic, exc)

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
        """Every query gets an answer: the last sample, or an empty one ("reached, nothing yet")."""
        try:
            last = self._latched.get(id(pub)) or (b"", f"{pub._zenoh_id}:0".encode())  # type: ignore[attr-defined]
            query.reply(self._key(pub.topic, "@latched"), last[0], attachment=last[1])
        except zenoh.ZError as exc:
            log.debug("%s: answering a catch-up failed: %s", pub.topic, exc)
        finally:
            query.drop()

    # -- receiving -------------------------------------------------------------------------------

    def _enqueue(self, inbox: _Inbox, topic: str, data: bytes, att: bytes) -> None:
        sub = inbox.sub
        if not sub._admits(data):
            return
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

    def _latched_token(self, inbox: _Inbox, sample) -> None:
        """Zenoh's thread: a latched publisher of the subscription's topic appeared (ask it for its
        last sample) or went (stop asking)."""
        token = _pub_token(str(sample.key_expr), self.prefix)
        with self._catch_up_wake:
            if sample.kind == zenoh.SampleKind.PUT:
                inbox.latched_pubs.add(token)
                self._schedule_catch_up(inbox, token, 0, 0.0)
            else:  # (a publisher's token of an older session may go after its new one came)
                inbox.latched_pubs.discard(token)

    def _schedule_catch_up(self, inbox: _Inbox, token: str, attempt: int, delay_s: float) -> None:
        with self._catch_up_wake:
            heapq.heappush(self._catch_ups, (time.monotonic() + delay_s, next(self._counter), inbox, token, attempt))
            self._catch_up_wake.notify()

    def _catch_up_loop(self) -> None:
        """Its own thread, so that a query never holds up deliveries: ask, and ask again until the
        publisher answered or its token went (module docstring)."""
        while True:
            with self._catch_up_wake:
                while not self._stop and (not self._catch_ups or self._catch_ups[0][0] > time.monotonic()):
                    wait = self._catch_ups[0][0] - time.monotonic() if self._catch_ups else None
                    self._catch_up_wake.wait(wait)
                if self._stop:
                    return
                _, _, inbox, token, attempt = heapq.heappop(self._catch_ups)
                if inbox.sub.closed or token not in inbox.latched_pubs:
                    continue
            try:
                answered = self._catch_up(inbox)
            except Exception:
                log.exception("latched catch-up failed")
                answered = set()
            pub_id = token.partition(".g")[0]
            if pub_id not in answered:
                lo, hi = CATCH_UP_RETRY_S
                self._schedule_catch_up(inbox, token, attempt + 1, min(hi, lo * 2**attempt))
                if attempt == 10:
                    log.info(
                        "%s: latched publisher %s has not answered after 10 queries; still asking",
                        inbox.sub.topic,
                        pub_id,
                    )

    def _catch_up(self, inbox: _Inbox) -> set[str]:
        """Ask the topic's latched publishers for their last samples; the ids that answered."""
        sub = inbox.sub
        answered: set[str] = set()
        prefix_len = len(self.prefix) + len("/@latched/")
        try:
            replies = self.session.get(
                self._key(sub.topic, "@latched"),
                timeout=min(1.0, self.config.open_timeout_s),
                consolidation=zenoh.ConsolidationMode.NONE,  # every publisher's answer, not the newest alone
            )
            for reply in replies:
                if reply.ok is None:
                    continue
                s = reply.ok
                att = s.attachment.to_bytes() if s.attachment is not None else b""
                pub_id, _ = _split_attachment(att)
                answered.add(pub_id)
                data = s.payload.to_bytes()
                if data:
                    self._enqueue(inbox, str(s.key_expr)[prefix_len:], data, att)
        except zenoh.ZError as exc:
            log.debug("%s: latched catch-up failed: %s", sub.topic, exc)
        return answered

    def _deliver_inbox(self, inbox: _Inbox) -> None:
        sub = inbox.sub
        while True:
            with self._work:
                if not inbox.items:
                    return
                topic, data, att = inbox.items.popleft()
            if att:
                pub_id, seq = _split_attachment(att)
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

    # -- liveness (module docstring) ----------------------------------------------------------------

    def _declare_liveness(self) -> None:
        """The heartbeat's publisher (a hub) and subscriber (a bus that connects) on the session."""
        self._own = []
        if self._beats:
            self._own.append(
                self.session.declare_publisher(
                    self._key(self.id, "@hub"), congestion_control=zenoh.CongestionControl.DROP, express=True
                )
            )
        if self._watches:
            sub = self.session.declare_subscriber(self._key("*", "@hub"), zenoh.handlers.RingChannel(16))
            self._own.append(sub)
            self._heard = sub.handler

    def _heartbeat_heard(self) -> bool:
        """Whether a hub's heartbeat (not our own) arrived since the last call; notes the hubs' ids."""
        heard = False
        handler = self._heard
        while handler is not None:
            try:
                sample = handler.try_recv()
            except zenoh.ZError:
                return heard
            if sample is None:
                return heard
            if not str(sample.key_expr).endswith("/" + self.id):
                heard = True
                self.heartbeats_heard += 1
                self._hub_zids.add(sample.payload.to_bytes().decode("ascii", "replace"))

    def _hub_linked(self) -> bool:
        """Whether the session still has a link to a hub whose heartbeat it heard."""
        try:
            info = self.session.info
            zids = {str(z) for z in info.routers_zid()} | {str(z) for z in info.peers_zid()}
        except Exception:  # a closed session
            return False
        return bool(zids & self._hub_zids)

    def _wedged(self, silent_s: float) -> bool:
        """Whether a session whose hub is silent for ``silent_s`` needs a new session: when it is
        closed, when its link to the hub is gone and Zenoh has not connected again (it retries
        every second), or when the link stays silent past its lease (Zenoh should have closed it).
        A link that is only stalled is left to Zenoh: it delivers what was queued when it
        resumes, which a new session would lose."""
        if self.session.is_closed():
            return True
        if silent_s > REOPEN_AFTER_S and not self._hub_linked():
            return True
        lease_s = (HUB_LEASE_MS if self.config.mode == "router" else PEER_LEASE_MS) / 1000
        return silent_s > lease_s + REOPEN_AFTER_S

    def _watch(self) -> None:
        """Beat (a hub) and watch the hubs' beats (a bus that connects): report a stalled session
        after STALL_AFTER_S, open a new one when it is wedged (:meth:`_wedged`), say when it is back."""
        next_beat = last_tick = time.monotonic()
        last_heard = None  # when a heartbeat was last heard (None: none yet)
        lost_at = None
        next_reopen = 0.0
        reopen_period = 1.0
        reopened = 0
        while not self._stop:
            time.sleep(0.05)
            now = time.monotonic()
            if self._beats and now >= next_beat:
                next_beat = now + HEARTBEAT_PERIOD_S
                try:
                    self._own[0].put(str(self.session.zid()).encode())
                except (zenoh.ZError, IndexError):
                    pass
            if not self._watches:
                continue
            starved = now - last_tick > STALL_AFTER_S / 2  # this thread ran late: judge nothing on it
            last_tick = now
            if self._heartbeat_heard():
                if lost_at is not None:
                    self.last_outage_s = now - lost_at
                    log.warning(
                        "bus session is back after %.1f s (%s)",
                        now - lost_at,
                        f"{reopened} new session(s)" if reopened else "the same session: nothing queued was lost",
                    )
                    lost_at = None
                    reopened = 0
                    reopen_period = 1.0
                self.session_ok = True
                last_heard = now
                continue
            if last_heard is None:
                continue
            if starved:
                last_heard = max(last_heard, now - STALL_AFTER_S / 2)
            if lost_at is None and now - last_heard > STALL_AFTER_S:
                lost_at = last_heard
                self.session_ok = False
                self.session_losses += 1
                log.warning(
                    "bus session stalled: no heartbeat from the graph's hub (%s) for %.1f s",
                    ", ".join(self.config.connect),
                    now - last_heard,
                )
            if now < self._reopen_blocked_until:  # simulate_session_loss: the network is still away
                continue
            if lost_at is not None and now >= next_reopen and self._wedged(now - lost_at):
                self._reopen()
                reopened += 1
                next_reopen = time.monotonic() + reopen_period
                reopen_period = min(MAX_REOPEN_PERIOD_S, reopen_period * 2)

    def _reopen(self) -> None:
        """A new session with everything declared again; the old one is closed in the background
        (closing may wait on a stalled link)."""
        try:
            session = self._open_session()
        except TransportError as exc:
            log.warning("bus session: could not open a new one (%s); trying again", exc)
            return
        old = self.session
        with self._lock:
            self.generation += 1
            self.session = session
            entities = list(self._pubs.values()) + list(self._subs.values()) + list(self._servers.values())
            self._handles.clear()
        self._declare_liveness()
        for e in entities:
            if e.closed:
                continue
            try:
                if isinstance(e, Publisher):
                    self._declare_publisher(e)
                elif isinstance(e, Subscription):
                    self._declare_subscription(e)
                else:
                    self._declare_server(e)
            except zenoh.ZError as exc:
                log.warning("bus session: declaring %s again failed: %s", e.topic, exc)
        log.warning(
            "bus session: opened a new one (generation %d), %d declarations renewed", self.generation, len(entities)
        )
        threading.Thread(target=_close_quietly, args=(old,), name="aes-zenoh-close-old", daemon=True).start()

    def simulate_session_loss(self, duration_s: float = 0.0) -> None:
        """Testing hook (tests, ``aes-planner bench transport``): close the current session under the
        bus, as a link lost for good leaves it (nothing delivered, no error), and let no new one
        open for ``duration_s`` (the network is away that long); the liveness watch has to notice
        the loss and recover."""
        self._reopen_blocked_until = time.monotonic() + duration_s
        _close_quietly(self.session)

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
        with self._catch_up_wake:
            self._catch_up_wake.notify_all()
        for t in (self._thread, self._catch_up_thread, self._watch_thread):
            if t is not None and threading.current_thread() is not t:
                t.join(timeout=5.0)
        for h in self._own:
            try:
                h.undeclare()
            except Exception as exc:
                log.debug("undeclare failed: %s", exc)
        try:
            self.session.close()
        except zenoh.ZError as exc:
            log.debug("session close: %s", exc)
        _OPEN_BUSES.discard(self)
        super().close()


def _close_quietly(session) -> None:
    try:
        session.close()
    except Exception as exc:  # already closed, or its links gone
        log.debug("closing a session: %s", exc)


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
