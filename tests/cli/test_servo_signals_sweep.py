"""Sweep: every ``aes-planner`` subcommand that opens a servo device, sent real signals.

The commands are found from the code (:mod:`tests.cli.servo_entry_points`: what reaches the
device factory, a ``Gimbal`` class, the node factory of a launch file or the supervisor), so a new
command that opens a gimbal is swept without anyone listing it: it fails here until it runs under
``stop_on_signals`` and has a recipe below. Each is driven against the servo emulator with one
SIGTERM, two SIGTERMs and two SIGINTs 0.05 s apart while it holds the servos, and must end with
128 + the first signal and torque read back off on both servos."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from aes_planner.drivers.emulator import ServoEmulator
from aes_planner.graph.signals import stop_on_signals
from tests.cli.servo_entry_points import reaches, servo_entry_points
from tests.helpers import wait_for

pytest.importorskip("dynamixel_sdk")

FOUND = servo_entry_points()

PATTERNS = {
    "sigterm": ((signal.SIGTERM,), 0.0),
    "sigterm-twice": ((signal.SIGTERM, signal.SIGTERM), 0.05),
    "sigint-twice": ((signal.SIGINT, signal.SIGINT), 0.05),
}


def _torque(emu) -> list[bool]:
    with emu.lock:
        return [s.torque_on for _, s in sorted(emu.servos.items())]


def _rig_files(tmp_path: Path, tty: Path) -> list[str]:
    """A launch of the Dynamixel driver on ``tty`` and a video as the camera, its intrinsics, a rig."""
    import cv2

    video = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, (64, 48))
    for i in range(3000):  # five frames a capture: far more captures than a run is given
        writer.write(np.full((48, 64, 3), (i * 7) % 256, np.uint8))
    writer.release()
    (tmp_path / "camera_info.yaml").write_text(
        "image_width: 64\nimage_height: 48\ncamera_name: video\n"
        "camera_matrix: {rows: 3, cols: 3, data: [60, 0, 32, 0, 60, 24, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n"
    )
    (tmp_path / "rig.yaml").write_text("base_xyz_m: [0.0, 0.0, 1.3]\n")
    (tmp_path / "rig_launch.yaml").write_text(
        "nodes:\n"
        "  - id: gimbal\n    type: gimbal\n"
        f"    config: {{device: {{type: dynamixel_pan_tilt, port: {tty}, latency_timer_ms: 100}}}}\n"
        "  - id: camera\n    type: camera\n"
        f"    config: {{device: {video}, calibration: {tmp_path / 'camera_info.yaml'}}}\n"
    )
    return ["--board", "chessboard:9x6:0.03", "--rig", str(tmp_path / "rig.yaml")] + [
        "--launch",
        str(tmp_path / "rig_launch.yaml"),
        "--settle-s",
        "0.05",
    ]


def _graph_launch(tmp_path: Path, tty: Path) -> str:
    launch = tmp_path / "gimbal_launch.yaml"
    launch.write_text(
        "scene: tabletop:1\nnodes:\n"
        f"  - id: gimbal\n    type: gimbal\n    config: {{rate_hz: 10, device: {{type: dynamixel_pan_tilt, port: {tty}, latency_timer_ms: 100}}}}\n"
        "  - id: camera\n    type: sim_camera\n    config: {rate_hz: 5, camera: {width: 32, height: 24}}\n"
        "  - id: planner\n    type: planner\n    config: {explore_views: 12, preset: fast}\n"
    )
    return str(launch)


@dataclass
class Recipe:
    """How to run one entry point against the emulator at ``tty``: its argv, and whether it
    powers the servos (then the signals go once torque is on; else once it talks to them, with
    every reply slowed so that the signals land while it does)."""

    argv: Callable[[Path, Path], list[str]]
    powers: bool = True
    slow: bool = False


SLOW_GIMBAL = "profile_velocity_deg_s: 10.0\nprofile_acceleration_deg_s2: 100.0\nlatency_timer_ms: 100\nretries: 5\n"


def _gimbal_config(tmp_path: Path) -> str:
    cfg = tmp_path / "slow_gimbal.yaml"
    cfg.write_text(SLOW_GIMBAL)
    return str(cfg)


RECIPES: dict[str, Recipe] = {
    "gimbal move": Recipe(
        lambda t, tty: (
            ["gimbal", "move", "--port", str(tty), "--config", _gimbal_config(t)]
            + ["--pan-deg", "90", "--tilt-deg", "0"]
        )
    ),
    "gimbal state": Recipe(
        lambda t, tty: ["gimbal", "state", "--port", str(tty), "--config", _gimbal_config(t)], powers=False
    ),
    "gimbal reboot": Recipe(
        lambda t, tty: ["gimbal", "reboot", "--port", str(tty), "--config", _gimbal_config(t)], powers=False
    ),
    "calibrate rig": Recipe(lambda t, tty: ["calibrate", "rig", *_rig_files(t, tty), "--out", str(t / "out.yaml")]),
    "calibrate verify": Recipe(lambda t, tty: ["calibrate", "verify", *_rig_files(t, tty)]),
    # a graph (covered pattern by pattern in tests/node/test_sigterm.py): swept in `make bench`
    "launch": Recipe(lambda t, tty: ["launch", _graph_launch(t, tty)], slow=True),
    "demo": Recipe(
        lambda t, tty: (
            ["demo", "--scene", "tabletop:1", "--moves", "1", "--clock", "wall", "--out", str(t / "run")]
            + ["--set", "planner.preset=fast", "--set", "gimbal.emulate=false", "--set", f"gimbal.device.port={tty}"]
        ),
        slow=True,
    ),
    "eval loop": Recipe(  # the demo's closed loop per scene x perturbation: a signal ends the evaluation
        lambda t, tty: (
            ["eval", "loop", "--scene", "tabletop:1", "--perturb", "base", "--moves", "1", "--clock", "wall"]
            + ["--out", str(t / "run")]
            + ["--set", "planner.preset=fast", "--set", "gimbal.emulate=false", "--set", f"gimbal.device.port={tty}"]
        ),
        slow=True,
    ),
}


def test_the_finder_finds_the_known_servo_commands_and_not_the_others():
    assert {"gimbal move", "calibrate rig", "calibrate verify", "launch"} <= set(FOUND)
    assert not {"calibrate board", "calibrate camera", "export rosbag2", "drone emulate"} & set(FOUND)


def test_every_servo_entry_point_has_a_signal_recipe():
    missing = sorted(set(FOUND) - set(RECIPES))
    assert not missing, f"{missing} open a servo device: give each a recipe in RECIPES (and run it under drives_servos)"


@pytest.mark.parametrize("name", sorted(FOUND))
def test_every_servo_entry_point_runs_under_stop_on_signals(name):
    func = FOUND[name]
    assert getattr(func, "drives_servos", False) or reaches(func, lambda obj: obj is stop_on_signals), (
        f"`aes-planner {name}` opens a servo device outside stop_on_signals: decorate it with "
        "aes_planner.cli.drives_servos (or run its graph with run_graph)"
    )


#: the entry point swept with every pattern in `make test`; the others run Ctrl-C twice there (a
#: user's usual stop) and every pattern in `make bench`: the signal handling they share is one
#: decorator, and each of them costs a process start per pattern
EVERY_PATTERN = "gimbal move"


def _params():
    for name in sorted(FOUND):
        for pattern in PATTERNS:
            slow = name in RECIPES and RECIPES[name].slow
            slow = slow or (name != EVERY_PATTERN and pattern != "sigint-twice")
            marks = [pytest.mark.slow] if slow else []
            yield pytest.param(name, pattern, id=f"{name.replace(' ', '-')}-{pattern}", marks=marks)


@pytest.mark.parametrize(("name", "pattern"), list(_params()))
def test_signals_leave_the_servos_unpowered(tmp_path, name, pattern):
    if name not in RECIPES:
        pytest.fail(f"no recipe for `aes-planner {name}` (see test_every_servo_entry_point_has_a_signal_recipe)")
    recipe = RECIPES[name]
    signals, gap_s = PATTERNS[pattern]
    tty = tmp_path / "ttyDXL"
    with ServoEmulator(link=tty) as emu:
        argv = recipe.argv(tmp_path, tty)
        if not recipe.powers:
            emu.faults.delay_next, emu.faults.delay_s = 10**6, 0.03  # every reply late: the command takes seconds
        proc = subprocess.Popen(
            [sys.executable, "-m", "aes_planner", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        lines: list[str] = []
        readers = [
            threading.Thread(target=lambda s=s: lines.extend(s), daemon=True) for s in (proc.stdout, proc.stderr)
        ]
        for r in readers:
            r.start()
        try:
            if recipe.powers:
                ready = lambda: all(_torque(emu))  # noqa: E731
            else:
                start = emu.packets_seen
                ready = lambda: emu.packets_seen > start + 2  # noqa: E731
            wait_for(lambda: ready() or proc.poll() is not None, timeout_s=180.0, poll_s=0.02)
            assert proc.poll() is None, f"`{name}` ended before it held the servos: {''.join(lines)[-3000:]}"
            for i, sig in enumerate(signals):
                if i:
                    time.sleep(gap_s)  # the gap between two signals is the case under test
                os.kill(proc.pid, sig)
            proc.wait(90)
            for r in readers:
                r.join(10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        out = "".join(lines)
        assert emu.wait_idle(), "the emulator did not catch up with what the command sent"
        assert _torque(emu) == [False, False], out[-3000:]
    assert proc.returncode == 128 + signals[0], (proc.returncode, out[-3000:])
    assert "Traceback" not in out and "terminate called" not in out, out[-3000:]
