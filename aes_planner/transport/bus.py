"""The bus interface every backend implements, and the backend-independent parts: topic names,
subscriptions with keep-last queues and rejection counters, pending requests."""

from __future__ import annotations

import logging
import re
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from aes_planner.errors import AesPlannerError
from aes_planner.messages import Message, MessageError, check_envelope, decode, peek_header

__all__ = [
    "Bus",
    "Publisher",
    "Subscription",
    "Server",
    "PendingRequest",
    "RawSample",
    "TopicInfo",
    "TransportError",
    "TopicError",
    "RequestTimeout",
    "RemoteError",
    "validate_topic",
    "validate_pattern",
    "topic_matches",
    "wait_any",
]

log = logging.getLogger(__name__)

MAX_TOPIC_LEN = 255
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class TransportError(AesPlannerError):
    """The bus could not do what was asked (closed bus, unreachable peer, wrong type)."""


class TopicError(TransportError, ValueError):
    """A topic name breaks the ROS 2 naming rules, or a topic is used with two types."""


class RequestTimeout(TransportError):
    """No reply arrived in time: is the serving node running and reachable?"""


class RemoteError(TransportError):
    """The server answered a request with an error."""


def validate_topic(name: str) -> str:
    """Check a topic name by the ROS 2 rules and return it without a leading ``/``.

    Tokens separated by ``/``: letters, digits and underscores, not starting with a digit; no
    empty tokens, no ``__``, no trailing ``/``; at most 255 characters. ``~`` and ``{}``
    substitutions are not supported (name the topic in full).
    """
    if not isinstance(name, str) or not name:
        raise TopicError(f"topic name must be a non-empty string, got {name!r}")
    if len(name) > MAX_TOPIC_LEN:
        raise TopicError(f"topic name is {len(name)} characters; the limit is {MAX_TOPIC_LEN}")
    bare = name[1:] if name.startswith("/") else name
    if not bare:
        raise TopicError("topic name '/' has no tokens; use a name like 'planner/suggestion'")
    if "__" in bare:
        raise TopicError(f"topic name {name!r} contains '__', which ROS 2 names reserve")
    for token in bare.split("/"):
        if not token:
            raise TopicError(f"topic name {name!r} has an empty token (a '//' or a trailing '/')")
        if not _TOKEN.match(token):
            raise TopicError(
                f"topic name {name!r}: token {token!r} must be letters, digits and '_' and not start with a digit"
            )
    return bare


#: Most ``**`` tokens in a pattern (each multiplies the cost of matching a topic against it).
MAX_DOUBLE_WILDCARDS = 4


def validate_pattern(pattern: str) -> str:
    """A topic name in which a token may be ``*`` (one token) or ``**`` (any number of tokens),
    returned in Zenoh's canonical form (``**/**`` -> ``**``, ``**/*`` -> ``*/**``: the same set of
    topics, which Zenoh otherwise refuses); at most :data:`MAX_DOUBLE_WILDCARDS` ``**``."""
    if pattern in ("", "/", "**", "/**"):
        return "**"
    bare = pattern[1:] if pattern.startswith("/") else pattern
    plain = "/".join("x" if t in ("*", "**") else t for t in bare.split("/"))
    validate_topic(plain)
    tokens = bare.split("/")
    changed = True
    while changed:
        changed = False
        for i in range(len(tokens) - 1):
            if tokens[i] == "**" and tokens[i + 1] in ("*", "**"):
                tokens[i : i + 2] = ["**"] if tokens[i + 1] == "**" else ["*", "**"]
                changed = True
                break
    if tokens.count("**") > MAX_DOUBLE_WILDCARDS:
        raise TopicError(
            f"pattern {pattern[:80]!r}: {tokens.count('**')} '**' tokens; use at most {MAX_DOUBLE_WILDCARDS}"
        )
    return "/".join(tokens)


def topic_matches(pattern: str, topic: str) -> bool:
    """Whether ``topic`` matches a :func:`validate_pattern` pattern."""

    def match(p: list[str], t: list[str]) -> bool:
        if not p:
            return not t
        if p[0] == "**":
            return any(match(p[1:], t[i:]) for i in range(len(t) + 1))
        return bool(t) and (p[0] == "*" or p[0] == t[0]) and match(p[1:], t[1:])

    return match(pattern.split("/"), topic.split("/"))


@dataclass(frozen=True)
class RawSample:
    """Bytes as they came off the bus (for recorders and ``echo``): not yet decoded."""

    topic: str
    data: bytes
    recv_time_s: float


@dataclass
class TopicInfo:
    """What a bus knows about a topic."""

    topic: str
    type_name: str = ""
    publishers: int = 0
    subscribers: int = 0
    latched: bool = False


class Subscription:
    """Messages of one topic (or raw samples of a pattern), kept last ``depth``.

    Pollable: :meth:`take` (all queued, oldest first), :meth:`latest` (the newest, queue
    cleared), :meth:`poll` (the oldest), :meth:`wait`. With a ``callback``, each message goes to
    it instead of the queue. Counters: ``received`` (arrived and accepted), ``dropped`` (of those,
    pushed out of a full queue before the consumer took them: this queue's, or a backend's inbox
    of not yet decoded samples), ``rejected`` (undecodable, wrong type, oversized: never
    delivered), ``callback_errors``; ``last_error`` says why the last one was rejected. So
    ``received - dropped`` reached the consumer and ``received + rejected`` arrived.
    """

    def __init__(
        self,
        bus: Bus,
        topic: str,
        msg_type: type[Message] | None,
        depth: int,
        callback: Callable | None,
        max_bytes: int | None,
        raw: bool = False,
    ) -> None:
        if not isinstance(depth, int) or isinstance(depth, bool) or depth < 1:
            raise TransportError(f"subscription depth must be an integer >= 1, got {depth!r}")
        self.bus = bus
        self.topic = topic
        self.msg_type = msg_type
        self.depth = depth
        self.callback = callback
        self.max_bytes = max_bytes
        self.raw = raw
        self.received = 0
        self.dropped = 0
        self.rejected = 0
        self.callback_errors = 0
        self.last_error = ""
        self.closed = False
        self.catch_up = True  # receive latched values published before it joined
        self._queue: deque = deque(maxlen=depth)
        self._lock = threading.Lock()

    # -- delivery (called by backends) ---------------------------------------------------------

    def _accept(self, topic: str, data: bytes):
        """Decode ``data``; None when rejected (counted)."""
        if self.raw:
            try:
                peek_header(data)
            except MessageError as exc:
                self._reject(str(exc))
                return None
            if self.max_bytes is not None and len(data) > self.max_bytes:
                self._reject(f"{len(data)} bytes exceed the cap of {self.max_bytes}")
                return None
            return RawSample(topic, bytes(data), time.time())
        try:
            return decode(data, self.msg_type, self.max_bytes)
        except MessageError as exc:
            self._reject(str(exc))
            return None

    def _admits(self, data: bytes) -> bool:
        """The O(1) check of a sample before a backend queues it undecoded (header, type, size,
        declared length: :func:`~aes_planner.messages.codec.check_envelope`); False when it is
        rejected (counted), so a sample that cannot decode never pushes an accepted one out."""
        try:
            if self.raw:
                peek_header(data)
            else:
                check_envelope(data, self.msg_type, self.max_bytes)
        except MessageError as exc:
            self._reject(str(exc))
            return False
        return True

    def _reject(self, reason: str) -> None:
        with self._lock:
            self.rejected += 1
            self.last_error = reason
        level = logging.WARNING if self.rejected <= 3 else logging.DEBUG
        log.log(level, "%s: rejected a message (%d so far): %s", self.topic, self.rejected, reason)

    def _deliver(self, topic: str, data: bytes, direct: bool = True) -> bool:
        """Decode and queue (or hand to the callback when ``direct``). Returns True if accepted."""
        if self.closed:
            return False
        item = self._accept(topic, data)
        if item is None:
            return False
        self._push(item, direct)
        return True

    def _dropped_unseen(self) -> None:
        """Count a sample a backend's inbox pushed out before it was decoded."""
        with self._lock:
            self.received += 1
            self.dropped += 1

    def _push(self, item, direct: bool = True) -> None:
        with self._lock:
            self.received += 1
            if self.callback is None or not direct:
                if len(self._queue) == self.depth:
                    self.dropped += 1
                self._queue.append(item)
        if self.callback is not None and direct:
            self._call(item)
        self.bus._notify()

    def _call(self, item) -> None:
        try:
            self.callback(item)
        except Exception:  # a subscriber's bug must not kill the bus thread or the publisher
            self.callback_errors += 1
            log.exception("%s: subscription callback raised", self.topic)

    # -- consumer side -------------------------------------------------------------------------

    @property
    def pending(self) -> int:
        return len(self._queue)

    def take(self, max_n: int | None = None) -> list:
        """Queued messages, oldest first (at most ``max_n``); they leave the queue."""
        with self._lock:
            n = len(self._queue) if max_n is None else min(max_n, len(self._queue))
            return [self._queue.popleft() for _ in range(n)]

    def poll(self):
        """The oldest queued message, or None."""
        with self._lock:
            return self._queue.popleft() if self._queue else None

    def latest(self):
        """The newest queued message (the older ones are discarded), or None."""
        with self._lock:
            if not self._queue:
                return None
            item = self._queue[-1]
            self._queue.clear()
            return item

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until something is queued (True) or ``timeout_s`` passes (False)."""
        return wait_any([self], timeout_s)

    def stats(self) -> dict[str, int]:
        return {
            "received": self.received,
            "dropped": self.dropped,
            "rejected": self.rejected,
            "callback_errors": self.callback_errors,
        }

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.bus._unsubscribe(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Publisher:
    """Publishes messages of one type on one topic; see :meth:`Bus.publisher`."""

    def __init__(self, bus: Bus, topic: str, msg_type: type[Message], latched: bool, reliable: bool) -> None:
        self.bus = bus
        self.topic = topic
        self.msg_type = msg_type
        self.latched = latched
        self.reliable = reliable
        self.published = 0
        self.closed = False

    def publish(self, msg: Message) -> None:
        if not isinstance(msg, self.msg_type):
            raise TransportError(f"{self.topic} carries {self.msg_type.TYPE_NAME}, got {type(msg).__name__}")
        self.publish_raw(msg.encode())

    def publish_raw(self, data: bytes) -> None:
        """Send already-encoded bytes (replay); receivers validate them like any other."""
        if self.closed:
            raise TransportError(f"publisher of {self.topic} is closed")
        self.bus._send(self, bytes(data))
        self.published += 1

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.bus._unpublish(self)


class PendingRequest:
    """A request waiting for its reply (see :meth:`Server.take`)."""

    def __init__(self, msg: Message, respond: Callable[[bytes | None, str], None]) -> None:
        self.msg = msg
        self._respond = respond
        self.done = False

    def reply(self, msg: Message) -> None:
        if not self.done:
            self.done = True
            self._respond(msg.encode(), "")

    def reply_error(self, text: str) -> None:
        if not self.done:
            self.done = True
            self._respond(None, text)


class Server:
    """Answers requests on a topic. With a ``handler(request) -> reply``, the bus calls it;
    without, :meth:`take` returns :class:`PendingRequest` objects to answer from a node loop.
    ``rejected`` counts requests that did not decode."""

    def __init__(
        self,
        bus: Bus,
        topic: str,
        request_type: type[Message],
        reply_type: type[Message],
        handler: Callable[[Message], Message] | None,
        depth: int,
    ) -> None:
        self.bus = bus
        self.topic = topic
        self.request_type = request_type
        self.reply_type = reply_type
        self.handler = handler
        self.rejected = 0
        self.served = 0
        self.last_error = ""
        self.closed = False
        self._queue: deque[PendingRequest] = deque()
        self._depth = depth
        self._lock = threading.Lock()

    def _handle(self, data: bytes, respond: Callable[[bytes | None, str], None]) -> None:
        """Decode a request and either answer it with the handler or queue it."""
        try:
            req = decode(data, self.request_type)
        except MessageError as exc:
            self.rejected += 1
            self.last_error = str(exc)
            log.warning("%s: rejected a request: %s", self.topic, exc)
            respond(None, f"rejected: {exc}")
            return
        pending = PendingRequest(req, respond)
        if self.handler is None:
            with self._lock:
                if len(self._queue) >= self._depth:
                    old = self._queue.popleft()
                    old.reply_error("dropped: the server is busy")
                self._queue.append(pending)
            self.bus._notify()
            return
        try:
            reply = self.handler(req)
            if not isinstance(reply, self.reply_type):
                raise TransportError(f"handler returned {type(reply).__name__}, expected {self.reply_type.TYPE_NAME}")
            pending.reply(reply)
        except Exception as exc:
            log.exception("%s: request handler raised", self.topic)
            pending.reply_error(f"handler failed: {exc}")
        self.served += 1

    @property
    def pending(self) -> int:
        return len(self._queue)

    def take(self) -> list[PendingRequest]:
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        self.served += len(out)
        return out

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            for p in self.take():
                p.reply_error("server closed")
            self.bus._unserve(self)


def wait_any(items: Iterable[Subscription | Server], timeout_s: float | None = None) -> bool:
    """Block until any of the subscriptions/servers (all of one bus) has something pending."""
    items = list(items)
    if not items:
        if timeout_s:
            time.sleep(timeout_s)
        return False
    cond = items[0].bus._cond
    with cond:
        return cond.wait_for(lambda: any(i.pending for i in items), timeout_s)


class Bus(ABC):
    """Topics between nodes; see :mod:`aes_planner.transport` for the contract."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._publishers: dict[str, Publisher] = {}  # publish() convenience cache
        self.closed = False

    # -- the API -------------------------------------------------------------------------------

    def publisher(
        self, topic: str, msg_type: type[Message], *, latched: bool = False, reliable: bool = True
    ) -> Publisher:
        """Declare a publisher. ``latched``: a subscriber that joins later still gets the last
        message. ``reliable=False``: may drop under load (frames); True blocks rather than drops."""
        self._check_open()
        topic = validate_topic(topic)
        if not (isinstance(msg_type, type) and issubclass(msg_type, Message)):
            raise TransportError(f"msg_type must be a message class, got {msg_type!r}")
        pub = Publisher(self, topic, msg_type, latched, reliable)
        self._declare_publisher(pub)
        return pub

    def publish(self, topic: str, msg: Message) -> None:
        """Publish on ``topic`` with a publisher the bus keeps (reliable, not latched)."""
        pub = self._publishers.get(topic)
        if pub is None or pub.closed:
            pub = self._publishers[topic] = self.publisher(topic, type(msg))
        pub.publish(msg)

    def subscribe(
        self,
        topic: str,
        msg_type: type[Message] | None = None,
        *,
        depth: int = 10,
        callback: Callable[[Message], None] | None = None,
        max_bytes: int | None = None,
    ) -> Subscription:
        """Subscribe; ``msg_type`` None accepts any registered type. See :class:`Subscription`."""
        self._check_open()
        sub = Subscription(self, validate_topic(topic), msg_type, depth, callback, max_bytes)
        self._declare_subscription(sub)
        return sub

    def subscribe_raw(
        self,
        pattern: str = "**",
        *,
        depth: int = 100,
        callback: Callable[[RawSample], None] | None = None,
        catch_up: bool = True,
    ) -> Subscription:
        """Undecoded :class:`RawSample` of every topic matching ``pattern`` (``*``/``**`` tokens).
        ``catch_up=False``: not the latched values published before (for measuring rates)."""
        self._check_open()
        sub = Subscription(self, validate_pattern(pattern), None, depth, callback, None, raw=True)
        sub.catch_up = catch_up
        self._declare_subscription(sub)
        return sub

    def serve(
        self,
        topic: str,
        request_type: type[Message],
        reply_type: type[Message],
        handler: Callable[[Message], Message] | None = None,
        *,
        depth: int = 10,
    ) -> Server:
        """Answer requests on ``topic``; see :class:`Server`."""
        self._check_open()
        server = Server(self, validate_topic(topic), request_type, reply_type, handler, depth)
        self._declare_server(server)
        return server

    @abstractmethod
    def request(self, topic: str, msg: Message, reply_type: type[Message], timeout_s: float = 2.0) -> Message:
        """Send ``msg`` to the server of ``topic`` and return its reply; :class:`RequestTimeout`
        when none answers in time, :class:`RemoteError` when it answers with an error."""

    def health(self) -> dict[str, int]:
        """The backend's session state for diagnostics (the Zenoh bus: ``session_ok``,
        ``session_losses``, ``last_outage_ms``); nothing for a bus that cannot lose one."""
        return {}

    @abstractmethod
    def topics(self) -> list[TopicInfo]:
        """The topics this bus knows of (declared publishers and subscribers)."""

    def close(self) -> None:
        """Undeclare everything and release the backend; safe to call twice."""
        self.closed = True
        with self._cond:
            self._cond.notify_all()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- for backends ----------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self.closed:
            raise TransportError("the bus is closed")

    def _notify(self) -> None:
        with self._cond:
            self._cond.notify_all()

    @abstractmethod
    def _declare_publisher(self, pub: Publisher) -> None: ...

    @abstractmethod
    def _declare_subscription(self, sub: Subscription) -> None: ...

    @abstractmethod
    def _declare_server(self, server: Server) -> None: ...

    @abstractmethod
    def _send(self, pub: Publisher, data: bytes) -> None: ...

    @abstractmethod
    def _unpublish(self, pub: Publisher) -> None: ...

    @abstractmethod
    def _unsubscribe(self, sub: Subscription) -> None: ...

    @abstractmethod
    def _unserve(self, server: Server) -> None: ...
