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
from aes_planner.messages import MessageError, decode, peek_header
from aes_planner.transport.bus import Bus, RawSample, Subscription
from aes_planner.transport.foxglove_view import OUR_ENCODING, _ViewState, foxglove_view, our_schema

__all__ = ["Recorder", "FoxgloveLive", "RecordingError", "read_recording", "replay", "recording_summary"]

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
        """Write our bytes (checked to decode; rejected and counted otherwise) and their view."""
        t = time.time_ns() if log_time_ns is None else int(log_time_ns)
        try:
            msg = decode(data)
        except MessageError as exc:
            self.rejected += 1
            log.warning("not recording a malformed message on %s: %s", topic, exc)
            return
        cls = type(msg)
        with self._lock:
            if self.closed:
                return
            self._write("/" + topic, our_schema(cls.TYPE_NAME, cls.SCHEMA_VERSION), OUR_ENCODING, data, t)
            if self.viz:
                try:
                    views = foxglove_view(topic, msg, t, state=self._state)
                except Exception:  # a view is a nicety; never lose the recording for it
                    log.exception("could not build the Foxglove view of %s", topic)
                    views = []
                for v in views:
                    self._write(
                        v.topic, (v.schema_name, v.schema_encoding, v.schema_data), v.message_encoding, v.data, t
                    )
            self.written += 1

    def _write(self, topic: str, schema: tuple[str, str, bytes], encoding: str, data: bytes, t: int) -> None:
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

    def _write(self, topic, schema, encoding, data, t) -> None:
        sid = self._schemas.get(schema)
        if sid is None:
            sid = self._schemas[schema] = self._writer.register_schema(schema[0], schema[1], schema[2])
        key = (topic, sid, encoding)
        cid = self._channels.get(key)
        if cid is None:
            cid = self._channels[key] = self._writer.register_channel(topic, encoding, sid)
        self._sequence += 1
        self._writer.add_message(cid, log_time=t, data=data, publish_time=t, sequence=self._sequence)

    def _close(self) -> None:
        self._writer.finish()
        self._file.close()


class FoxgloveLive(_Sink):
    """The same channels served live over the Foxglove WebSocket protocol (foxglove-sdk).

    ``host`` defaults to loopback; anything else must be asked for explicitly."""

    def __init__(self, port: int = 8765, host: str = "127.0.0.1", *, viz: bool = True, name: str = "aes-planner"):
        super().__init__(viz)
        import foxglove

        self._foxglove = foxglove
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except Exception as exc:  # the SDK raises its own error types for a busy port
            raise RecordingError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.port = self.server.port
        self._channels: dict[tuple, object] = {}

    def _write(self, topic, schema, encoding, data, t) -> None:
        key = (topic, schema[0], encoding)
        ch = self._channels.get(key)
        if ch is None:
            fs = self._foxglove.Schema(name=schema[0], encoding=schema[1], data=schema[2])
            ch = self._channels[key] = self._foxglove.Channel(
                topic, schema=fs, message_encoding=encoding, context=self.context
            )
        ch.log(data, log_time=t)

    def _close(self) -> None:
        self.server.stop()


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
