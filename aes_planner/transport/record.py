"""Recordings (MCAP) and the live Foxglove view, both fed from a bus.

* :class:`Recorder` writes an MCAP file (the ``mcap`` package): our own channels (``/topic``,
  message encoding ``aes-planner``: the exact bytes that went over the bus) beside the
  Foxglove-typed channels of :mod:`aes_planner.transport.foxglove_view`, which the Foxglove app
  opens with no plugin. ``Recorder(path).attach(bus)`` records every topic of a bus::

      with Recorder(run_dir / "recording.mcap") as rec:
          rec.attach(bus)            # or rec.attach(bus, ["camera/frame", "planner/**"])
          ...                        # run the nodes; close() finishes the file

* :func:`read_recording` yields our messages back (topic, bytes, log time); :func:`replay`
  publishes them on a bus at the recorded pace (``rate`` times faster), optionally looping.
* :class:`FoxgloveLive` serves the same channels over the Foxglove WebSocket protocol
  (foxglove-sdk, loopback by default): ``FoxgloveLive(port=8765).attach(bus)``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from aes_planner.errors import AesPlannerError
from aes_planner.messages import MESSAGE_TYPES, MessageError, decode, peek_header
from aes_planner.transport.bus import Bus, RawSample, Subscription, validate_topic
from aes_planner.transport.foxglove_view import (
    OUR_ENCODING,
    _ViewState,
    foxglove_view,
    our_schema,
    stamp_ns,
    view_channels,
)

__all__ = [
    "Recorder",
    "FoxgloveLive",
    "RecordingError",
    "read_recording",
    "replay",
    "recording_metadata",
    "recording_summary",
]

log = logging.getLogger(__name__)


#: The longest pause :func:`replay` makes between two messages (a recording's clock may jump).
MAX_REPLAY_GAP_S = 10.0


class RecordingError(AesPlannerError):
    """A recording cannot be written or read (path, format)."""


class _Sink:
    """Shared by the MCAP recorder and the live server: our channel + the Foxglove view."""

    def __init__(self, viz: bool = True) -> None:
        self.viz = viz
        self._lock = threading.Lock()
        self._subs: list[Subscription] = []
        self._state = _ViewState()
        self.written = 0
        self.rejected = 0
        self.closed = False

    def attach(self, bus: Bus, patterns: Iterable[str] = ("**",), depth: int = 1000) -> _Sink:
        """Write every message the bus carries on topics matching ``patterns``."""
        for p in patterns:
            self._subs.append(bus.subscribe_raw(p, depth=depth, callback=self._on_sample))
        return self

    def _on_sample(self, sample: RawSample) -> None:
        self.write_raw(sample.topic, sample.data, int(sample.recv_time_s * 1e9))

    def write(self, topic: str, msg, log_time_ns: int | None = None) -> None:
        self.write_raw(topic, msg.encode(), log_time_ns)

    def write_raw(self, topic: str, data: bytes, log_time_ns: int | None = None) -> None:
        """Write our bytes (checked to decode; rejected and counted otherwise) and their view.

        ``log_time_ns`` is when the message was received (now when None); the message's own stamp
        goes with it as its publish time (:func:`~aes_planner.transport.foxglove_view.stamp_ns`)."""
        t = time.time_ns() if log_time_ns is None else int(log_time_ns)
        try:
            msg = decode(data)
        except MessageError as exc:
            self.rejected += 1
            log.warning("not recording a malformed message on %s: %s", topic, exc)
            return
        cls = type(msg)
        stamp = stamp_ns(msg, t)
        with self._lock:
            if self.closed:
                return
            self._write("/" + topic, our_schema(cls.TYPE_NAME, cls.SCHEMA_VERSION), OUR_ENCODING, data, t, stamp, topic)
            if self.viz:
                try:
                    views = foxglove_view(topic, msg, t, state=self._state)
                except Exception:  # a view is a nicety; never lose the recording for it
                    log.exception("could not build the Foxglove view of %s", topic)
                    views = []
                for v in views:
                    schema = (v.schema_name, v.schema_encoding, v.schema_data)
                    self._write(v.topic, schema, v.message_encoding, v.data, t, stamp, topic)
            self.written += 1

    def _write(
        self, topic: str, schema: tuple[str, str, bytes], encoding: str, data: bytes, t: int, stamp: int, source: str
    ) -> None:
        """One message on channel ``topic``: received at ``t``, stamped ``stamp`` (ns), shown
        for bus topic ``source``."""
        raise NotImplementedError

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs.clear()
        with self._lock:
            if not self.closed:
                self.closed = True
                self._close()

    def _close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Recorder(_Sink):
    """An MCAP file of our channels and their Foxglove view; see the module doc."""

    def __init__(self, path: str | Path, *, viz: bool = True, overwrite: bool = False) -> None:
        super().__init__(viz)
        from mcap.writer import Writer

        self.path = Path(path)
        if self.path.exists() and (self.path.is_dir() or not overwrite):
            raise RecordingError(f"{self.path} exists; choose another file name (or remove it)")
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise RecordingError(f"cannot write {self.path}: {exc.strerror}") from None
        self._writer = Writer(self._file)
        self._writer.start(profile="", library="aes-planner")
        self._schemas: dict[tuple, int] = {}
        self._channels: dict[tuple, int] = {}
        self._sequence = 0

    def _write(self, topic, schema, encoding, data, t, stamp, source) -> None:
        # log_time = when it was recorded (replay paces on it, across every clock the nodes use);
        # publish_time = the message's own stamp (capture or planning time), as the MCAP spec has it
        sid = self._schemas.get(schema)
        if sid is None:
            sid = self._schemas[schema] = self._writer.register_schema(schema[0], schema[1], schema[2])
        key = (topic, sid, encoding)
        cid = self._channels.get(key)
        if cid is None:
            cid = self._channels[key] = self._writer.register_channel(topic, encoding, sid)
        self._sequence += 1
        self._writer.add_message(cid, log_time=t, data=data, publish_time=stamp, sequence=self._sequence)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (``name``: string -> string), e.g. which clock the run used."""
        with self._lock:
            if not self.closed:
                self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def _close(self) -> None:
        self._writer.finish()
        self._file.close()


class FoxgloveLive(_Sink):
    """The same channels served live over the Foxglove WebSocket protocol (foxglove-sdk).

    ``host`` defaults to loopback; anything else must be asked for explicitly. Clients must ask
    for the WebSocket subprotocol ``foxglove.sdk.v1`` (the Foxglove app does; the older
    ``foxglove.websocket.v1`` is refused with HTTP 400).

    Nothing is lost to a client that joins early or late:

    * :meth:`advertise` (the topics a graph's nodes declare, ``declared`` at construction) creates
      a topic's channels before its first message, so a client connected before the graph starts
      subscribes in time for the first message, and never to a channel the server does not know;
    * a latched topic's last message (on each of its channels) goes to a client when it
      subscribes, as the bus gives it to a late subscriber.

    Every message carries the message's own stamp as its log time, not the time it arrived.
    """

    def __init__(
        self,
        port: int = 8765,
        host: str = "127.0.0.1",
        *,
        viz: bool = True,
        name: str = "aes-planner",
        declared: Iterable[tuple[str, type, bool]] = (),
    ):
        super().__init__(viz)
        import foxglove

        self._foxglove = foxglove
        self.context = foxglove.Context()
        self._channels: dict[str, object] = {}
        self._by_id: dict[int, str] = {}  # channel id -> channel topic
        self._latched_topics: set[str] = set()
        self._latched_lock = threading.Lock()
        self._latched_last: dict[str, dict[str, tuple[bytes, int]]] = {}  # channel -> bus topic -> last
        self._subscribed: set[tuple[int, int]] = set()  # (client id, channel id)
        try:
            self.server = foxglove.start_server(
                name=name, host=host, port=port, context=self.context, server_listener=_Listener(self)
            )
        except Exception as exc:  # the SDK raises its own error types for a busy port
            raise RecordingError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.port = self.server.port
        for topic, msg_type, latched in declared:
            self.advertise(topic, msg_type, latched)

    def advertise(self, topic: str, msg_type: type, latched: bool = False) -> None:
        """Create ``topic``'s channels (ours and its view's) now, before its first message;
        ``latched``: a client subscribing later gets the last message."""
        topic = validate_topic(topic)
        with self._lock:
            if latched:
                self._latched_topics.add(topic)
            self._channel("/" + topic, our_schema(msg_type.TYPE_NAME, msg_type.SCHEMA_VERSION), OUR_ENCODING)
            if self.viz:
                for ch_topic, schema, encoding in view_channels(topic, msg_type):
                    self._channel(ch_topic, schema, encoding)

    def advertise_bus_topics(self, bus: Bus) -> int:
        """:meth:`advertise` every topic ``bus`` knows a publisher of (its type and latching);
        returns how many (topics of unknown types are left to their first message)."""
        n = 0
        for info in bus.topics():
            cls = MESSAGE_TYPES.get(info.type_name)
            if cls is not None and info.publishers:
                self.advertise(info.topic, cls, info.latched)
                n += 1
        return n

    def _channel(self, topic: str, schema: tuple[str, str, bytes], encoding: str):
        # a topic's channel is created once, by its first advertisement or message (one schema)
        ch = self._channels.get(topic)
        if ch is None:
            fs = self._foxglove.Schema(name=schema[0], encoding=schema[1], data=schema[2])
            ch = self._foxglove.Channel(topic, schema=fs, message_encoding=encoding, context=self.context)
            self._channels[topic] = ch
            self._by_id[ch.id()] = topic
        return ch

    def _write(self, topic, schema, encoding, data, t, stamp, source) -> None:
        ch = self._channel(topic, schema, encoding)
        if ch.schema_name() != schema[0]:
            log.debug("not showing a %s on %s, a channel of %s", schema[0], topic, ch.schema_name())
            return
        if source in self._latched_topics:
            with self._latched_lock:
                self._latched_last.setdefault(topic, {})[source] = (data, stamp)
        ch.log(data, log_time=stamp)

    @property
    def subscriptions(self) -> int:
        """How many (client, channel) subscriptions the server has now."""
        return len(self._subscribed)

    def _on_subscribe(self, client_id: int, channel_id: int) -> None:
        """Give a client that just subscribed the last message of each latched topic shown on the
        channel (only to that client)."""
        self._subscribed.add((client_id, channel_id))
        topic = self._by_id.get(channel_id)
        with self._latched_lock:
            last = list(self._latched_last.get(topic, {}).values())
        ch = self._channels.get(topic)
        for data, stamp in last:
            ch.log(data, log_time=stamp, sink_id=client_id)

    def _close(self) -> None:
        self.server.stop()


class _Listener:
    """The foxglove-sdk server listener: called in the server's thread on each subscription."""

    def __init__(self, live: FoxgloveLive) -> None:
        self._live = live

    def on_subscribe(self, client, channel) -> None:
        try:
            self._live._on_subscribe(client.id, channel.id)
        except Exception:  # never let the server's thread see an exception
            log.exception("sending the latched messages of %s failed", channel.topic)

    def on_unsubscribe(self, client, channel) -> None:
        self._live._subscribed.discard((client.id, channel.id))


def _open_reader(path: str | Path):
    from mcap.reader import make_reader

    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording")
    f = open(path, "rb")
    try:
        reader = make_reader(f)
        reader.get_header()
    except Exception as exc:
        f.close()
        raise RecordingError(f"{path} is not an MCAP file ({exc})") from None
    return f, reader


def read_recording(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, bytes, int]]:
    """Our messages in a recording, in log-time order: ``(topic, bytes, log_time_ns)``.

    Foxglove-view channels are skipped; ``topics`` (without the leading ``/``) filters."""
    wanted = None if topics is None else {"/" + t.lstrip("/") for t in topics}
    f, reader = _open_reader(path)
    try:
        try:
            reader.get_summary()
        except Exception:  # no footer: cut short (a killed recorder); read what was written
            yield from _read_cut_short(f, path, wanted)
            return
        try:
            for _schema, channel, message in reader.iter_messages(topics=list(wanted) if wanted else None):
                if channel.message_encoding != OUR_ENCODING:
                    continue
                yield channel.topic.lstrip("/"), message.data, message.log_time
        except RecordingError:
            raise
        except Exception as exc:  # a truncated or corrupt file (the mcap reader's own errors)
            raise RecordingError(f"{path}: unreadable MCAP data ({type(exc).__name__}: {exc})") from None
    finally:
        f.close()


def _read_cut_short(f, path, wanted: set[str] | None) -> Iterator[tuple[str, bytes, int]]:
    """Our messages of a recording without its summary, in file order, up to where it breaks off."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    f.seek(0)
    channels: dict[int, Channel] = {}
    n = 0
    try:
        for record in StreamReader(f, skip_magic=False).records:
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                ch = channels.get(record.channel_id)
                if ch is None or ch.message_encoding != OUR_ENCODING or (wanted and ch.topic not in wanted):
                    continue
                n += 1
                yield ch.topic.lstrip("/"), record.data, record.log_time
    except Exception as exc:  # where the file breaks off (the mcap reader's own errors)
        if n == 0:
            raise RecordingError(
                f"{path}: unreadable MCAP data, cut short before any message ({type(exc).__name__})"
            ) from None
        log.warning(
            "%s: the recording breaks off after %d messages (cut short: was the recorder killed?); read up to there",
            path,
            n,
        )
    else:
        log.warning("%s: the recording has no summary (cut short?); read all %d messages in file order", path, n)


def recording_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """``{name: {key: value}}`` of a recording's MCAP metadata records (``run``: its clock...)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror}") from None


def recording_summary(path: str | Path) -> dict[str, dict]:
    """``{topic: {"type": name, "count": n}}`` of our channels in a recording."""
    out: dict[str, dict] = {}
    for topic, data, _t in read_recording(path):
        try:
            name = peek_header(data).type_name
        except MessageError:
            name = "?"
        entry = out.setdefault(topic, {"type": name, "count": 0})
        entry["count"] += 1
    return out


def replay(
    path: str | Path,
    bus: Bus,
    *,
    rate: float = 1.0,
    loop: bool = False,
    topics: Iterable[str] | None = None,
    stop: threading.Event | None = None,
) -> int:
    """Publish a recording's messages on ``bus`` with their recorded spacing divided by ``rate``
    (``rate <= 0``: as fast as possible; a gap longer than :data:`MAX_REPLAY_GAP_S` after the
    division is shortened to it, with a warning). Returns the number published. Messages that do
    not decode, or whose type differs from the topic's first message, are skipped, counted and
    logged (the bus's subscribers would reject them anyway)."""
    import math

    if not isinstance(rate, (int, float)) or not math.isfinite(rate) or 0 < rate < 1e-3:
        raise RecordingError(f"rate must be 0 (as fast as possible) or a finite number >= 0.001, got {rate!r}")
    stop = stop or threading.Event()
    publishers: dict[str, object] = {}
    count = 0
    while not stop.is_set():
        start_wall = time.monotonic()
        first_t = None
        n_this_pass = 0
        for topic, data, t in read_recording(path, topics):
            if stop.is_set():
                break
            try:
                cls = type(decode(data))  # the whole message, not just its header
            except MessageError as exc:
                log.warning("skipping a malformed message on %s: %s", topic, exc)
                continue
            pub = publishers.get(topic)
            if pub is not None and pub.msg_type is not cls:
                log.warning("skipping a %s on %s, a topic of %s", cls.__name__, topic, pub.msg_type.__name__)
                continue
            if first_t is None:
                first_t = t
            if rate > 0:
                due = start_wall + (t - first_t) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > MAX_REPLAY_GAP_S:
                    log.warning("a gap of %.3g s in the recording is shortened to %g s", delay, MAX_REPLAY_GAP_S)
                    start_wall -= delay - MAX_REPLAY_GAP_S
                    delay = MAX_REPLAY_GAP_S
                if delay > 0 and stop.wait(delay):
                    break
            if pub is None:
                pub = publishers[topic] = bus.publisher(topic, cls)
            pub.publish_raw(data)
            count += 1
            n_this_pass += 1
        if not loop or n_this_pass == 0:
            break
    return count
