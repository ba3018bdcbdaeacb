"""The live Foxglove server at the protocol level, with a WebSocket client on loopback written from
the Foxglove WebSocket protocol (not foxglove-sdk's client code): channels advertised before their
first message, latched topics to late subscribers, stamps and frame ids, the subprotocol."""

from __future__ import annotations

import json
import struct
import threading

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from aes_planner.messages import Diagnostics, GimbalState, PosedFrame, ViewSuggestion, decode, encode
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import InProcessBus
from aes_planner.transport.record import FoxgloveLive
from tests.helpers import wait_for

SUBPROTOCOL = "foxglove.sdk.v1"
DECLARED = [
    ("camera/frame", PosedFrame, False),
    ("planner/suggestion", ViewSuggestion, True),
    ("planner/diagnostics", Diagnostics, False),
]


def protobuf_fields(data: bytes) -> dict[int, list]:
    """The top-level fields of a protobuf message (protobuf's wire format: varints and
    length-delimited fields; no fixed-width ones appear in what the tests read)."""

    def varint(pos: int) -> tuple[int, int]:
        shift = value = 0
        while True:
            b = data[pos]
            value |= (b & 0x7F) << shift
            pos, shift = pos + 1, shift + 7
            if not b & 0x80:
                return value, pos

    out: dict[int, list] = {}
    pos = 0
    while pos < len(data):
        key, pos = varint(pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = varint(pos)
        elif wire == 2:
            n, pos = varint(pos)
            value, pos = data[pos : pos + n], pos + n
        elif wire == 1:
            value, pos = data[pos : pos + 8], pos + 8
        else:
            assert wire == 5, f"wire type {wire}"
            value, pos = data[pos : pos + 4], pos + 4
        out.setdefault(number, []).append(value)
    return out


def stamp_of(fields: dict[int, list]) -> tuple[int, int]:
    """(sec, nsec) of field 1, a google.protobuf.Timestamp, in foxglove's CompressedImage and
    FrameTransform."""
    ts = protobuf_fields(fields[1][0])
    return ts.get(1, [0])[0], ts.get(2, [0])[0]


class Client:
    """A Foxglove WebSocket client in a thread: subscribes to every channel as soon as it is
    advertised and keeps what arrives, per topic, as (log time ns, payload)."""

    def __init__(self, port: int, topics: set[str] | None = None) -> None:
        self._connection = connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=5)
        self.ws = self._connection.__enter__()
        self.topics = topics
        self.channels: dict[str, dict] = {}
        self.subscribed: dict[int, str] = {}  # subscription id -> topic
        self.got: dict[str, list[tuple[int, bytes]]] = {}
        self.status: list[dict] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.ws.recv(timeout=0.1)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(msg, str):
                body = json.loads(msg)
                if body["op"] == "advertise":
                    subs = []
                    for ch in body["channels"]:
                        self.channels[ch["topic"]] = ch
                        if self.topics is None or ch["topic"] in self.topics:
                            sub_id = len(self.subscribed) + 1
                            self.subscribed[sub_id] = ch["topic"]
                            subs.append({"id": sub_id, "channelId": ch["id"]})
                    if subs:
                        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif body["op"] == "status":
                    self.status.append(body)
            elif msg[0] == 1:  # opcode 1: message data (u32 subscription id, u64 log time, payload)
                sub_id, log_time = struct.unpack_from("<IQ", msg, 1)
                self.got.setdefault(self.subscribed[sub_id], []).append((log_time, bytes(msg[13:])))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._connection.__exit__(None, None, None)


@pytest.fixture
def live():
    bus = InProcessBus()
    server = FoxgloveLive(port=0, declared=DECLARED).attach(bus)
    yield bus, server
    server.close()
    bus.close()


def _suggestion(seq: int, stamp_s: float) -> ViewSuggestion:
    s = sample_messages()["ViewSuggestion"]
    s.sequence, s.stamp_s = seq, stamp_s
    return s


def test_a_client_connected_before_the_first_message_gets_every_message(live):
    bus, server = live
    client = Client(server.port)
    try:
        # every declared channel (ours and the view's) is advertised before anything is published
        wanted = {"/camera/frame", "/camera/frame/image", "/tf", "/planner/suggestion", "/planner/suggestion/scene"}
        wanted |= {"/planner/suggestion/scores", "/planner/diagnostics", "/planner/diagnostics/json"}
        assert wait_for(lambda: wanted <= set(client.subscribed.values()), 5), sorted(client.channels)
        assert server.written == 0
        # subscriptions reach the server before the first message (the listener sees them)
        assert wait_for(lambda: server.subscriptions >= len(wanted), 5)
        pub = bus.publisher("planner/suggestion", ViewSuggestion, latched=True)
        for i in range(3):
            pub.publish(_suggestion(i, 100.0 + i))
        assert wait_for(lambda: len(client.got.get("/planner/suggestion", [])) == 3, 5)
        assert [decode(d).sequence for _t, d in client.got["/planner/suggestion"]] == [0, 1, 2]
        assert wait_for(lambda: len(client.got.get("/planner/suggestion/scores", [])) == 3, 5)
        assert not [s for s in client.status if "Unknown channel" in s.get("message", "")]
    finally:
        client.close()


def test_a_client_that_joins_late_gets_the_latched_suggestion_first(live):
    bus, server = live
    samples = sample_messages()
    frames = bus.publisher("camera/frame", PosedFrame)
    pub = bus.publisher("planner/suggestion", ViewSuggestion, latched=True)
    frames.publish(samples["PosedFrame"])
    pub.publish(_suggestion(0, 100.0))
    pub.publish(_suggestion(1, 101.0))
    assert wait_for(lambda: server.written == 3, 5)
    client = Client(server.port)
    try:
        assert wait_for(lambda: len(client.got.get("/planner/suggestion", [])) == 1, 5)
        assert wait_for(lambda: len(client.got.get("/planner/suggestion/scene", [])) == 1, 5)
        # the last suggestion, not an older one; and only latched topics are repeated
        assert decode(client.got["/planner/suggestion"][0][1]).sequence == 1
        assert wait_for(lambda: len(client.got.get("/tf", [])) == 1, 5)  # world -> suggestion, not the frame's
        pub.publish(_suggestion(2, 102.0))
        assert wait_for(lambda: len(client.got.get("/planner/suggestion", [])) == 2, 5)
        assert [decode(d).sequence for _t, d in client.got["/planner/suggestion"]] == [1, 2]
        assert "/camera/frame/image" not in client.got and "/camera/frame" not in client.got
        # a third client joining gets the latched one; only it does (sent to that client alone)
        other = Client(server.port, {"/planner/suggestion"})
        try:
            assert wait_for(lambda: len(other.got.get("/planner/suggestion", [])) == 1, 5)
            assert decode(other.got["/planner/suggestion"][0][1]).sequence == 2
            pub.publish(_suggestion(3, 103.0))
            assert wait_for(lambda: len(client.got["/planner/suggestion"]) == 3, 5)
            assert [decode(d).sequence for _t, d in client.got["/planner/suggestion"]] == [1, 2, 3]
        finally:
            other.close()
    finally:
        client.close()


def test_messages_carry_their_own_stamp_and_a_stable_camera_frame(live):
    bus, server = live
    client = Client(server.port, {"/camera/frame/image", "/tf", "/planner/suggestion"})
    try:
        assert wait_for(lambda: len(client.subscribed) == 3, 5)
        assert wait_for(lambda: server.subscriptions >= 3, 5)
        frame = sample_messages()["PosedFrame"]
        for i in range(2):
            frame.stamp_s, frame.frame_id, frame.sequence = 50.0 + i, f"sim_camera/{i:06d}", i
            bus.publish("camera/frame", frame)
        bus.publisher("planner/suggestion", ViewSuggestion, latched=True).publish(_suggestion(0, 60.25))
        assert wait_for(lambda: len(client.got.get("/camera/frame/image", [])) == 2, 5)
        assert wait_for(lambda: len(client.got.get("/tf", [])) == 3, 5)
        # foxglove.CompressedImage: timestamp 1, data 2, format 3, frame_id 4
        images = [(t, protobuf_fields(d)) for t, d in client.got["/camera/frame/image"]]
        assert [t for t, _ in images] == [50_000_000_000, 51_000_000_000]  # capture time, not receipt
        assert [stamp_of(im) for _, im in images] == [(50, 0), (51, 0)]
        assert {im[4][0] for _, im in images} == {b"camera_optical"}  # one frame moving, not one per image
        assert images[0][1][3] == [b"png"] and images[0][1][2][0][:4] == b"\x89PNG"
        # foxglove.FrameTransform: timestamp 1, parent_frame_id 2, child_frame_id 3
        tfs = [protobuf_fields(d) for _t, d in client.got["/tf"]]
        assert [(tf[2][0], tf[3][0]) for tf in tfs] == [
            (b"world", b"camera_optical"),
            (b"world", b"camera_optical"),
            (b"world", b"suggestion"),
        ]
        assert stamp_of(tfs[2]) == (60, 250_000_000)  # planning time
        assert wait_for(lambda: len(client.got.get("/planner/suggestion", [])) == 1, 5)
        assert client.got["/planner/suggestion"][0][0] == 60_250_000_000
    finally:
        client.close()


def test_the_sdk_subprotocol_is_required():
    """What docs/guides/topics.md tells client authors: ``foxglove.sdk.v1``; the older name gets HTTP 400."""
    server = FoxgloveLive(port=0)
    try:
        with pytest.raises(InvalidStatus) as exc:
            connect(f"ws://127.0.0.1:{server.port}", subprotocols=["foxglove.websocket.v1"], open_timeout=5)
        assert exc.value.response.status_code == 400
        with connect(f"ws://127.0.0.1:{server.port}", subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
    finally:
        server.close()


def test_the_graph_advertises_what_its_nodes_declare():
    from aes_planner.cli.processes import declared_outputs
    from aes_planner.graph import load_launch

    declared = {t: (cls, latched) for t, cls, latched in declared_outputs(load_launch("sim_closed_loop"))}
    assert declared["planner/suggestion"] == (ViewSuggestion, True)
    assert declared["camera/frame"] == (PosedFrame, False)
    assert {"gimbal/state", "gimbal/command", "planner/diagnostics"} <= set(declared)


def test_the_bytes_on_our_channel_are_the_bus_bytes(live):
    bus, server = live
    client = Client(server.port, {"/planner/suggestion"})
    try:
        assert wait_for(lambda: server.subscriptions >= 1, 5)
        msg = _suggestion(4, 10.0)
        bus.publisher("planner/suggestion", ViewSuggestion, latched=True).publish(msg)
        assert wait_for(lambda: "/planner/suggestion" in client.got, 5)
        assert client.got["/planner/suggestion"][0][1] == encode(msg)
    finally:
        client.close()


def test_the_foxglove_command_advertises_what_the_bus_publishes():
    """``aes-planner foxglove`` beside a running graph: topics with a publisher are advertised at
    once, with their latching, before their next message."""
    bus = InProcessBus()
    pub = bus.publisher("planner/suggestion", ViewSuggestion, latched=True)
    bus.publisher("gimbal/state", GimbalState)
    server = FoxgloveLive(port=0).attach(bus)
    try:
        assert server.advertise_bus_topics(bus) == 2
        client = Client(server.port)
        try:
            assert wait_for(lambda: {"/planner/suggestion", "/gimbal/state/json"} <= set(client.subscribed.values()), 5)
            assert client.channels["/planner/suggestion"]["schemaName"] == "aes_planner.ViewSuggestion"
            assert wait_for(lambda: server.subscriptions >= 6, 5)
            pub.publish(_suggestion(0, 1.0))
            assert wait_for(lambda: "/planner/suggestion" in client.got, 5)
        finally:
            client.close()
    finally:
        server.close()
        bus.close()
