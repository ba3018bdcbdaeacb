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

    def once(key, fn, runs=7, warmup=1, cpu=False):  # Recorder.time's signature
        fn()
        rec.record(key, 1.0, "ms", runs)
        return 1.0

    monkeypatch.setattr(rec, "time", once)
    return rec


# ---------------------------------------------------------------- the bad-input sweep
def _one_clean_line(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert "Traceback" not in text, text
    assert len(lines) == 1, f"expected one error line, got {len(lines)}:\n{text[:2000]}"
    assert lines[0].startswith("error: ") and "this is a bug" not in lines[0], lines[0]
    assert len(lines[0]) < 1200, f"error line of {len(lines[0])} characters"
    return lines[0]


@pytest.fixture
def deadline():
    """``with deadline(s):`` fails the test if the block runs longer than ``s`` seconds (a hang)."""
    import contextlib
    import signal

    @contextlib.contextmanager
    def limit(seconds: float):
        def expired(signum, frame):
            raise TimeoutError(f"took longer than {seconds} s (a hang?)")

        old = signal.signal(signal.SIGALRM, expired)
        signal.setitimer(signal.ITIMER_REAL, seconds)
        try:
            yield
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)

    return limit


@pytest.fixture
def cli_error(capsys, deadline):
    """``cli_error(argv, match)``: the CLI exits 2 with one ``error: ...`` line (no traceback, not the
    last-resort "bug" line) containing ``match``, within 60 s; returns the line."""
    from aes_planner.cli import main

    def run(argv, match: str = "", seconds: float = 60.0) -> str:
        capsys.readouterr()
        with deadline(seconds):
            rc = main([str(a) for a in argv])
        out = capsys.readouterr()
        assert rc == 2, f"exit {rc}; stdout {out.out[-500:]!r} stderr {out.err[-500:]!r}"
        line = _one_clean_line(out.err)
        assert match.lower() in line.lower(), line
        return line

    return run


@pytest.fixture
def clean_error(deadline):
    """``clean_error(fn, *args, match=...)``: ``fn`` raises an ``AesPlannerError`` (a one-line message
    of bounded size containing ``match``) within 60 s, nothing else."""
    from aes_planner.errors import AesPlannerError

    def run(fn, *args, match: str = "", seconds: float = 60.0, **kwargs) -> AesPlannerError:
        with deadline(seconds), pytest.raises(AesPlannerError) as info:
            fn(*args, **kwargs)
        text = str(info.value)
        assert "\n" not in text.strip(), f"a multi-line message: {text[:2000]}"
        assert len(text) < 1200, f"message of {len(text)} characters"
        assert match.lower() in text.lower(), text
        return info.value

    return run


@pytest.fixture
def no_unpickling(monkeypatch):
    """Any unpickling after this fixture (pickle's, torch.load's, weights-only or not) fails the test:
    for loaders that must refuse a pickle-based file without reading it."""
    import pickle

    import torch._weights_only_unpickler as wou

    def never(*args, **kwargs):
        pytest.fail("something was unpickled")

    for owner, name in ((pickle, "Unpickler"), (pickle, "load"), (pickle, "loads"), (wou, "Unpickler")):
        monkeypatch.setattr(owner, name, never)
    monkeypatch.setattr(torch, "load", never)
    monkeypatch.setattr(torch.serialization, "load", never)


@pytest.fixture
def work(tmp_path):
    """A scratch folder holding one plain file, ``a_file``: a destination that is not a folder."""
    (tmp_path / "a_file").write_text("x")
    return tmp_path
