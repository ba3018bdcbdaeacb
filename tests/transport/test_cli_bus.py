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


# ------------------------------------------- what comes from the bus is escaped before the terminal
def test_what_comes_from_the_bus_is_printed_escaped(hub, capsys):
    """A peer that announces a publisher, and puts data, on a key with escape sequences (with Zenoh
    directly, past our topic checks) cannot write them into the terminal of `topics` or `echo`."""
    bus, ep = hub
    evil = "evil\x1b[2J\x1b]0;owned\x07/x"
    token = bus.session.liveliness().declare_token(f"{bus.prefix}/@meta/pub/Bad\x1b[31mType/0/peer/{evil}")
    stop = threading.Event()

    def put():
        while not stop.wait(0.05):
            bus.session.put(f"{bus.prefix}/{evil}", b"\x1b[31mnot a message")

    t = threading.Thread(target=put)
    t.start()
    try:
        for argv in (["topics", "--duration", "1"], ["topics", "--duration", "1", "--json"]):
            assert main([*argv, "--connect", ep]) == 0
            out = capsys.readouterr().out
            assert "\x1b" not in out and "\x07" not in out and "evil" in out and "2J" in out
        assert main(["echo", "**", "--timeout", "1.5", "--connect", ep]) in (0, 2)
        both = capsys.readouterr()
        assert "\x1b" not in both.out + both.err and "\x07" not in both.out + both.err
    finally:
        stop.set()
        t.join()
        token.undeclare()


@pytest.mark.parametrize(
    "pattern, canonical",
    [("a/**/**/b", "a/**/b"), ("a/**/*/b", "a/*/**/b"), ("**/*/**/*", "*/*/**"), ("/**/**", "**")],
)
def test_patterns_are_made_canonical_for_zenoh(pattern, canonical, endpoint, capsys):
    from aes_planner.transport import validate_pattern

    assert validate_pattern(pattern) == canonical
    assert main(["echo", pattern, "--timeout", "0.3", "--connect", endpoint]) == 2  # no publisher: a clear error
    err = capsys.readouterr().err
    assert err.startswith("error: no message on") and "bug" not in err


@pytest.mark.parametrize(
    "argv, match",
    [
        (["echo", "/".join(["**", "x"] * 30), "--timeout", "1"], "'**' tokens"),
        (["topics", "--duration", "1e7"], "at most 600"),
        (["replay", "x.mcap", "--count", "0"], "--count"),
        (["replay", "x.mcap", "--loop", "--duration", "inf"], "--duration"),
    ],
)
def test_bus_commands_refuse_what_would_hang(argv, match, capsys, deadline):
    with deadline(10):
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("target", ["missing_folder/x.mcap", "x.mcap"])
def test_record_refuses_a_symlink_dangling_or_not(tmp_path, capsys, endpoint, target, deadline):
    link = tmp_path / "link.mcap"
    link.symlink_to(tmp_path / target)
    with deadline(10):
        assert main(["record", "-o", str(link), "--duration", "0.1", "--connect", endpoint]) == 2
    assert "symlink" in capsys.readouterr().err and not (tmp_path / target).exists()


def test_replay_loop_is_bounded_by_count_and_duration(hub, capsys, tmp_path, deadline):
    bus, ep = hub
    rec = tmp_path / "r.mcap"
    assert main(["record", "planner/suggestion", "-o", str(rec), "--duration", "1", "--connect", ep]) == 0
    capsys.readouterr()
    with deadline(30):
        assert main(["replay", str(rec), "--rate", "0", "--wait", "0", "--count", "3", "--connect", ep]) == 0
    assert capsys.readouterr().out.startswith("3 messages replayed")
    with deadline(30):
        t0 = time.monotonic()
        assert main(["replay", str(rec), "--loop", "--duration", "1.5", "--wait", "0", "--connect", ep]) == 0
        assert time.monotonic() - t0 < 10
    n = int(capsys.readouterr().out.split()[0])
    assert n >= 2  # looped, then stopped by itself
