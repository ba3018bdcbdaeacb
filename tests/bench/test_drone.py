"""The ``drone`` benchmark group runs against the emulator and records plausible figures."""

import importlib

import pytest

from aes_planner.bench import GROUPS, Recorder

pytest.importorskip("pymavlink")


def test_drone_group_records_latency_reach_and_telemetry_rate():
    rec = Recorder()
    importlib.import_module(GROUPS["drone"]).run(rec, quick=True)
    r = {k: v["value"] for k, v in rec.results.items()}
    assert set(r) == {"drone.setpoint_latency.ms", "drone.time_to_reach_2m.s", "drone.telemetry_without_loss.hz"}
    assert 0 < r["drone.setpoint_latency.ms"] < 1000
    assert 2.0 <= r["drone.time_to_reach_2m.s"] < 20  # 2 m at 1 m/s cannot take less than 2 s
    assert r["drone.telemetry_without_loss.hz"] >= 250  # a vehicle's 30-250 Hz, on a loaded host too
    assert "pymavlink" in rec.meta["backends"]["drone"]
