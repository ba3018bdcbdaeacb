"""The hardware-free device interfaces: Device ABC, Gimbal interface, type-word registry."""

import math
from dataclasses import dataclass

import pytest

from aes_planner.config import ConfigError, require
from aes_planner.devices import DEVICE_TYPES, Device, Gimbal, GimbalReading, device_class, make_device, register_device
from tests.helpers import run_python_without


@dataclass
class _ToyConfig:
    speed_rad_s: float = 1.0

    def __post_init__(self):
        require(self.speed_rad_s > 0, "speed_rad_s", "must be > 0")


class _ToyGimbal(Gimbal):
    """A simulated gimbal: the interface is implementable without any hardware."""

    config_class = _ToyConfig

    def __init__(self, config: _ToyConfig):
        self.config, self._on, self._goal, self.log = config, False, (0.0, 0.0), []

    @property
    def connected(self):
        return self._on

    def connect(self):
        self._on = True
        self.log.append("connect")

    def disconnect(self):
        self._on = False
        self.log.append("disconnect")

    def move_to(self, pan_rad, tilt_rad):
        self._goal = (pan_rad, tilt_rad)
        return self._goal

    def state(self):
        return GimbalReading(*self._goal, *self._goal, False, (25.0, 25.0), (), 0.0)

    def wait_until_reached(self, timeout_s=None):
        return self.state()


@pytest.fixture
def toy_type():
    register_device("toy_gimbal", _ToyGimbal)
    yield "toy_gimbal"
    DEVICE_TYPES.pop("toy_gimbal", None)


def test_context_manager_disconnects_even_on_error(toy_type):
    g = make_device({"type": toy_type, "speed_rad_s": 2.0})
    assert isinstance(g, _ToyGimbal) and g.config.speed_rad_s == 2.0
    with pytest.raises(RuntimeError):
        with g:
            assert g.connected
            raise RuntimeError("boom")
    assert g.log == ["connect", "disconnect"] and not g.connected
    g.reboot()  # a no-op by default


def test_state_summary_and_degrees():
    st = GimbalReading(math.radians(10), math.radians(-5), 0.0, 0.0, True, (31.0, 33.0), ("tilt: overload",), 1.0)
    assert st.pan_deg == pytest.approx(10) and st.tilt_deg == pytest.approx(-5)
    assert (
        st.summary()
        == "pan +10.00 deg, tilt -5.00 deg (goal +0.00, +0.00), moving, 31/33 C, hardware error: tilt: overload"
    )


def test_registry_errors_name_the_key(toy_type):
    with pytest.raises(ConfigError) as info:
        make_device({"type": "warp_drive"}, "rig.gimbal")
    assert info.value.key == "rig.gimbal.type" and "dynamixel_pan_tilt" in str(info.value)
    with pytest.raises(ConfigError) as info:
        make_device({"speed_rad_s": 1.0}, "rig.gimbal")
    assert info.value.key == "rig.gimbal.type"
    with pytest.raises(ConfigError) as info:
        make_device({"type": toy_type, "speed_rad_s": -1.0}, "rig.gimbal")
    assert info.value.key == "rig.gimbal.speed_rad_s"
    with pytest.raises(ValueError):
        register_device("not a word", _ToyGimbal)


def test_the_abc_requires_the_whole_interface():
    class Half(Device):
        def connect(self):
            pass

    with pytest.raises(TypeError):
        Half()


def test_real_and_emulated_types_are_registered_without_importing_drivers():
    code = (
        "import aes_planner.devices as d\n"
        "assert {'dynamixel_pan_tilt', 'emulated_pan_tilt'} <= set(d.DEVICE_TYPES)\n"
        "assert not any(m.startswith('aes_planner.drivers') for m in sys.modules)\n"
        "try:\n"
        "    d.device_class('dynamixel_pan_tilt')\n"
        "except d.DeviceError as exc:\n"
        "    print(exc)\n"
    )
    out = run_python_without(("dynamixel_sdk", "serial"), code)
    assert out.returncode == 0, out.stderr
    assert "pip install 'aes-planner[hardware]'" in out.stdout


def test_device_class_resolves_the_driver():
    from aes_planner.drivers.dynamixel import DynamixelPanTilt

    assert device_class("dynamixel_pan_tilt") is DynamixelPanTilt
