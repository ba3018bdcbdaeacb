"""The soak: frames at 30 Hz into a planning planner, garbage on every topic (short form here;
the long form is marked slow and runs in make bench)."""

import pytest

from aes_planner.bench.soak import OVERSIZED_MB, run_soak


def check(r, duration_s):
    assert r.frames_sent >= 30 * duration_s * 0.6  # the publisher kept its rate on a loaded machine
    assert r.frames_in + r.frames_dropped >= r.frames_sent * 0.9  # each frame was taken or dropped
    assert r.frames_dropped > 0 and r.frames_used >= 1  # busy planning drops to the latest
    assert r.field_frames_max <= 8  # bounded memory: the field keeps max_frames
    assert all(n > 0 for n in r.rejected.values()), r.rejected  # garbage rejected on every topic
    assert r.nonfinite == 0 and r.step_errors == 0
    assert r.suggestions >= 1  # it kept serving while rejecting garbage
    assert r.rss_end_mb - r.rss_start_mb < 150.0, (r.rss_start_mb, r.rss_end_mb)


def test_soak_short():
    r = run_soak(duration_s=8.0)
    check(r, 8.0)


@pytest.mark.slow
def test_soak_long():
    r = run_soak(duration_s=180.0)
    check(r, 180.0)
    late = r.rss_samples_mb[len(r.rss_samples_mb) // 2 :]
    q = len(late) // 2
    # Flat in the second half: the floor (the samples with no oversized garbage in flight) does not
    # grow from its first quarter to its second. Single samples are not flat: each oversized
    # payload lives for a moment on both ends of the bus, so a sample can sit up to two payloads
    # above the floor (seen: +70 to +140 MB) - bounded, not a backlog.
    assert min(late[q:]) - min(late[:q]) < 20.0, (min(late[:q]), min(late[q:]))
    assert max(late) - min(late) < 2 * OVERSIZED_MB + 30.0, (min(late), max(late))


def test_bench_node_records_the_soak_figures(wiring_recorder, monkeypatch):
    """Wiring only: which keys ``aes-planner bench node`` writes (the soak itself is tested above)."""
    import aes_planner.bench.soak as soak
    from aes_planner.bench import node as bench_node

    fake = soak.SoakResult(10.0, 300, 290, 250, 12, 6, 40, {"camera/frame": 10}, 400.0, 410.0, 0.5, 0.9, 8, 0, 0)
    monkeypatch.setattr(soak, "run_soak", lambda duration_s: fake)
    bench_node.run(wiring_recorder, quick=True)
    r = wiring_recorder.results
    assert r["node.soak.frames_dropped"]["value"] == 250 and r["node.soak.rss_end_mb"]["value"] == 410.0
    assert r["node.soak.suggestion_p95_ms"]["value"] == pytest.approx(900.0)
