"""Every time-like knob and every profile value has a bound at the config boundary, and every wait
honours its timeout: no value that passes validation hangs a command or wraps a register."""

import math
import time
import types

import pytest

import aes_planner.drivers.dynamixel as dxl
from aes_planner.config import ConfigError, from_dict
from aes_planner.devices import GimbalCommError, GimbalTimeoutError
from aes_planner.drivers import dynamixel_models as dm
from aes_planner.drivers.dynamixel import DynamixelPanTiltConfig

KNOBS = {
    "poll_interval_s": dxl.MAX_POLL_INTERVAL_S,
    "latency_timer_ms": dxl.MAX_LATENCY_TIMER_MS,
    "backoff_s": dxl.MAX_BACKOFF_S,
    "move_timeout_s": dxl.MAX_MOVE_TIMEOUT_S,
    "reboot_timeout_s": dxl.MAX_REBOOT_TIMEOUT_S,
    "arrival_tolerance_deg": dxl.MAX_ARRIVAL_TOLERANCE_DEG,
}


@pytest.mark.parametrize("name", sorted(KNOBS))
@pytest.mark.parametrize("factor", [1.0, 1.0001, 1e6])
def test_time_like_knobs_have_an_upper_bound(name, factor):
    value = KNOBS[name] * factor
    if factor == 1.0:
        assert getattr(DynamixelPanTiltConfig(port="/dev/x", **{name: value}), name) == value
        return
    with pytest.raises(ConfigError, match="must be at most") as info:
        from_dict(DynamixelPanTiltConfig, {"port": "/dev/x", name: value}, "gimbal")
    assert info.value.key == f"gimbal.{name}"


@pytest.mark.parametrize(
    "name, value",
    [
        ("profile_velocity_deg_s", 1e30),
        ("profile_velocity_deg_s", 1e6),
        ("profile_acceleration_deg_s2", 1e30),
        ("profile_acceleration_deg_s2", 1e9),
    ],
)
def test_profile_values_that_would_wrap_the_registers_are_refused(name, value):
    with pytest.raises(ConfigError, match="register range") as info:
        from_dict(DynamixelPanTiltConfig, {"port": "/dev/x", name: value}, "gimbal")
    assert info.value.key == f"gimbal.{name}"


def test_the_largest_accepted_profile_fits_every_model():
    vel = min(m.max_profile_velocity_deg_s for m in dm.MODELS)
    acc = min(m.max_profile_acceleration_deg_s2 for m in dm.MODELS)
    DynamixelPanTiltConfig(port="/dev/x", profile_velocity_deg_s=vel, profile_acceleration_deg_s2=acc)
    for m in dm.MODELS:
        assert 0 < m.velocity_units(vel) <= m.item("profile_velocity").hi
        assert 0 < m.acceleration_units(acc) <= m.item("profile_acceleration").hi
        for bad in (1e30, math.inf, math.nan):
            with pytest.raises(ValueError):
                m.velocity_units(bad)
            with pytest.raises(ValueError):
                m.acceleration_units(bad)
        assert m.velocity_units(1e-30) == 1  # tiny but positive is the slowest speed, never "no limit"


def test_a_register_value_out_of_range_is_never_written(gimbal):
    with pytest.raises(dxl.DeviceError, match="range is 0..32767"):
        gimbal._write_item("pan", "profile_velocity", 2**32)  # would wrap to 0 = no limit


def test_wait_honours_its_timeout_with_the_slowest_poll(emulator, make_gimbal, monkeypatch):
    slept = []

    def sleep(dt):
        slept.append(dt)
        time.sleep(dt)

    monkeypatch.setattr(dxl, "time", types.SimpleNamespace(monotonic=time.monotonic, time=time.time, sleep=sleep))
    with make_gimbal(emulator.port, poll_interval_s=dxl.MAX_POLL_INTERVAL_S, profile_velocity_deg_s=5.0) as g:
        g.move_to(math.radians(90), 0.0)
        with pytest.raises(GimbalTimeoutError):
            g.wait_until_reached(0.2)
        # never a whole 1 s poll interval past the 0.2 s deadline: the last wait is cut short
        assert slept and sum(slept) <= 0.25 and max(slept) <= 0.2 + 1e-6  # (+ a retry backoff or two)
        with pytest.raises(ConfigError, match="timeout_s"):
            g.wait_until_reached(1e9)


def test_retry_waits_are_capped(emulator, make_gimbal, monkeypatch):
    waits = []
    fake_time = types.SimpleNamespace(monotonic=time.monotonic, time=time.time, sleep=waits.append)
    g = make_gimbal(emulator.port, backoff_s=dxl.MAX_BACKOFF_S, retries=6)
    g.connect()
    monkeypatch.setattr(dxl, "time", fake_time)
    emulator.faults.drop_next = 100
    with pytest.raises(GimbalCommError):
        g.state()
    emulator.faults.drop_next = 0
    assert len(waits) == 6 and max(waits) <= dxl.MAX_BACKOFF_S  # doubling alone would reach 32 s
