"""The bus contract on the in-process backend (the Zenoh backend runs the same checks)."""

import threading

import numpy as np
import pytest

from aes_planner.messages import GimbalCommand, GimbalState, PlannerRequest, PosedFrame, ViewSuggestion, encode
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import (
    InProcessBus,
    RemoteError,
    RequestTimeout,
    TopicError,
    TransportError,
    topic_matches,
    validate_topic,
    wait_any,
)


@pytest.fixture
def bus():
    b = InProcessBus()
    yield b
    b.close()


@pytest.mark.parametrize(
    "name", ["", "/", "a//b", "a/", "1abc", "a/2b", "a b", "a-b", "a__b", "~/x", "{ns}/x", "a" * 300, None]
)
def test_bad_topic_names_are_refused(name):
    with pytest.raises(TopicError):
        validate_topic(name)


def test_topic_names_and_patterns():
    assert validate_topic("/planner/suggestion") == "planner/suggestion"
    assert validate_topic("_private/x1") == "_private/x1"
    assert topic_matches("**", "a/b") and topic_matches("a/*", "a/b") and not topic_matches("a/*", "a/b/c")
    assert topic_matches("a/**", "a/b/c") and not topic_matches("b/**", "a/b")


def test_keep_last_queue_counts_drops(bus):
    sub = bus.subscribe("gimbal/command", GimbalCommand, depth=3)
    pub = bus.publisher("gimbal/command", GimbalCommand)
    for i in range(5):
        pub.publish(GimbalCommand("move", 0.1 * i, 0.0, sequence=i))
    assert sub.pending == 3 and sub.dropped == 2 and sub.received == 5
    assert [m.sequence for m in sub.take()] == [2, 3, 4]
    assert sub.take() == [] and sub.latest() is None
    pub.publish(GimbalCommand(sequence=7))
    pub.publish(GimbalCommand(sequence=8))
    assert sub.latest().sequence == 8 and sub.pending == 0


def test_subscribers_get_their_own_copies(bus):
    frame = sample_messages()["PosedFrame"]
    a = bus.subscribe("camera/frame", PosedFrame)
    b = bus.subscribe("camera/frame", PosedFrame)
    bus.publish("camera/frame", frame)
    fa, fb = a.poll(), b.poll()
    fa.image[:] = 0
    assert np.array_equal(fb.image, frame.image) and fa.image is not frame.image


def test_latched_topic_reaches_a_late_subscriber(bus):
    pub = bus.publisher("planner/suggestion", ViewSuggestion, latched=True)
    plain = bus.publisher("gimbal/state", GimbalState)
    pub.publish(ViewSuggestion(1.0, sequence=1))
    pub.publish(ViewSuggestion(2.0, sequence=2))
    plain.publish(GimbalState(0, 0, 0, 0))
    late = bus.subscribe("planner/suggestion", ViewSuggestion)
    missed = bus.subscribe("gimbal/state", GimbalState)
    assert [m.sequence for m in late.take()] == [2]
    assert missed.pending == 0


def test_malformed_and_oversized_are_rejected_and_counted(bus):
    sub = bus.subscribe("gimbal/command", GimbalCommand, max_bytes=200)
    seen = []
    cb = bus.subscribe("gimbal/command", GimbalCommand, callback=seen.append)
    raw = bus.publisher("gimbal/command", GimbalCommand)
    good = encode(GimbalCommand("move", 0.2, 0.1))
    raw.publish_raw(good[:-3])  # truncated
    raw.publish_raw(b"\x00" * 50)  # garbage
    raw.publish_raw(encode(GimbalState(0, 0, 0, 0)))  # wrong type on the topic
    nan = bytearray(good)
    nan[-33:-25] = np.array([np.nan]).tobytes()  # pan_rad
    raw.publish_raw(bytes(nan))
    raw.publish_raw(good)
    assert sub.rejected == 4 and sub.received == 1 and cb.rejected == 4 and len(seen) == 1
    assert "GimbalCommand" in sub.last_error or "finite" in sub.last_error
    assert sub.poll().pan_rad == 0.2


def test_callback_errors_do_not_reach_the_publisher(bus):
    def boom(msg):
        raise RuntimeError("subscriber bug")

    sub = bus.subscribe("gimbal/command", GimbalCommand, callback=boom)
    bus.publish("gimbal/command", GimbalCommand())
    assert sub.callback_errors == 1 and sub.received == 1


def test_types_are_enforced(bus):
    bus.publisher("gimbal/command", GimbalCommand)
    with pytest.raises(TopicError, match="carries GimbalCommand"):
        bus.subscribe("gimbal/command", GimbalState)
    pub = bus.publisher("gimbal/command", GimbalCommand)
    with pytest.raises(TransportError, match="carries GimbalCommand"):
        pub.publish(GimbalState(0, 0, 0, 0))
    with pytest.raises(TransportError, match="depth"):
        bus.subscribe("x", GimbalCommand, depth=0)


def test_request_reply_with_handler_and_polled(bus):
    bus.serve("planner/request", PlannerRequest, ViewSuggestion, lambda req: ViewSuggestion(9.0, sequence=req.sequence))
    reply = bus.request("planner/request", PlannerRequest(sequence=5), ViewSuggestion)
    assert reply.sequence == 5 and reply.stamp_s == 9.0
    with pytest.raises(RemoteError, match="rejected"):
        bus.request_raw(bus._servers["planner/request"], b"junk", ViewSuggestion, 1.0)
    with pytest.raises(RequestTimeout):
        bus.request("nobody/home", PlannerRequest(), ViewSuggestion, timeout_s=0.05)

    polled = bus.serve("gimbal/query", PlannerRequest, GimbalState)
    stop = threading.Event()

    def loop():
        while not stop.is_set():
            if wait_any([polled], 0.05):
                for p in polled.take():
                    p.reply(GimbalState(0.5, 0, 0, 0, sequence=p.msg.sequence))

    t = threading.Thread(target=loop)
    t.start()
    try:
        assert bus.request("gimbal/query", PlannerRequest(sequence=3), GimbalState).sequence == 3
    finally:
        stop.set()
        t.join()
    with pytest.raises(RequestTimeout):
        bus.request("gimbal/query", PlannerRequest(), GimbalState, timeout_s=0.05)


def test_wait_any_wakes_on_delivery(bus):
    sub = bus.subscribe("gimbal/state", GimbalState)
    assert not wait_any([sub], 0.01)
    threading.Timer(0.05, lambda: bus.publish("gimbal/state", GimbalState(0, 0, 0, 0))).start()
    assert wait_any([sub], 5.0) and sub.pending == 1


def test_raw_subscription_sees_every_topic_and_topics_lists_them(bus):
    raw = bus.subscribe_raw("**")
    for name, msg in sample_messages().items():
        bus.publish(f"t/{name.lower()}", msg)
    samples = raw.take()
    assert [s.topic for s in samples] == [f"t/{n.lower()}" for n in sample_messages()]
    infos = {i.topic: i for i in bus.topics()}
    assert infos["t/posedframe"].type_name == "PosedFrame" and infos["t/posedframe"].publishers == 1


def test_closed_bus_refuses(bus):
    sub = bus.subscribe("a", GimbalState)
    bus.close()
    with pytest.raises(TransportError, match="closed"):
        bus.publish("a", GimbalState(0, 0, 0, 0))
    assert sub.closed
