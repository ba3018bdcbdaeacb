"""DynamixelPanTilt against the emulator through the real SDK: every operation."""

import dataclasses
import math
import time

import pytest

from aes_planner.config import ConfigError
from aes_planner.devices import DeviceError, GimbalCommError, GimbalTimeoutError, make_device
from aes_planner.drivers import dynamixel_models as dm
from aes_planner.drivers.dynamixel import DynamixelPanTilt, DynamixelPanTiltConfig, scan
from aes_planner.drivers.emulated import EmulatedPanTilt
from aes_planner.drivers.emulator import ServoEmulator
from aes_planner.geometry.pantilt import JointCommandError


def _goal(emu, dxl_id):
    with emu.lock:
        return emu.servos[dxl_id].get("goal_position")


def test_connect_identifies_and_writes_nothing(emulator, gimbal):
    assert gimbal.connected
    assert gimbal.models == {"pan": "XM430-W350", "tilt": "XM430-W350"}
    with emulator.lock:
        for servo in emulator.servos.values():
            assert not servo.torque_on
            assert (servo.get("min_position_limit"), servo.get("max_position_limit")) == (0, 4095)
    assert emulator.goal_log == []


def test_move_takes_control_and_arrives(emulator, gimbal):
    pan, tilt = gimbal.move_to(math.radians(20), math.radians(-10))
    assert (pan, tilt) == (math.radians(20), math.radians(-10))
    st = gimbal.wait_until_reached(3.0)
    assert st.pan_deg == pytest.approx(20, abs=0.1) and st.tilt_deg == pytest.approx(-10, abs=0.1)
    assert not st.moving and st.hardware_error == () and st.temperature_c == (30.0, 30.0)
    assert _goal(emulator, 1) == 2048 + round(20 / 360 * 4096)
    assert _goal(emulator, 2) == 2048 - round(10 / 360 * 4096)
    pan_lo, pan_hi = gimbal.config.calibration("pan").tick_limits
    with emulator.lock:
        pan, tilt = emulator.servos[1], emulator.servos[2]
        assert pan.torque_on and tilt.torque_on
        assert pan.get("operating_mode") == 3
        assert (pan.get("min_position_limit"), pan.get("max_position_limit")) == (pan_lo, pan_hi)
        assert (tilt.get("min_position_limit"), tilt.get("max_position_limit")) == gimbal.config.calibration(
            "tilt"
        ).tick_limits


def test_profile_is_written_from_degrees(emulator, make_gimbal):
    g = make_gimbal(emulator.port, profile_velocity_deg_s=60.0, profile_acceleration_deg_s2=300.0)
    with g:
        g.move_to(0.0, 0.0)
        with emulator.lock:
            assert emulator.servos[1].get("profile_velocity") == round(10 / 0.229)
            assert emulator.servos[2].get("profile_acceleration") == round(300 / 21.4577)


def test_state_reports_motion_and_goal(emulator, make_gimbal):
    g = make_gimbal(emulator.port, profile_velocity_deg_s=30.0, profile_acceleration_deg_s2=0.0)
    with g:
        g.move_to(math.radians(10), 0.0)
        st = g.state()
        assert st.moving and st.goal_pan_rad == pytest.approx(math.radians(10), abs=1e-3)
        assert abs(st.pan_rad) < math.radians(10)
        assert g.wait_until_reached(3.0).pan_deg == pytest.approx(10, abs=0.1)


def test_direction_and_zero_offset(emulator, make_gimbal):
    g = make_gimbal(emulator.port, pan_direction=-1, pan_zero_offset_ticks=100, tilt_zero_offset_ticks=-50)
    with g:
        g.move_to(math.radians(45), math.radians(0))
        st = g.wait_until_reached(3.0)
        assert _goal(emulator, 1) == 2048 + 100 - 512
        assert _goal(emulator, 2) == 2048 - 50
        assert st.pan_deg == pytest.approx(45, abs=0.1) and st.tilt_deg == pytest.approx(0, abs=0.1)


def test_commands_are_clamped_to_the_limits(emulator, gimbal):
    pan, tilt = gimbal.move_to(10.0, -10.0)
    assert (pan, tilt) == (math.radians(150), math.radians(-60))
    gimbal.state()  # round trip: the emulator has taken the sync write
    assert _goal(emulator, 1) == gimbal.config.calibration("pan").tick_limits[1]
    assert _goal(emulator, 2) == gimbal.config.calibration("tilt").tick_limits[0]


@pytest.mark.parametrize("bad", [(math.nan, 0.0), (0.0, math.inf), (-math.inf, 0.0), ("x", 0.0), (10**400, 0.0)])
def test_non_finite_commands_are_refused_and_never_sent(emulator, gimbal, bad):
    seen = emulator.packets_seen
    with pytest.raises(JointCommandError, match="refusing to move"):
        gimbal.move_to(*bad)
    assert emulator.packets_seen == seen and emulator.goal_log == []


def test_wait_times_out_with_an_error(emulator, make_gimbal):
    g = make_gimbal(emulator.port, profile_velocity_deg_s=1.0)
    with g:
        g.move_to(math.radians(30), 0.0)
        with pytest.raises(GimbalTimeoutError, match="did not reach its goal within 0.1 s"):
            g.wait_until_reached(0.1)
        with pytest.raises(ValueError):
            g.wait_until_reached(math.nan)


def test_a_servo_that_rebooted_behind_the_driver_is_taken_again(emulator, gimbal):
    """A supply dip (or another program's REBOOT) leaves a servo with torque off: it takes goals
    and never moves. The next move notices and turns torque on again (it waited forever before)."""
    gimbal.move_to(math.radians(20), math.radians(-10))
    gimbal.wait_until_reached(3.0)
    gimbal.move_to(math.radians(25), math.radians(-10))  # torque still on: nothing to retake
    gimbal.wait_until_reached(3.0)
    assert gimbal.torque_losses == 0
    with emulator.lock:
        emulator.servos[2].reboot()  # tilt: RAM defaults, torque off, holding where it stands
    time.sleep(0.1)  # past the servo's boot time
    gimbal.move_to(math.radians(-15), math.radians(5))
    st = gimbal.wait_until_reached(3.0)
    assert st.pan_deg == pytest.approx(-15, abs=0.1) and st.tilt_deg == pytest.approx(5, abs=0.1)
    assert gimbal.torque_losses == 1
    with emulator.lock:
        assert all(s.torque_on for s in emulator.servos.values())


def test_disconnect_turns_torque_off_and_is_idempotent(emulator, make_gimbal):
    g = make_gimbal(emulator.port)
    with g:
        g.move_to(0.1, 0.1)
        with emulator.lock:
            assert all(s.torque_on for s in emulator.servos.values())
    assert not g.connected
    with emulator.lock:
        assert not any(s.torque_on for s in emulator.servos.values())
    g.disconnect()
    with pytest.raises(DeviceError, match="not connected"):
        g.state()


def test_eeprom_mismatch_is_fixed_with_torque_off_first(emulator, make_gimbal):
    with emulator.lock:  # left behind by another program: torque on, wrong limits
        servo = emulator.servos[1]
        servo.set("torque_enable", 1)
        servo.set("max_position_limit", 4095)
        servo.set("operating_mode", 4)
    with make_gimbal(emulator.port) as g:
        g.move_to(0.2, 0.0)
        g.wait_until_reached(3.0)
        with emulator.lock:
            assert servo.get("operating_mode") == 3
            assert servo.get("max_position_limit") == g.config.calibration("pan").tick_limits[1]
            assert servo.torque_on


def test_unknown_model_is_refused_with_a_hint(emulator, make_gimbal):
    with emulator.lock:
        servo = emulator.servos[2]
        servo.model = dataclasses.replace(servo.model, model_number=4242)
    g = make_gimbal(emulator.port)
    with pytest.raises(DeviceError, match="model number 4242.*dynamixel_models.py"):
        g.connect()
    assert not g.connected


def test_a_new_model_works_from_data_alone(monkeypatch, make_gimbal):
    xm = dm.model_by_name("xm430-w350")
    new = dataclasses.replace(xm, name="XM430-TEST", model_number=4321, firmware_version=50)
    monkeypatch.setattr(dm, "MODELS", dm.MODELS + (new,))
    with ServoEmulator(["xm430-test", "xl430-w250"]) as emu, make_gimbal(emu.port) as g:
        assert g.models == {"pan": "XM430-TEST", "tilt": "XL430-W250"}
        g.move_to(0.3, -0.3)
        st = g.wait_until_reached(3.0)
        assert st.pan_rad == pytest.approx(0.3, abs=2e-3) and st.tilt_rad == pytest.approx(-0.3, abs=2e-3)


def test_missing_servo_and_missing_port_say_what_to_check(emulator, tmp_path, make_gimbal):
    g = make_gimbal(emulator.port, tilt_id=5)
    with pytest.raises(GimbalCommError, match="no valid reply from id 5.*There is no status packet.*baud"):
        g.connect()
    with pytest.raises(GimbalCommError, match="cannot open serial port"):
        make_gimbal(str(tmp_path / "ttyUSB9")).connect()


def test_scan_lists_ids_models_firmware(emulator):
    found = scan(emulator.port, 1_000_000)
    assert [(r.dxl_id, r.model_number, r.model_name, r.firmware_version) for r in found] == [
        (1, 1020, "XM430-W350", 45),
        (2, 1020, "XM430-W350", 45),
    ]
    with pytest.raises(GimbalCommError, match="no servo answered.*57600"):
        scan(emulator.port, 57_600)


def test_launch_type_words_switch_implementations(emulator, fast):
    real = make_device({"type": "dynamixel_pan_tilt", "port": emulator.port, **fast})
    assert isinstance(real, DynamixelPanTilt) and not isinstance(real, EmulatedPanTilt)
    emulated = make_device({"type": "emulated_pan_tilt", "models": ["xm430-w350", "xl430-w250"], **fast})
    assert isinstance(emulated, EmulatedPanTilt)
    with emulated:
        assert emulated.models == {"pan": "XM430-W350", "tilt": "XL430-W250"}
        emulated.move_to(0.2, 0.1)
        assert emulated.wait_until_reached(3.0).tilt_rad == pytest.approx(0.1, abs=2e-3)
        emu = emulated.emulator
    assert emulated.emulator is None and emu.pty_path is None  # stopped with the device
    with pytest.raises(ConfigError) as info:
        make_device({"type": "dynamixel_pan_tilt", "port": "/dev/x", "bauds": 1}, "rig.gimbal")
    assert info.value.key == "rig.gimbal.bauds"


def test_config_is_a_dynamixel_config():
    with pytest.raises(TypeError):
        DynamixelPanTilt({"port": "/dev/x"})
    assert DynamixelPanTiltConfig(port="/dev/x").baud == 1_000_000
