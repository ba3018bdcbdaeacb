"""The clamp rule (docs/architecture.md, "Rules no floor breaks"): a joint command is clamped once,
by ``JointLimits.clamp``, in whatever drives the joints (a ``Gimbal`` device, or the ROS 2 bridge's
outbound command); everything before it only checks and refuses (``JointLimits.check``)."""

import ast
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.geometry.rig import JOINT_LIMIT_TOLERANCE_RAD, JointCommandError, JointLimits

ROOT = Path(__file__).resolve().parents[1]
#: The only files that may call a two-argument ``.clamp(pan, tilt)``: the devices (the one clamp),
#: the ROS 2 bridge's outbound command (where ROS 2 drives the joints), the limits' own module
#: and the kinematics, whose inverse solution is a pose's joints, not a command.
CLAMPERS = {
    "drivers/dynamixel.py",
    "drivers/sim_gimbal.py",
    "aes_planner/ros2/inbound.py",
    "aes_planner/geometry/rig.py",
    "aes_planner/geometry/pantilt.py",
}


#: Words in the name of what holds joint limits (a ``JointLimits``, a ``PanTilt``, a platform, a
#: rig); a tensor's ``.clamp(lo, hi)`` is held by none of them.
JOINT_HOLDERS = ("limit", "kin", "platform", "rig", "pan_tilt", "gimbal")


def _joint_clamp_calls(path: Path) -> list[int]:
    """Lines of ``<holder>.clamp(pan, tilt)`` calls: two positional arguments, on something whose
    name says it holds joint limits."""
    tree = ast.parse(path.read_text(), str(path))
    return [
        n.lineno
        for n in ast.walk(tree)
        if isinstance(n, ast.Call)
        and isinstance(n.func, ast.Attribute)
        and n.func.attr == "clamp"
        and len(n.args) == 2
        and not n.keywords
        and any(w in ast.unparse(n.func.value).lower() for w in JOINT_HOLDERS)
    ]


def test_nothing_before_the_device_offers_a_joint_clamp():
    from aes_planner.node.gimbal import GimbalNode
    from aes_planner.platform import RigPlatform

    assert not hasattr(RigPlatform, "clamp") and hasattr(RigPlatform, "check")
    assert not hasattr(GimbalNode, "clamp") and hasattr(GimbalNode, "check")


def test_only_the_devices_and_the_bridge_clamp_a_joint_command():
    found = {}
    for folder in ("aes_planner", "drivers", "sim", "ros2"):
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            lines = _joint_clamp_calls(path)
            if lines and rel not in CLAMPERS:
                found[rel] = lines
    assert not found, (
        f"joint commands clamped outside the devices: {found}; check and refuse instead (JointLimits.check)"
    )
    assert _joint_clamp_calls(ROOT / "drivers/dynamixel.py")  # the rule's one clamp is still there


LIMITS = JointLimits((math.radians(-90), math.radians(90)), (math.radians(-30), math.radians(30)))


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_check_returns_the_joints_unchanged_or_refuses(pan, tilt):
    try:
        out = LIMITS.check(pan, tilt)
    except JointCommandError as exc:
        assert not LIMITS.within(pan, tilt, JOINT_LIMIT_TOLERANCE_RAD) or not (
            math.isfinite(pan) and math.isfinite(tilt)
        )
        assert "refusing to move" in str(exc)
        return
    assert out == (pan, tilt)  # never moved inside: that is the device's clamp
    assert LIMITS.within(pan, tilt, JOINT_LIMIT_TOLERANCE_RAD)


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_the_one_clamp_gives_finite_joints_inside_the_limits_or_refuses(pan, tilt):
    try:
        p, t = LIMITS.clamp(pan, tilt)
    except JointCommandError:
        assert not (math.isfinite(pan) and math.isfinite(tilt))
        return
    assert LIMITS.within(p, t, 0.0) and LIMITS.check(p, t) == (p, t)


def test_the_gimbal_node_refuses_beyond_its_launch_limits_and_the_device_clamps_to_its_own():
    """A client's move beyond the gimbal node's launch limits: refused and counted, the device never
    sees it; one inside them but beyond the device's (narrower) limits: the device's clamp, the only
    one. (The planner's refusal: tests/node/test_planner_core.py.)"""
    from aes_planner.drivers.sim_gimbal import SimPanTilt, SimPanTiltConfig
    from aes_planner.messages import GimbalCommand
    from aes_planner.node.gimbal import GimbalNode, GimbalNodeConfig

    dev = SimPanTilt(SimPanTiltConfig(pan_limits_deg=(-45.0, 45.0), tilt_limits_deg=(-20.0, 20.0)))
    node = GimbalNode(GimbalNodeConfig(pan_limits_deg=(-90.0, 90.0), tilt_limits_deg=(-30.0, 30.0)), device=dev)
    node.start()
    try:
        node.step({"gimbal/command": [GimbalCommand("move", math.radians(120), 0.0)]}, 1.0)
        assert node.counters["commands_refused"] == 1 and node.counters["moves"] == 0
        node.step({"gimbal/command": [GimbalCommand("move", math.radians(80), math.radians(-25))]}, 2.0)
        assert node.counters["moves"] == 1
        reading = dev.state()
        assert reading.goal_pan_rad == pytest.approx(math.radians(45))  # the device's clamp, the only one
        assert reading.goal_tilt_rad == pytest.approx(math.radians(-20))
    finally:
        node.stop()
