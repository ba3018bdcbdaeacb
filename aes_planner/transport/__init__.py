"""Topics between nodes: one interface, an in-process backend and a Zenoh backend.

The contract (every backend)
============================

Topic names follow ROS 2 rules (:func:`validate_topic`): ``planner/suggestion``; a leading
``/`` is accepted and dropped. Payloads are :mod:`aes_planner.messages`, encoded on publish and
decoded (validated) on receipt: a subscriber only ever sees valid messages of its type, and
counts what it rejected.

Publish::

    pub = bus.publisher("planner/suggestion", ViewSuggestion, latched=True)   # reliable by default
    pub.publish(msg)                      # TransportError on a wrong type; MessageError if over the cap
    frames = bus.publisher("camera/frame", PosedFrame, reliable=False)          # may drop to the latest
    bus.publish("gimbal/command", cmd)    # shorthand: a kept, reliable, non-latched publisher

``latched=True``: a subscriber that joins later still gets the last message (per publisher),
also across processes; a message published before any subscriber matched is not lost.

Subscribe — pollable keep-last queue (for ``step(inputs, now) -> outputs`` node loops)::

    sub = bus.subscribe("camera/frame", PosedFrame, depth=1)   # keep the last 1
    wait_any([sub, other_sub], timeout_s=0.1)                 # block until any has something
    frames = sub.take()       # all queued, oldest first;  sub.latest() newest (queue cleared); sub.poll()
    sub.received, sub.dropped, sub.rejected, sub.last_error   # counters (ints) and the last reason

or with a callback (in-process: called in the publisher's thread; Zenoh: in the bus's dispatcher
thread, one at a time; an exception is logged and counted in ``callback_errors``)::

    bus.subscribe("planner/suggestion", ViewSuggestion, callback=on_suggestion)

``bus.subscribe_raw("**")`` gives undecoded :class:`RawSample` (topic, bytes, receive time) of
every matching topic: for recorders and ``echo``.

Request/reply::

    server = bus.serve("planner/request", PlannerRequest, ViewSuggestion, handler=fn)  # fn(req) -> reply
    server = bus.serve("planner/request", PlannerRequest, ViewSuggestion)              # or poll:
    for pending in server.take(): pending.reply(make_reply(pending.msg))               #  from the loop
    reply = bus.request("planner/request", PlannerRequest("suggest"), ViewSuggestion, timeout_s=2.0)

``request`` raises :class:`RequestTimeout` (nobody answered in time) or :class:`RemoteError`
(the server refused: undecodable request, handler error). A pollable server queues at most
``depth`` requests (the oldest are answered "busy").

Lifetime: ``bus.close()`` (or ``with``) undeclares everything; ``sub.close()``, ``pub.close()``,
``server.close()`` undeclare one. ``bus.topics()`` lists :class:`TopicInfo`.

Backends
========

* :class:`InProcessBus` — one process; share the instance between nodes.
* :class:`ZenohBus` (``aes_planner.transport.zenoh_bus``) — across processes and machines,
  peer mode, loopback and no multicast scouting unless configured (:class:`ZenohConfig`).

:func:`open_bus` builds either from a :class:`BusConfig` (the ``bus:`` block of a launch file).
"""

from __future__ import annotations

from aes_planner.transport.bus import (
    Bus,
    PendingRequest,
    Publisher,
    RawSample,
    RemoteError,
    RequestTimeout,
    Server,
    Subscription,
    TopicError,
    TopicInfo,
    TransportError,
    topic_matches,
    validate_pattern,
    validate_topic,
    wait_any,
)
from aes_planner.transport.config import BusConfig, ZenohConfig
from aes_planner.transport.inprocess import InProcessBus

__all__ = [
    "Bus",
    "BusConfig",
    "InProcessBus",
    "PendingRequest",
    "Publisher",
    "RawSample",
    "RemoteError",
    "RequestTimeout",
    "Server",
    "Subscription",
    "TopicError",
    "TopicInfo",
    "TransportError",
    "ZenohConfig",
    "open_bus",
    "topic_matches",
    "validate_pattern",
    "validate_topic",
    "wait_any",
]


def open_bus(config: BusConfig | None = None) -> Bus:
    """A new bus for ``config`` (default: in-process); the Zenoh backend is imported only when
    asked for."""
    config = config or BusConfig()
    if config.backend == "zenoh":
        from aes_planner.transport.zenoh_bus import ZenohBus

        return ZenohBus(config.zenoh)
    return InProcessBus()
