"""The ``sim`` benchmark group is registered and records its figures: render times at 128 and 256 px (and
supersampled), scene build and per-family render times, and the backend used."""

import importlib

from aes_planner.bench import GROUPS


def test_sim_group_records_render_times(wiring_recorder):
    rec = wiring_recorder
    importlib.import_module(GROUPS["sim"]).run(rec, quick=True)
    keys = set(rec.results)
    assert {"sim.render_128.ms", "sim.render_256.ms", "sim.render_128_aa3.ms", "sim.build_indoor.ms"} <= keys
    assert {f"sim.family_{name}_128.ms" for name in ("indoor", "outdoor", "tabletop", "gallery")} <= keys
    assert "numpy" in rec.meta["backends"]["sim"]
