"""MCAP recordings: our exact bytes beside Foxglove's types; replay feeds a bus the same bytes."""

import dataclasses
import json
import struct

import numpy as np
import pytest
from mcap.reader import make_reader

from aes_planner.geometry.camera import Intrinsics
from aes_planner.messages import GimbalCommand, PosedFrame, ViewSuggestion, encode
from aes_planner.messages.samples import sample_messages
from aes_planner.transport import InProcessBus
from aes_planner.transport.record import Recorder, RecordingError, read_recording, recording_summary, replay

FOXGLOVE_SCHEMAS = {"foxglove.CompressedImage", "foxglove.FrameTransform", "foxglove.SceneUpdate"}


def record_samples(path):
    bus = InProcessBus()
    samples = sample_messages()
    with Recorder(path) as rec:
        rec.attach(bus)
        for name, msg in samples.items():
            bus.publish(f"t/{name.lower()}", msg)
        bus.publish("t/posedframe", samples["PosedFrame"])
        bus.publisher("t/posedframe", PosedFrame).publish_raw(b"garbage")
        assert rec.rejected == 0  # the raw subscription refuses it before the recorder
    bus.close()
    return samples


def test_recording_holds_our_bytes_and_foxglove_types(tmp_path):
    path = tmp_path / "run.mcap"
    samples = record_samples(path)
    got = list(read_recording(path))
    assert [t for t, _, _ in got] == [f"t/{n.lower()}" for n in samples] + ["t/posedframe"]
    for (_topic, data, _t), msg in zip(got, samples.values()):
        assert data == encode(msg)
    assert recording_summary(path)["t/posedframe"] == {"type": "PosedFrame", "count": 2}

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name for s in summary.schemas.values()}
        topics = {c.topic: c for c in summary.channels.values()}
        assert FOXGLOVE_SCHEMAS <= schemas
        assert topics["/t/posedframe/image"].message_encoding == "protobuf"
        assert {"/tf", "/t/viewsuggestion/scene", "/t/viewsuggestion/scores", "/t/gimbalstate/json"} <= set(topics)
        scores = [json.loads(m.data) for _s, c, m in reader.iter_messages(topics=["/t/viewsuggestion/scores"])]
    best = samples["ViewSuggestion"].best
    assert scores[0]["best"]["score"] == best.score and scores[0]["best"]["terms"] == best.terms
    assert scores[0]["scores"] == [c.score for c in samples["ViewSuggestion"].candidates]
    assert scores[0]["covered_fraction"] == samples["ViewSuggestion"].covered_fraction == 0.625
    assert scores[0]["explore"]["score"] == samples["ViewSuggestion"].explore.score


def test_scene_update_colours_frustums_by_score(tmp_path):
    from foxglove.messages import SceneUpdate  # noqa: F401 (the schema the file names)

    from aes_planner.transport.foxglove_view import EXPLORE_COLOR, foxglove_view, score_color

    msg = sample_messages()["ViewSuggestion"]
    views = foxglove_view("planner/suggestion", msg, 1_000)
    assert {v.topic for v in views} == {"/planner/suggestion/scene", "/tf", "/planner/suggestion/scores"}
    assert score_color(1.0, 0.0, 1.0)[1] == 1.0 and score_color(0.0, 0.0, 1.0)[0] == 1.0
    scene = next(v for v in views if v.topic == "/planner/suggestion/scene").data  # protobuf bytes
    # the exploratory candidate drawn apart: its own entity id and label, in its blue (Color's doubles)
    assert b"candidate_1" in scene and b"explore" in scene and b"explore 0.300" in scene
    assert struct.pack("<d", EXPLORE_COLOR[0]) in scene and struct.pack("<d", EXPLORE_COLOR[1]) in scene
    bare = foxglove_view("planner/suggestion", dataclasses.replace(msg, explore=None, covered_fraction=None), 1_000)
    assert b"explore" not in next(v for v in bare if v.topic == "/planner/suggestion/scene").data


def test_replay_feeds_a_fresh_bus_the_same_bytes(tmp_path):
    path = tmp_path / "run.mcap"
    samples = record_samples(path)
    bus = InProcessBus()
    frames = bus.subscribe("t/posedframe", PosedFrame, depth=10)
    raw = bus.subscribe_raw("**", depth=100)
    n = replay(path, bus, rate=0)
    assert n == len(samples) + 1
    assert [s.data for s in raw.take()] == [d for _, d, _ in read_recording(path)]
    assert frames.received == 2 and frames.rejected == 0
    assert replay(path, bus, rate=0, topics=["t/gimbalcommand"]) == 1


def test_replay_loops_until_stopped(tmp_path):
    import threading

    path = tmp_path / "cmd.mcap"
    bus = InProcessBus()
    with Recorder(path) as rec:
        rec.attach(bus)
        bus.publish("gimbal/command", GimbalCommand())
    stop = threading.Event()
    seen = []

    def on_msg(m):
        seen.append(m)
        if len(seen) >= 5:
            stop.set()

    bus.subscribe("gimbal/command", GimbalCommand, callback=on_msg)
    assert replay(path, bus, rate=0, loop=True, stop=stop) >= 5


def test_bad_recordings_and_paths_are_clear_errors(tmp_path):
    with pytest.raises(RecordingError, match="no such"):
        list(read_recording(tmp_path / "missing.mcap"))
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="not an MCAP"):
        list(read_recording(junk))
    good = tmp_path / "good.mcap"
    record_samples(good)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[:64])  # cut before its first message
    with pytest.raises(RecordingError, match="cut short before any message"):
        list(read_recording(cut))
    with pytest.raises(RecordingError, match="exists"):
        Recorder(good)
    with pytest.raises(RecordingError, match="cannot write"):
        Recorder(tmp_path / "no" / "such" / "dir.mcap")
    with pytest.raises(RecordingError, match="rate"):
        replay(good, InProcessBus(), rate=float("nan"))


def test_a_recording_cut_short_is_read_up_to_where_it_breaks_off(tmp_path, caplog):
    """A recorder killed with SIGKILL leaves no summary; the file was unreadable as a whole."""
    good = tmp_path / "good.mcap"
    bus = InProcessBus()
    k = Intrinsics(100.0, 100.0, 64.0, 48.0, 128, 96)
    rng = np.random.default_rng(0)
    with Recorder(good) as rec:  # incompressible images: several chunks
        rec.attach(bus)
        for i in range(200):
            image = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)
            bus.publish("t/frame", PosedFrame(image, k, np.eye(4), float(i), sequence=i))
    bus.close()
    full = list(read_recording(good))
    assert len(full) == 200
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size * 7 // 10])
    with caplog.at_level("WARNING", logger="aes_planner.transport.record"):
        got = list(read_recording(cut))
    assert 0 < len(got) < len(full) and got == full[: len(got)]
    assert "breaks off after" in caplog.text
    assert replay(cut, InProcessBus(), rate=0) == len(got)


def test_suggestion_only_recording_has_best_transform(tmp_path):
    path = tmp_path / "s.mcap"
    with Recorder(path) as rec:
        rec.write("planner/suggestion", ViewSuggestion(1.0))  # empty: no best, no transform
        rec.write("planner/suggestion", sample_messages()["ViewSuggestion"])
    with open(path, "rb") as f:
        tfs = list(make_reader(f).iter_messages(topics=["/tf"]))
    assert len(tfs) == 1


def test_a_recording_keeps_receive_time_as_log_time_and_the_stamp_as_publish_time(tmp_path):
    """Replay paces on log time (when the message was recorded); the message's own stamp (capture or
    planning time, sample stamps 2.5 s and 3.0 s) is each channel's publish time and is inside the
    Foxglove messages."""
    import time

    path = tmp_path / "run.mcap"
    before = time.time_ns()
    samples = record_samples(path)
    with open(path, "rb") as f:
        got = {(c.topic, m.sequence): m for _s, c, m in make_reader(f).iter_messages()}
    by_topic: dict[str, list] = {}
    for (topic, _seq), m in sorted(got.items(), key=lambda kv: kv[0][1]):
        by_topic.setdefault(topic, []).append(m)
    for topic, stamp_s in (("/t/posedframe", 2.5), ("/t/posedframe/image", 2.5), ("/t/viewsuggestion", 3.0)):
        m = by_topic[topic][0]
        assert m.publish_time == int(stamp_s * 1e9), topic
        assert m.log_time >= before, topic
    assert samples["ViewSuggestion"].stamp_s == 3.0
    # the image's frame and the transform's child are one stable camera frame, not the image's name
    assert b"t_posedframe_optical" in by_topic["/t/posedframe/image"][0].data  # from topic t/posedframe
    assert b"cam0" not in by_topic["/t/posedframe/image"][0].data
