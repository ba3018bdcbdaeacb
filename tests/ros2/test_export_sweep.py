"""Sweep: ``export rosbag2`` fed what a careless or hostile user has: an empty or garbage file, a
recording whose stamps no ROS 2 bag holds (beyond 2038, 1e300 s, int64 log times), an output that is
a (dangling) symlink, a 10,000-character frame id. Each ends in one capped ``error:`` line and
status 2, or a bag without the refused messages and a warning: never a year-2263 bag."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")
pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")

from rosbags.rosbag2 import Reader

from aes_planner.cli import MAX_ERROR_CHARS, main
from aes_planner.messages import GimbalState
from aes_planner.transport.record import Recorder


def _export(capsys, recording, out, *extra) -> tuple[int, str]:
    rc = main(["export", "rosbag2", str(recording), str(out), *extra])
    return rc, capsys.readouterr().err


def _one_error(rc: int, err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert rc == 2 and len(lines) == 1, err
    assert "unexpected" not in lines[0] and len(lines[0]) <= MAX_ERROR_CHARS + 1
    return lines[0]


def _states(path, stamps_s, log_ns=None):
    with Recorder(path) as rec:
        for i, t in enumerate(stamps_s):
            rec.write("gimbal/state", GimbalState(0.1 * i, 0.0, 0.0, 0.0, True, stamp_s=t), log_ns or 1_000_000_000 + i)
    return path


@pytest.mark.parametrize("content", [b"", b"\x00" * 64, b"garbage " * 100, b"\x89MCAP0\r\n"])
def test_an_empty_or_garbage_recording_is_an_error_and_leaves_no_bag(tmp_path, capsys, content):
    rec = tmp_path / "run.mcap"
    rec.write_bytes(content)
    rc, err = _export(capsys, rec, tmp_path / "bag")
    _one_error(rc, err)
    assert not (tmp_path / "bag").exists()


def test_a_recording_without_a_bridgeable_message_is_an_error(tmp_path, capsys):
    rec = tmp_path / "run.mcap"
    with Recorder(rec):
        pass  # a valid recording with nothing in it
    rc, err = _export(capsys, rec, tmp_path / "bag")
    assert "no message" in _one_error(rc, err)
    assert not (tmp_path / "bag").exists()


@pytest.mark.parametrize("stamp_s", [2e10, 1e11, 1e300, 2.0**31, -1.0])
def test_stamps_no_bag_holds_are_refused_and_said(tmp_path, capsys, stamp_s):
    rec = _states(tmp_path / "run.mcap", [stamp_s])
    rc, err = _export(capsys, rec, tmp_path / "bag")
    assert "not a time" in _one_error(rc, err)
    assert not (tmp_path / "bag").exists()


def test_a_bad_stamp_among_good_ones_is_left_out_with_a_warning(tmp_path, capsys, caplog):
    rec = _states(tmp_path / "run.mcap", [1.0, 2e10, 2.0])
    assert main(["export", "rosbag2", str(rec), str(tmp_path / "bag")]) == 0
    with Reader(tmp_path / "bag") as reader:
        stamps = [t for c, t, _ in reader.messages() if c.topic == "/gimbal/joint_states"]
        assert reader.start_time < 2**31 * 10**9 and reader.end_time < 2**31 * 10**9  # not the year 2263
    assert stamps == [1_000_000_000, 2_000_000_000]
    assert "refused for their stamps" in caplog.text


def test_log_times_beyond_int64_nanoseconds_are_refused(tmp_path, capsys):
    rec = _states(tmp_path / "run.mcap", [1.0], log_ns=2**63 - 1)
    # the header stamp is fine, the log time (the fallback for header-less messages) is not a time
    rc, err = _export(capsys, rec, tmp_path / "bag")
    assert "not a time" in _one_error(rc, err)


@pytest.mark.parametrize("kind", ["dangling", "to-a-folder", "file", "folder"])
def test_an_output_that_exists_or_is_a_symlink_is_refused_before_any_work(tmp_path, capsys, kind):
    rec = _states(tmp_path / "run.mcap", [1.0])
    out = tmp_path / "bag"
    elsewhere = tmp_path / "elsewhere"
    if kind == "dangling":
        os.symlink(elsewhere, out)
    elif kind == "to-a-folder":
        elsewhere.mkdir()
        os.symlink(elsewhere, out)
    elif kind == "file":
        out.write_text("x")
    else:
        out.mkdir()
    rc, err = _export(capsys, rec, out)
    assert "OUT_DIR" in _one_error(rc, err)
    assert not elsewhere.exists() or not any(elsewhere.iterdir())


def test_a_huge_frame_id_in_the_config_is_echoed_capped(tmp_path, capsys):
    rec = _states(tmp_path / "run.mcap", [1.0])
    cfg = tmp_path / "bridge.yaml"
    cfg.write_text("world_frame: " + "m" * 10_000 + "\n")
    rc, err = _export(capsys, rec, tmp_path / "bag", "--config", str(cfg))
    line = _one_error(rc, err)
    assert "characters cut" in line
