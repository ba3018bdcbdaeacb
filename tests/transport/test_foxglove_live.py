"""The live Foxglove server at the protocol level: a WebSocket client on loopback subscribes to an
image channel and a suggestion channel and receives both."""

import json
import struct
import time

from websockets.sync.client import connect

from aes_planner.messages import encode
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import InProcessBus
from aes_planner.transport.record import FoxgloveLive


def test_websocket_client_receives_an_image_and_a_suggestion():
    samples = sample_messages()
    bus = InProcessBus()
    live = FoxgloveLive(port=0).attach(bus)
    try:
        assert live.port > 0
        # Channels are advertised once they exist: publish once before the client subscribes.
        bus.publish("camera/frame", samples["PosedFrame"])
        bus.publish("planner/suggestion", samples["ViewSuggestion"])
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"], open_timeout=5) as ws:
            channels = {}
            end = time.monotonic() + 5
            while not {"/camera/frame/image", "/planner/suggestion"} <= set(channels) and time.monotonic() < end:
                msg = ws.recv(timeout=5)
                if isinstance(msg, str):
                    body = json.loads(msg)
                    if body["op"] == "advertise":
                        channels.update({c["topic"]: c for c in body["channels"]})
            image, ours = channels["/camera/frame/image"], channels["/planner/suggestion"]
            assert image["schemaName"] == "foxglove.CompressedImage" and image["encoding"] == "protobuf"
            assert ours["encoding"] == "aes-planner" and ours["schemaName"] == "aes_planner.ViewSuggestion"
            ws.send(
                json.dumps(
                    {
                        "op": "subscribe",
                        "subscriptions": [{"id": 1, "channelId": image["id"]}, {"id": 2, "channelId": ours["id"]}],
                    }
                )
            )
            time.sleep(0.3)  # let the server register the subscriptions
            bus.publish("camera/frame", samples["PosedFrame"])
            bus.publish("planner/suggestion", samples["ViewSuggestion"])
            got = {}
            end = time.monotonic() + 5
            while len(got) < 2 and time.monotonic() < end:
                msg = ws.recv(timeout=5)
                if isinstance(msg, bytes) and msg[0] == 1:  # opcode 1: message data
                    sub_id, _log_time = struct.unpack_from("<IQ", msg, 1)
                    got[sub_id] = msg[13:]
        assert b"\x89PNG" in got[1]
        assert got[2] == encode(samples["ViewSuggestion"])
    finally:
        live.close()
        bus.close()
