"""The ``sim`` benchmark group is registered and records the figures the issue asks for."""

import importlib

from aes_planner.bench import GROUPS, Recorder


def test_sim_group_records_render_times(monkeypatch):
    rec = Recorder()

    def once(key, fn, runs=7, warmup=1):  # run each case once: this checks the wiring, not speed
        fn()
        rec.record(key, 1.0, "ms", runs)
        return 1.0

    monkeypatch.setattr(rec, "time", once)
    importlib.import_module(GROUPS["sim"]).run(rec, quick=True)
    keys = set(rec.results)
    assert {"sim.render_128.ms", "sim.render_256.ms", "sim.render_128_aa3.ms", "sim.build_indoor.ms"} <= keys
    assert {f"sim.family_{name}_128.ms" for name in ("indoor", "outdoor", "tabletop", "gallery")} <= keys
    assert "numpy" in rec.meta["backends"]["sim"]
