"""Bad-input sweep of the Dynamixel gimbal's configuration: emulator arguments end in the emulator's
own one-line error, and a profile velocity is bounded by what the servo can be set to.
"""

import pytest

from tests.helpers import write_file


@pytest.mark.parametrize(
    "args, match",
    [
        ('["--help"]', "emulator_args[0]"),
        ('["--models", "xl430-w250"]', "emulator_args[0]"),
        ('["--seed"]', "emulator_args[0]"),
        ('["--seed", "1e3"]', "invalid int value"),
        ('["--drop-rate", "2"]', "drop_rate"),
        ('["--link", "/nonexistent/folder/pty"]', "does not exist"),
    ],
)
def test_emulator_arguments_end_in_the_emulators_own_error(tmp_path, cli_error, args, match):
    launch = write_file(
        tmp_path,
        "g.yaml",
        "nodes:\n  - id: gimbal\n    type: gimbal\n"
        f"    config: {{emulate: true, emulator_args: {args}, device: {{type: dynamixel_pan_tilt, port: x}}}}\n",
    )
    cli_error(["launch", launch, "--timeout", "3"], match, seconds=20)  # not a 30 s wait


@pytest.mark.parametrize("deg_s", [45001.0, 1500.0, 1e6])
def test_profile_velocity_is_bounded_by_what_the_servo_can_be_set_to(clean_error, deg_s):
    from aes_planner.drivers.dynamixel_config import DynamixelPanTiltConfig

    clean_error(DynamixelPanTiltConfig, port="/dev/x", profile_velocity_deg_s=deg_s, match="profile_velocity_deg_s")
    assert DynamixelPanTiltConfig(port="/dev/x", profile_velocity_deg_s=1400.0).profile_velocity_deg_s == 1400.0
