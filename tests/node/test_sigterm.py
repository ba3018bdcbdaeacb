"""SIGTERM to an ``aes-planner launch`` process that drives servos: it stops every node and
leaves the servos with torque off (the drivers' safe-shutdown helper), then exits."""

import os
import signal
import subprocess
import sys
import time

from aes_planner.drivers.emulator import ServoEmulator


def test_sigterm_leaves_torque_off(tmp_path):
    link = tmp_path / "ttyDXL"
    launch = tmp_path / "gimbal.yaml"
    launch.write_text(
        "scene: tabletop:1\n"
        "nodes:\n"
        "  - id: gimbal\n"
        "    type: gimbal\n"
        f"    config: {{rate_hz: 10, device: {{type: dynamixel_pan_tilt, port: {link}, latency_timer_ms: 30}}}}\n"
        "  - id: camera\n"
        "    type: sim_camera\n"
        "    config: {rate_hz: 5, camera: {width: 32, height: 24}}\n"
        "  - id: planner\n"
        "    type: planner\n"
        "    config: {explore_views: 12, preset: fast}\n"
    )
    with ServoEmulator(link=link) as emu:
        proc = subprocess.Popen(
            [sys.executable, "-m", "aes_planner", "launch", str(launch)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            deadline = time.time() + 60
            while time.time() < deadline:
                with emu.lock:
                    if all(s.torque_on for s in emu.servos.values()):
                        break
                assert proc.poll() is None, proc.communicate()
                time.sleep(0.05)
            with emu.lock:
                assert all(s.torque_on for s in emu.servos.values()), "the planner never moved the gimbal"
            os.kill(proc.pid, signal.SIGTERM)
            out, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        with emu.lock:
            assert not any(s.torque_on for s in emu.servos.values()), err
    assert proc.returncode in (0, 1), err
    assert "Traceback" not in err, err
