"""echo / topics / record / replay against a Zenoh hub on loopback; bad flags exit 2 in one line."""

import json
import threading
import time

import pytest

from aes_planner.cli import main
from aes_planner.messages import PosedFrame, ViewSuggestion
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import ZenohConfig
from aes_planner.transport.record import recording_summary
from tests.helpers import wait_for


@pytest.fixture
def hub(endpoint):
    from aes_planner.transport.zenoh_bus import ZenohBus

    bus = ZenohBus(ZenohConfig(listen=(endpoint,), connect=()))
    samples = sample_messages()
    bus.publisher("planner/suggestion", ViewSuggestion, latched=True).publish(samples["ViewSuggestion"])
    frames = bus.publisher("camera/frame", PosedFrame, reliable=False)
    stop = threading.Event()

    def stream():
        while not stop.wait(0.05):
            frames.publish(samples["PosedFrame"])

    t = threading.Thread(target=stream)
    t.start()
    yield bus, endpoint
    stop.set()
    t.join()
    bus.close()


def test_echo_topics_record_replay(hub, capsys, tmp_path):
    bus, ep = hub
    assert main(["echo", "planner/suggestion", "--once", "--json", "--connect", ep, "--timeout", "10"]) == 0
    body = json.loads(capsys.readouterr().out.splitlines()[0])
    assert body["type"] == "ViewSuggestion" and body["topic"] == "planner/suggestion"
    assert body["candidates"][0]["score"] == 0.8
    assert body["kind"] == "search" and len(body["candidates"][0]["view"]) == 5  # what the suggestion is

    assert main(["echo", "camera/frame", "--once", "--connect", ep, "--timeout", "10"]) == 0
    out = capsys.readouterr().out
    assert "PosedFrame" in out and "width: 8" in out and "mean_rgb" in out  # summarised, not dumped

    assert main(["topics", "--json", "--duration", "1", "--connect", ep]) == 0
    rows = {r["topic"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["planner/suggestion"]["type"] == "ViewSuggestion" and rows["planner/suggestion"]["latched"]
    assert rows["camera/frame"]["rate_hz"] > 2

    rec = tmp_path / "r.mcap"
    assert main(["record", "-o", str(rec), "--duration", "1.5", "--connect", ep]) == 0
    summary = recording_summary(rec)
    assert summary["planner/suggestion"]["count"] == 1 and summary["camera/frame"]["count"] >= 5

    got = bus.subscribe("planner/suggestion", ViewSuggestion, depth=100)
    time.sleep(0.2)
    got.take()
    assert (
        main(["replay", str(rec), "--rate", "0", "--wait", "1", "--connect", ep, "--topics", "planner/suggestion"]) == 0
    )
    wait_for(lambda: got.received >= 1, timeout_s=5.0, poll_s=0.05)
    assert got.received >= 1 and got.rejected == 0


@pytest.mark.parametrize(
    "argv, match",
    [
        (["echo", "bad//topic", "--timeout", "1"], "empty token"),
        (["echo", "x", "--timeout", "nan"], "--timeout"),
        (["echo", "x", "--timeout", "1", "--connect", "127.0.0.1:7447"], "endpoint"),
        (["echo", "x", "--timeout", "1", "--listen", "tcp/0.0.0.0:0"], "allow_remote"),
        (["topics", "--duration", "-1"], "--duration"),
        (["replay", "missing.mcap"], "no such recording"),
        (["replay", "missing.mcap", "--rate", "-2"], "--rate"),
        (["foxglove", "--port", "70000"], "--port"),
    ],
)
def test_bad_flags_are_one_line_errors(argv, match, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_echo_times_out_clearly(endpoint, capsys):
    assert main(["echo", "nothing/here", "--timeout", "0.5", "--connect", endpoint]) == 2
    assert "no message on nothing/here" in capsys.readouterr().err


def test_record_refuses_an_existing_file(tmp_path, capsys, endpoint):
    f = tmp_path / "x.mcap"
    f.write_text("keep me")
    assert main(["record", "-o", str(f), "--duration", "0.1", "--connect", endpoint]) == 2
    assert f.read_text() == "keep me" and "exists" in capsys.readouterr().err
