"""The two-shell check: ``aes-planner gimbal emulate`` in a process, scan/move/state on its pty."""

import signal

import pytest

from aes_planner.cli import main
from aes_planner.drivers.emulator import EmulatorProcess


@pytest.fixture
def patient(tmp_path):
    """``--config`` for a loaded CI machine: the emulator is another process that may wait for a
    CPU; a 16 ms latency timer (2 x 16 + 2 ms per reply) and 3 retries are too tight there."""
    cfg = tmp_path / "patient.yaml"
    cfg.write_text("latency_timer_ms: 100\nretries: 5\n")
    return ["--config", str(cfg)]


@pytest.fixture
def emulate(tmp_path):
    """``aes-planner gimbal emulate`` in a separate process; yields (process, pty path, link)."""
    link = tmp_path / "ttyDXL"
    with EmulatorProcess(args=["--link", str(link)]) as emulator:
        assert emulator.port.startswith("/dev/pts/"), emulator.port
        yield emulator, emulator.port, link


def test_emulate_scan_move_state(emulate, patient, capsys):
    proc, port, link = emulate
    assert main(["gimbal", "scan", "--port", port]) == 0
    out = capsys.readouterr().out
    assert "2 servo(s)" in out and "id   1  model  1020 XM430-W350    firmware 45" in out and "id   2" in out

    assert main(["gimbal", "move", "--port", port, "--pan-deg", "25", "--tilt-deg", "-12", *patient]) == 0
    out = capsys.readouterr().out
    assert "moving to pan +25.00 deg, tilt -12.00 deg" in out and "arrived: pan +24.96 deg, tilt -12.04 deg" in out

    assert main(["gimbal", "state", "--port", str(link), *patient]) == 0  # the symlink works as well
    out = capsys.readouterr().out
    assert "pan XM430-W350, tilt XM430-W350" in out and "pan +24.96 deg, tilt -12.04 deg" in out and "still" in out

    assert main(["gimbal", "move", "--port", port, "--pan-deg", "400", "--tilt-deg", "0", *patient]) == 0
    assert "(clamped to the joint limits)" in capsys.readouterr().out

    assert main(["gimbal", "reboot", "--port", port, *patient]) == 0
    assert "no hardware error was latched" in capsys.readouterr().out

    proc.proc.send_signal(signal.SIGTERM)
    assert proc.proc.wait(10) == 0  # a clean exit, not killed
    assert not link.exists()


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["gimbal", "move", "--port", "P", "--pan-deg", "nan", "--tilt-deg", "0"],
            "--pan-deg must be a finite number",
        ),
        (["gimbal", "move", "--pan-deg", "1", "--tilt-deg", "0"], "give the serial port"),
        (["gimbal", "move", "--port", "P", "--tilt-deg", "0"], "give --pan-deg DEGREES"),
        (
            ["gimbal", "move", "--port", "P", "--pan-deg", "1", "--yaw-deg", "1", "--tilt-deg", "0"],
            "give --pan-deg only",
        ),
        (["gimbal", "state", "--port", "/dev/ttyUSB_missing"], "cannot open serial port /dev/ttyUSB_missing"),
        (["gimbal", "state", "--port", "/dev/x", "--baud", "1234"], "baud"),
        (["gimbal", "scan", "--port", "/dev/ttyUSB_missing"], "cannot open serial port"),
        (["gimbal", "emulate", "--models", "ax-12a"], "unknown servo model 'ax-12a'"),
    ],
)
def test_user_errors_are_one_line_and_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_config_file_and_flags_load_into_the_same_dataclass(tmp_path, capsys):
    cfg = tmp_path / "gimbal.yaml"
    cfg.write_text("port: /dev/ttyUSB_missing\ntilt_id: 3\nspeed: 2\n")
    assert main(["gimbal", "state", "--config", str(cfg)]) == 2
    assert f"{cfg}.speed: unknown key" in capsys.readouterr().err


def test_wrong_baud_explains_there_is_no_status_packet(emulate, capsys):
    _, port, _ = emulate
    assert main(["gimbal", "state", "--port", port, "--baud", "57600"]) == 2
    err = capsys.readouterr().err
    assert "There is no status packet!" in err and "--baud matches their Baud Rate register" in err


def test_deprecated_yaw_pitch_flags_still_move_the_joints_and_warn(emulate, patient, capsys):
    _, port, _ = emulate
    assert main(["gimbal", "move", "--port", port, "--yaw-deg", "10", "--pitch-deg", "-5", *patient]) == 0
    captured = capsys.readouterr()
    assert "moving to pan +10.00 deg, tilt -5.00 deg" in captured.out
    assert "--yaw-deg is deprecated, use --pan-deg" in captured.err
    assert "--pitch-deg is deprecated, use --tilt-deg" in captured.err
