"""Shared test set-up: fixed seeds, hypothesis profiles (no deadlines: the machine is shared)."""

import os

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, settings

settings.register_profile("default", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(autouse=True)
def _fixed_seeds():
    np.random.seed(0)  # noqa: NPY002 (tests that use the legacy global stream get a fixed one)
    torch.manual_seed(0)
    yield


@pytest.fixture
def wiring_recorder(monkeypatch):
    """A bench ``Recorder`` whose ``time`` runs each case once and records 1 ms: for tests of a
    group's wiring (which keys it records), not of its speed."""
    from aes_planner.bench import Recorder

    rec = Recorder()

    def once(key, fn, runs=7, warmup=1):
        fn()
        rec.record(key, 1.0, "ms", runs)
        return 1.0

    monkeypatch.setattr(rec, "time", once)
    return rec
