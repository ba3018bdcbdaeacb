"""``InProcessBus``: the bus within one process.

Every message is encoded on publish and decoded for each subscriber, exactly as over the wire:
subscribers never share (and cannot mutate) a publisher's arrays, and malformed bytes are
rejected and counted the same way. Callbacks run synchronously in the publisher's thread;
request handlers run in the requester's thread.
"""

from __future__ import annotations

import threading

from aes_planner.messages import Message, MessageError, decode
from aes_planner.transport.bus import (
    Bus,
    Publisher,
    RemoteError,
    RequestTimeout,
    Server,
    Subscription,
    TopicError,
    TopicInfo,
    TransportError,
    topic_matches,
    validate_topic,
)

__all__ = ["InProcessBus"]


class InProcessBus(Bus):
    """All nodes of one process on one bus object (share the instance)."""

    def __init__(self) -> None:
        super().__init__()
        self._lock = threading.RLock()
        self._subs: list[Subscription] = []
        self._pubs: list[Publisher] = []
        self._servers: dict[str, Server] = {}
        self._latched: dict[str, bytes] = {}
        self._types: dict[str, str] = {}

    def _check_type(self, topic: str, msg_type: type[Message] | None) -> None:
        if msg_type is None:
            return
        known = self._types.setdefault(topic, msg_type.TYPE_NAME)
        if known != msg_type.TYPE_NAME:
            raise TopicError(f"topic {topic} carries {known}; cannot use it for {msg_type.TYPE_NAME}")

    def _declare_publisher(self, pub: Publisher) -> None:
        with self._lock:
            self._check_type(pub.topic, pub.msg_type)
            self._pubs.append(pub)

    def _declare_subscription(self, sub: Subscription) -> None:
        with self._lock:
            if not sub.raw:
                self._check_type(sub.topic, sub.msg_type)
            self._subs.append(sub)
            latched = [(t, d) for t, d in self._latched.items() if sub.catch_up and self._wants(sub, t)]
        for topic, data in latched:
            sub._deliver(topic, data)

    @staticmethod
    def _wants(sub: Subscription, topic: str) -> bool:
        return topic_matches(sub.topic, topic) if sub.raw else sub.topic == topic

    def _declare_server(self, server: Server) -> None:
        with self._lock:
            if server.topic in self._servers:
                raise TopicError(f"{server.topic} already has a server in this process")
            self._servers[server.topic] = server

    def _send(self, pub: Publisher, data: bytes) -> None:
        self._check_open()
        with self._lock:
            if pub.latched:
                self._latched[pub.topic] = data
            targets = [s for s in self._subs if self._wants(s, pub.topic)]
        for sub in targets:  # outside the lock: callbacks may publish
            sub._deliver(pub.topic, data)

    def _unpublish(self, pub: Publisher) -> None:
        with self._lock:
            if pub in self._pubs:
                self._pubs.remove(pub)

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)

    def _unserve(self, server: Server) -> None:
        with self._lock:
            if self._servers.get(server.topic) is server:
                del self._servers[server.topic]

    def request(self, topic: str, msg: Message, reply_type: type[Message], timeout_s: float = 2.0) -> Message:
        self._check_open()
        topic = validate_topic(topic)
        with self._lock:
            server = self._servers.get(topic)
        if server is None:
            raise RequestTimeout(f"no server answers on {topic}")
        return self.request_raw(server, msg.encode(), reply_type, timeout_s)

    def request_raw(self, server: Server, data: bytes, reply_type: type[Message], timeout_s: float) -> Message:
        done = threading.Event()
        result: list = []

        def respond(reply: bytes | None, error: str) -> None:
            result.append((reply, error))
            done.set()

        server._handle(data, respond)
        if not done.wait(timeout_s):
            raise RequestTimeout(f"{server.topic}: no reply within {timeout_s:g} s; is its node looping?")
        reply, error = result[0]
        if reply is None:
            raise RemoteError(f"{server.topic}: {error}")
        try:
            return decode(reply, reply_type)
        except MessageError as exc:
            raise TransportError(f"{server.topic}: bad reply: {exc}") from None

    def topics(self) -> list[TopicInfo]:
        with self._lock:
            infos: dict[str, TopicInfo] = {}
            for p in self._pubs:
                info = infos.setdefault(p.topic, TopicInfo(p.topic, p.msg_type.TYPE_NAME))
                info.publishers += 1
                info.latched = info.latched or p.latched
            for s in self._subs:
                if s.raw:
                    continue
                info = infos.setdefault(s.topic, TopicInfo(s.topic, self._types.get(s.topic, "")))
                info.subscribers += 1
            return sorted(infos.values(), key=lambda i: i.topic)

    def close(self) -> None:
        with self._lock:
            subs, self._subs = self._subs, []
            servers, self._servers = list(self._servers.values()), {}
            self._pubs.clear()
        for s in subs:
            s.closed = True
        for server in servers:
            server.closed = True
            for p in server.take():
                p.reply_error("bus closed")
        super().close()
