"""Benchmark group ``node``: the soak (:func:`aes_planner.bench.soak.run_soak`), long form.

Frames of a simulated rig scene at 30 Hz into a passive planner (RGB scoring, ``fast`` search)
for 60 s (``--quick``: 10 s) with malformed and oversized payloads on every topic. Figures:

* ``node.soak.frames_in`` / ``frames_dropped`` / ``frames_used``: frames the planner received,
  dropped to the latest while busy, and integrated;
* ``node.soak.rss_start_mb`` / ``rss_end_mb``: resident memory after warm-up and at the end;
* ``node.soak.suggestion_p50_ms`` / ``suggestion_p95_ms``: suggestion latency (field rebuild +
  search) percentiles over the run;
* ``node.soak.rejected``: malformed messages rejected by the subscriptions (all topics).
"""

from __future__ import annotations

from aes_planner.bench import Recorder


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.bench.soak import run_soak

    r = run_soak(duration_s=10.0 if quick else 60.0)
    rec.meta["backends"]["node"] = "in-process bus; planner passive, rgb scorer, fast search, 64x48 frames at 30 Hz"
    rec.record("node.soak.duration_s", r.duration_s, "s")
    rec.record("node.soak.frames_sent", r.frames_sent, "frames")
    rec.record("node.soak.frames_in", r.frames_in, "frames")
    rec.record("node.soak.frames_dropped", r.frames_dropped, "frames")
    rec.record("node.soak.frames_used", r.frames_used, "frames")
    rec.record("node.soak.suggestions", r.suggestions, "messages")
    rec.record("node.soak.rejected", sum(r.rejected.values()), "messages")
    rec.record("node.soak.rss_start_mb", r.rss_start_mb, "MB")
    rec.record("node.soak.rss_end_mb", r.rss_end_mb, "MB")
    rec.record("node.soak.suggestion_p50_ms", r.latency_p50_s * 1e3, "ms", max(r.suggestions, 1))
    rec.record("node.soak.suggestion_p95_ms", r.latency_p95_s * 1e3, "ms", max(r.suggestions, 1))
