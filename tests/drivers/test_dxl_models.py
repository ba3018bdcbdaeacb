"""Control tables as data, two's complement, the tick <-> radian map and the driver config."""

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.config import ConfigError, from_dict
from aes_planner.drivers import dynamixel_models as dm
from aes_planner.drivers.dynamixel import DynamixelPanTiltConfig, EmulatedPanTiltConfig
from tests.helpers import run_python_without

# (address, size) of the items the driver and emulator rely on, as in the ROBOTIS e-manual's
# XM430/XL430 control tables (typed in here independently of dynamixel_models).
REFERENCE_ITEMS = {
    "model_number": (0, 2),
    "id": (7, 1),
    "baud_rate": (8, 1),
    "drive_mode": (10, 1),
    "operating_mode": (11, 1),
    "homing_offset": (20, 4),
    "temperature_limit": (31, 1),
    "velocity_limit": (44, 4),
    "max_position_limit": (48, 4),
    "min_position_limit": (52, 4),
    "torque_enable": (64, 1),
    "led": (65, 1),
    "status_return_level": (68, 1),
    "hardware_error_status": (70, 1),
    "bus_watchdog": (98, 1),
    "profile_acceleration": (108, 4),
    "profile_velocity": (112, 4),
    "goal_position": (116, 4),
    "moving": (122, 1),
    "moving_status": (123, 1),
    "present_velocity": (128, 4),
    "present_position": (132, 4),
    "present_input_voltage": (144, 2),
    "present_temperature": (146, 1),
}


@pytest.mark.parametrize("name, number", [("XM430-W350", 1020), ("XL430-W250", 1060)])
def test_models_match_the_reference(name, number):
    model = dm.model_by_name(name.lower())
    assert model.model_number == number and dm.model_by_number(number) is model
    for item, (addr, size) in REFERENCE_ITEMS.items():
        assert (model.item(item).addr, model.item(item).size) == (addr, size), item
    load = "present_current" if name.startswith("XM") else "present_load"
    assert (model.item(load).addr, model.item(load).size, model.item(load).signed) == (126, 2, True)
    # items never overlap, and every one fits the table
    spans = sorted((i.addr, i.addr + i.size) for i in model.table.values())
    assert all(a_end <= b_start for (_, a_end), (b_start, _) in zip(spans, spans[1:]))
    assert spans[-1][1] <= model.table_end


def test_unknown_model_names_the_known_ones():
    with pytest.raises(KeyError, match="xm430-w350"):
        dm.model_by_name("ax-12a")
    assert dm.model_by_number(12) is None


@given(st.sampled_from([1, 2, 4]), st.data())
def test_twos_complement_round_trips(size, data):
    value = data.draw(st.integers(-(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1))
    raw = dm.to_unsigned(value, size)
    assert 0 <= raw < 1 << (8 * size)
    assert dm.to_signed(raw, size) == value


def test_signed_examples():
    assert dm.to_signed(0xFFFFFFFF, 4) == -1
    assert dm.to_signed(0xFFFE, 2) == -2
    assert dm.to_signed(0x7FFFFFFF, 4) == 2**31 - 1


def test_hardware_error_decoding():
    assert dm.decode_hardware_error(0) == ()
    assert dm.decode_hardware_error(0b100000) == ("overload",)
    assert dm.decode_hardware_error(0b111101) == (
        "input voltage",
        "overheating",
        "motor encoder",
        "electrical shock",
        "overload",
    )


def test_calibration_centre_and_quarter_turns():
    cal = dm.JointCalibration(0, 1, (-math.pi, math.pi))
    assert cal.to_ticks(0.0) == 2048 and cal.to_rad(2048) == 0.0
    assert cal.to_ticks(math.pi / 2) == 3072 and cal.to_rad(1024) == pytest.approx(-math.pi / 2)
    flipped = dm.JointCalibration(100, -1, (-1.0, 1.0))
    assert flipped.to_ticks(0.0) == 2148
    assert flipped.to_ticks(math.pi / 4) == 2148 - 512
    assert flipped.to_rad(2148 - 512) == pytest.approx(math.pi / 4)


@given(
    st.integers(-500, 500),
    st.sampled_from([1, -1]),
    st.floats(-2.5, 0.0),
    st.floats(0.01, 2.5),
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6),
)
def test_ticks_never_leave_the_limits(offset, direction, lo, hi, angle):
    cal = dm.JointCalibration(offset, direction, (lo, hi))
    tlo, thi = cal.tick_limits
    ticks = cal.to_ticks(angle)
    assert tlo <= ticks <= thi
    # the tick limits lie inside the limits in radians
    for t in (tlo, thi):
        assert lo - 1e-9 <= cal.to_rad(t) <= hi + 1e-9


def test_calibration_refuses_non_finite():
    cal = dm.JointCalibration(0, 1, (-1.0, 1.0))
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError):
            cal.to_ticks(bad)


def test_profile_units():
    xm = dm.model_by_name("xm430-w350")
    assert xm.velocity_units(0.0) == 0 and xm.acceleration_units(0.0) == 0
    assert xm.velocity_units(60.0) == round(10.0 / 0.229)  # 60 deg/s = 10 rpm
    assert xm.acceleration_units(300.0) == round(300.0 / (214.577 / 10.0))


def test_config_defaults_and_yaml_loading():
    c = from_dict(DynamixelPanTiltConfig, {"port": "/dev/ttyUSB0"})
    assert (c.baud, c.pan_id, c.tilt_id) == (1_000_000, 1, 2)
    c = from_dict(DynamixelPanTiltConfig, {"port": "/dev/x", "tilt_direction": -1, "pan_limits_deg": [-90, 90]})
    assert c.tilt_direction == -1 and c.pan_limits_deg == (-90.0, 90.0)


@pytest.mark.parametrize(
    "data, key",
    [
        ({"port": "/dev/x", "speed": 3}, "gimbal.speed"),
        ({}, "gimbal.port"),
        ({"port": ""}, "gimbal.port"),
        ({"port": "/dev/x", "baud": 12345}, "gimbal.baud"),
        ({"port": "/dev/x", "tilt_id": 1}, "gimbal.tilt_id"),
        ({"port": "/dev/x", "pan_direction": 0}, "gimbal.pan_direction"),
        ({"port": "/dev/x", "pan_limits_deg": [10, -10]}, "gimbal.pan_limits_deg"),
        ({"port": "/dev/x", "tilt_limits_deg": [-100, 10]}, "gimbal.tilt_limits_deg"),
        ({"port": "/dev/x", "pan_limits_deg": [-180, 180]}, "gimbal.pan_limits_deg"),
        ({"port": "/dev/x", "pan_zero_offset_ticks": 1500}, "gimbal.pan_limits_deg"),
        ({"port": "/dev/x", "move_timeout_s": 0}, "gimbal.move_timeout_s"),
        ({"port": "/dev/x", "profile_velocity_deg_s": -1}, "gimbal.profile_velocity_deg_s"),
    ],
)
def test_config_errors_name_the_key(data, key):
    with pytest.raises(ConfigError) as info:
        from_dict(DynamixelPanTiltConfig, data, "gimbal")
    assert info.value.key == key


def test_emulated_config_checks_models_and_ids():
    c = from_dict(EmulatedPanTiltConfig, {})
    assert c.port == "" and c.models == ("xm430-w350", "xm430-w350")
    with pytest.raises(ConfigError, match="models"):
        from_dict(EmulatedPanTiltConfig, {"models": ["xm430-w350", "nope"]})
    with pytest.raises(ConfigError, match="tilt_id"):
        from_dict(EmulatedPanTiltConfig, {"models": ["xm430-w350", "xm430-w350"], "tilt_id": 3})


def test_a_new_model_is_data_only():
    xm = dm.model_by_name("xm430-w350")
    new = dataclasses.replace(xm, name="XM430-TEST", model_number=9999)
    assert new.by_addr[116][0] == "goal_position"  # the address index is rebuilt from the table


def test_servo_facts_live_in_one_place():
    from aes_planner.drivers import dynamixel, dynamixel_config, emulator

    assert dynamixel.EmulatedPanTiltConfig is dynamixel_config.EmulatedPanTiltConfig
    assert dynamixel.SDK_BAUD_RATES is dm.SDK_BAUD_RATES and emulator.BAUD_RATES is dm.BAUD_RATES
    assert set(dm.SDK_BAUD_RATES) <= set(dm.BAUD_RATES.values())
    for model in dm.MODELS:
        assert dm.OperatingMode.POSITION in model.operating_modes
        assert all(isinstance(m, dm.OperatingMode) for m in model.operating_modes)
    assert "XM430-W350 (1020)" in dm.supported_models()
    # the config validates without the SDK (a launch file is checked before any hardware import)
    code = (
        "from aes_planner.drivers.dynamixel_config import DynamixelPanTiltConfig\n"
        "print(DynamixelPanTiltConfig(port='/dev/x').baud)"
    )
    out = run_python_without(("dynamixel_sdk",), code)
    assert out.returncode == 0 and out.stdout.strip() == "1000000", out.stderr


def test_emulated_config_port_is_never_overwritten_to_pass_validation():
    c = EmulatedPanTiltConfig(port="")
    assert c.port == ""
    with pytest.raises(ConfigError, match="port"):
        from_dict(EmulatedPanTiltConfig, {"port": 5})
    with pytest.raises(ConfigError, match="port"):
        DynamixelPanTiltConfig(port="")
