"""Bad-input sweep of ``replay`` (aes_planner.transport.record): a recording's undecodable and
foreign-typed messages are skipped and a clock jump is capped; a bad rate or topic is one
``error:`` line with exit 2.
"""

import pytest


@pytest.fixture
def recording(tmp_path):
    """A recording with a malformed message, one of another type on the same topic, and a
    clock jump of 30 years, written with the MCAP writer directly."""
    from mcap.writer import Writer

    from aes_planner.messages import Diagnostics, encode
    from aes_planner.messages.samples import sample_messages
    from aes_planner.transport.foxglove_view import OUR_ENCODING, our_schema

    good = encode(Diagnostics(1.0, "n"))
    other = encode(sample_messages()["GimbalState"])
    path = tmp_path / "r.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        name, enc, data = our_schema("Diagnostics", 1)
        ch = w.register_channel("/t/d", OUR_ENCODING, w.register_schema(name, enc, data))
        for i, (payload, t) in enumerate([(good, 0), (good[: len(good) // 2], 1), (other, 2), (good, 10**18)]):
            w.add_message(ch, log_time=t, publish_time=t, data=payload, sequence=i)
        w.finish()
    return path


def test_replay_skips_what_does_not_decode_and_caps_clock_jumps(recording, monkeypatch, deadline):
    from aes_planner.messages import Diagnostics
    from aes_planner.transport import InProcessBus
    from aes_planner.transport import record as rec

    monkeypatch.setattr(rec, "MAX_REPLAY_GAP_S", 0.05)
    bus = InProcessBus()
    sub = bus.subscribe("t/d", Diagnostics, depth=10)
    with deadline(10):
        n = rec.replay(recording, bus, rate=1.0)
    assert n == 2  # the first and the last; truncated and foreign-typed ones skipped
    assert len(sub.take()) == 2 and sub.rejected == 0
    bus.close()


@pytest.mark.parametrize("rate", ["1e-300", "nan", "-1", "inf", "5000"])
def test_replay_rate_bounds(recording, cli_error, rate):
    cli_error(["replay", recording, "--rate", rate, "--wait", "0"], "--rate", seconds=10)


def test_replay_topics_are_checked(recording, cli_error):
    cli_error(["replay", recording, "--topics", "bad topic", "--wait", "0"], "topic name", seconds=10)
