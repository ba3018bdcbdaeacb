"""Signals to an ``aes-planner launch`` that drives servos, sent as a service manager or an impatient
user sends them (real signals, to a process started with the default dispositions): every node
stops, the servos are left with torque off (read back from the emulated servos afterwards),
signals that follow wait for that clean-up, and the exit status is 128 + the first signal."""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from aes_planner.drivers.emulator import ServoEmulator
from tests.helpers import wait_for
from tests.transport.conftest import free_port


def _launch_file(tmp_path, device: str, gimbal_extra: str = "") -> str:
    launch = tmp_path / "gimbal.yaml"
    launch.write_text(
        "scene: tabletop:1\n"
        "nodes:\n"
        "  - id: gimbal\n"
        "    type: gimbal\n"
        f"    config: {{rate_hz: 10, device: {device}{gimbal_extra}}}\n"
        "  - id: camera\n"
        "    type: sim_camera\n"
        "    config: {rate_hz: 5, camera: {width: 32, height: 24}}\n"
        "  - id: planner\n"
        "    type: planner\n"
        "    config: {explore_views: 12, preset: fast}\n"
    )
    return str(launch)


def _torque(emu) -> list[bool]:
    with emu.lock:
        return [s.torque_on for _, s in sorted(emu.servos.items())]


def _signal_when_torque_on(proc, emu, signals, gap_s=0.1):
    """Wait until the planner drives the servos, send ``signals`` ``gap_s`` apart, and wait."""
    wait_for(lambda: all(_torque(emu)) or proc.poll() is not None, timeout_s=90.0, poll_s=0.05)
    if proc.poll() is not None or not all(_torque(emu)):
        out, err = proc.communicate(timeout=30) if proc.poll() is not None else ("", "")
        raise AssertionError(
            f"the planner never moved the gimbal (exit {proc.returncode}): {out[-2000:]} {err[-2000:]}"
        )
    for i, sig in enumerate(signals):
        if i:
            time.sleep(gap_s)
        os.kill(proc.pid, sig)
    return proc.communicate(timeout=60)


@pytest.mark.parametrize(
    ("signals", "gap_s"),
    [
        # one SIGTERM is the first half of the next case: `make bench`
        pytest.param((signal.SIGTERM,), 0.0, marks=pytest.mark.slow),
        ((signal.SIGTERM, signal.SIGTERM), 0.1),  # a script's kill, kill
        ((signal.SIGINT, signal.SIGINT), 0.1),  # Ctrl-C, Ctrl-C
        ((signal.SIGTERM, signal.SIGINT, signal.SIGTERM), 0.005),  # landing inside the clean-up
    ],
    ids=["sigterm", "sigterm-twice", "sigint-twice", "three-in-the-cleanup"],
)
def test_signals_leave_torque_off_and_exit_with_the_first(tmp_path, signals, gap_s):
    link = tmp_path / "ttyDXL"
    launch = _launch_file(tmp_path, f"{{type: dynamixel_pan_tilt, port: {link}, latency_timer_ms: 100}}")
    with ServoEmulator(link=link) as emu:
        proc = subprocess.Popen(
            [sys.executable, "-m", "aes_planner", "launch", launch],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            out, err = _signal_when_torque_on(proc, emu, signals, gap_s)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert emu.wait_idle(), "the emulator did not catch up with what the launch sent"
        assert _torque(emu) == [False, False], err
    assert proc.returncode == 128 + signals[0], (proc.returncode, err)  # not 0: a script can tell
    assert f"stopped by {signal.Signals(signals[0]).name}" in out
    assert "Traceback" not in err and "terminate called" not in err, err


def _supervised(launch) -> subprocess.Popen:
    """``aes-planner launch FILE --processes`` on a free hub port, its output piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "aes_planner", "launch", launch, "--processes"]
        + ["--listen", f"tcp/127.0.0.1:{free_port()}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_two_sigterms_to_a_supervised_launch(tmp_path):
    """``--processes``: the supervisor stops its children (the gimbal's torque-off) whatever follows."""
    link = tmp_path / "ttyDXL"
    launch = _launch_file(tmp_path, f"{{type: dynamixel_pan_tilt, port: {link}, latency_timer_ms: 100}}")
    with ServoEmulator(link=link) as emu:
        proc = _supervised(launch)
        try:
            out, err = _signal_when_torque_on(proc, emu, (signal.SIGTERM, signal.SIGTERM))
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert emu.wait_idle(), "the emulator did not catch up with what the launch sent"
        assert _torque(emu) == [False, False], out + err
    assert proc.returncode == 143, (proc.returncode, out, err)
    # the gimbal's process stopped by itself, cleanly (a planner busy in a suggestion on a loaded host
    # may outlast the supervisor's grace and be killed: that is the supervisor's documented rule)
    died = next((ln for ln in out.splitlines() if "nodes that died" in ln), "")
    assert "gimbal" not in died and "gimbal did not stop" not in out, out
    assert "Traceback" not in out + err and "terminate called" not in out + err


def test_two_sigterms_to_the_gimbal_process_of_a_supervised_launch(tmp_path):
    """A node process signalled directly (a user's ``kill PID``, twice): it finishes its torque-off,
    exits 143, and the supervisor reports it gone and ends the launch."""
    link = tmp_path / "ttyDXL"
    launch = _launch_file(tmp_path, f"{{type: dynamixel_pan_tilt, port: {link}, latency_timer_ms: 100}}")
    with ServoEmulator(link=link) as emu:
        proc = _supervised(launch)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        try:
            wait_for(lambda: all(_torque(emu)) or proc.poll() is not None, timeout_s=90.0, poll_s=0.05)
            assert all(_torque(emu)), "".join(lines)
            (pid,) = [int(ln.split("pid ")[1].rstrip(")\n")) for ln in lines if "started gimbal (pid" in ln]
            os.kill(pid, signal.SIGTERM)
            time.sleep(0.1)
            os.kill(pid, signal.SIGTERM)
            proc.wait(60)
            reader.join(10)
            err = proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert emu.wait_idle(), "the emulator did not catch up with what the launch sent"
        assert _torque(emu) == [False, False], "".join(lines) + err
    out = "".join(lines)
    assert "gimbal died (exit code 143)" in out and "ending the launch: gimbal is gone" in out, out
    assert proc.returncode == 1 and "Traceback" not in out + err, (proc.returncode, out, err)


def test_two_sigterms_with_the_emulator_in_a_child_process(tmp_path):
    """``emulate: true`` (the shipped sim launch's gimbal): the driver's torque-off reaches the
    emulator before it stops, and the emulator reports the servos' torque as it exits."""
    launch = _launch_file(tmp_path, "{type: dynamixel_pan_tilt, latency_timer_ms: 100}, emulate: true")
    proc = subprocess.Popen(
        [sys.executable, "-m", "aes_planner", "-v", "launch", launch],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []  # -v: the driver's "torque on" and the emulator's last word arrive on stderr
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        wait_for(lambda: any("torque on:" in ln for ln in lines) or proc.poll() is not None, timeout_s=90.0)
        assert proc.poll() is None, "".join(lines)
        os.kill(proc.pid, signal.SIGTERM)
        time.sleep(0.1)
        os.kill(proc.pid, signal.SIGTERM)
        proc.wait(60)
        reader.join(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = "".join(lines)
    assert proc.returncode == 143, (proc.returncode, err[-3000:])
    assert "terminate called" not in err and "Traceback" not in err, err[-3000:]
    assert "servo emulator stopped: torque off on id 1, id 2" in err, err[-3000:]


def test_two_sigterms_to_the_demo(tmp_path):
    """``demo`` (the shipped sim launch: the driver on the emulator in a child process) stops,
    unscored, with the servos left with torque off and 143."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "aes_planner", "-v", "demo", "--scene", "tabletop:1", "--moves", "1"]
        + ["--out", str(tmp_path / "run"), "--set", "planner.preset=fast"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []  # one reader per pipe: communicate() beside a reader would split lines
    printed: list[str] = []
    readers = [
        threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True),
        threading.Thread(target=lambda: printed.extend(proc.stdout), daemon=True),
    ]
    for r in readers:
        r.start()
    try:
        wait_for(lambda: any("torque on:" in ln for ln in lines) or proc.poll() is not None, timeout_s=120.0)
        assert proc.poll() is None, "".join(lines)
        os.kill(proc.pid, signal.SIGTERM)
        time.sleep(0.1)
        os.kill(proc.pid, signal.SIGTERM)
        proc.wait(60)
        for r in readers:
            r.join(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    err, out = "".join(lines), "".join(printed)
    assert proc.returncode == 143, (proc.returncode, out, err[-3000:])
    assert "demo: stopped by SIGTERM" in out and not (tmp_path / "run" / "summary.json").exists()
    assert "servo emulator stopped: torque off on id 1, id 2" in err, err[-3000:]
    assert "terminate called" not in err and "Traceback" not in err, err[-3000:]
