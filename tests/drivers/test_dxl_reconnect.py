"""The serial port disappears and comes back: the emulator is stopped and a new
one started on the same path, as a USB adapter unplugged and plugged in again, or a servo bus
that lost power. The driver reports the loss, reopens the port with back-off, takes control again
(limits in EEPROM, profile, torque on) and holds its last goal; the gimbal node reports it in its
diagnostics and loses no move it had accepted."""

import math

import pytest

from aes_planner.devices import GimbalCommError, GimbalPortLostError
from aes_planner.drivers.dynamixel_models import CENTER_TICKS, TICKS_PER_REV
from aes_planner.drivers.emulator import EmulatorProcess, ServoEmulator
from aes_planner.messages import GimbalCommand
from aes_planner.node.gimbal import GimbalNode, GimbalNodeConfig
from tests.helpers import wait_for

from .conftest import FAST


def _state_ok(g) -> bool:
    try:
        g.state()
        return True
    except GimbalPortLostError:
        return False


def _deg(ticks: int) -> float:
    return (ticks - CENTER_TICKS) * 360.0 / TICKS_PER_REV


def test_a_restarted_emulator_is_reconnected_with_torque_limits_and_the_last_goal(tmp_path, make_gimbal):
    link = tmp_path / "ttyDXL"
    g = make_gimbal(str(link), profile_velocity_deg_s=90.0, pan_limits_deg=(-40.0, 40.0), reconnect_backoff_s=0.02)
    emu = ServoEmulator(link=link).start()
    try:
        g.connect()
        g.move_to(0.3, -0.1)
        g.wait_until_reached(3.0)
        emu.stop()  # the bus is gone: the pty closed, the link removed
        with pytest.raises(GimbalPortLostError, match="disappeared"):
            g.state()
        assert g.port_lost and g.port_losses == 1
        with pytest.raises(GimbalPortLostError, match="still missing"):
            g.state()
        # a fresh bus on the same path: servos at power-up (torque off, centred, factory limits)
        emu = ServoEmulator(link=link).start()
        with emu.lock:
            assert not any(s.torque_on for s in emu.servos.values())
        assert wait_for(lambda: _state_ok(g), timeout_s=20.0)  # reopened by a later call, nobody asked
        assert not g.port_lost and g.reconnects == 1 and g.port_losses == 1
        with emu.lock:
            pan, tilt = emu.servos[1], emu.servos[2]
            assert pan.torque_on and tilt.torque_on  # control taken again without a new move
            lo, hi = g.config.calibration("pan").tick_limits
            assert (pan.get("min_position_limit"), pan.get("max_position_limit")) == (lo, hi)
            assert pan.get("profile_velocity") == pan.model.velocity_units(90.0)
            assert _deg(pan.get("goal_position")) == pytest.approx(math.degrees(0.3), abs=0.1)
        st = g.wait_until_reached(5.0)  # the servos return to where they were told to be
        assert st.pan_rad == pytest.approx(0.3, abs=3e-3) and st.tilt_rad == pytest.approx(-0.1, abs=3e-3)
        with emu.lock:
            assert all(lo - 1 <= t <= hi + 1 for i, t in emu.goal_log if i == 1)  # nothing outside the limits
    finally:
        g.disconnect()
        emu.stop()
    assert not link.exists()


def test_a_port_that_is_back_but_silent_is_retried_with_back_off(tmp_path, make_gimbal, monkeypatch):
    """A missing path is checked on every call (one stat); a port that opens but whose servos do
    not answer yet (powering up) costs reply timeouts, so it is tried at most once per back-off wait."""
    import aes_planner.drivers.dynamixel as dxl

    link = tmp_path / "ttyDXL"
    g = make_gimbal(str(link), reconnect_backoff_s=0.05, retries=0)
    opens = []
    real_open = dxl._open_port
    monkeypatch.setattr(dxl, "_open_port", lambda *a: (opens.append(1), real_open(*a))[1])
    with ServoEmulator(link=link) as emu:
        g.connect()
        opens.clear()
        emu.vanish()
        with pytest.raises(GimbalPortLostError, match="disappeared"):
            g.state()
        with pytest.raises(GimbalPortLostError, match="still missing"):
            g.state()
        assert not opens  # nothing opened while the path is gone
        emu.restore()
        with emu.lock:
            emu.faults.drop_next = 10_000  # the servos are silent
        clock = [100.0]
        monkeypatch.setattr(dxl.time, "monotonic", lambda: clock[0])
        tries = []
        for _ in range(200):  # 2 s of calls at 100 Hz
            n = len(opens)
            with pytest.raises(GimbalCommError):
                g.state()
            tries.append(len(opens) > n)
            clock[0] += 0.01
        # at 0, 0.05, 0.15, 0.35, 0.75, 1.55 s (waits doubling from 0.05 s, capped at 2 s): 6 tries, not 200
        assert 5 <= sum(tries) <= 7 and tries[0]
        with emu.lock:
            emu.faults.drop_next = 0
        clock[0] += 2.0  # past any wait
        g.state()
        assert g.reconnects == 1 and g.port_losses == 1
    g.disconnect()


def test_a_hardware_error_found_on_reconnection_keeps_torque_off(tmp_path, make_gimbal):
    link = tmp_path / "ttyDXL"
    g = make_gimbal(str(link), reconnect_backoff_s=0.01)
    emu = ServoEmulator(link=link).start()
    try:
        g.connect()
        g.move_to(0.1, 0.0)
        emu.stop()
        with pytest.raises(GimbalPortLostError):
            g.state()
        emu = ServoEmulator(link=link).start()
        emu.inject_hardware_error(2, "overheating")
        assert wait_for(lambda: _state_ok(g), timeout_s=20.0)
        assert g.faults == {"tilt": ("overheating",)}
        with emu.lock:
            assert not any(s.torque_on for s in emu.servos.values())
    finally:
        g.disconnect()
        emu.stop()


def test_the_gimbal_node_rides_through_an_emulator_process_stopped_and_restarted(tmp_path):
    """The same sequence with the emulator in its own process (`aes-planner gimbal emulate
    --link`): stopped at 4 s, restarted at 8 s; a move that arrives while it is gone is kept."""
    link = str(tmp_path / "ttyDXL")
    device = {"type": "dynamixel_pan_tilt", "port": link, **FAST, "profile_velocity_deg_s": 120.0}
    node = GimbalNode(GimbalNodeConfig(device=device, rate_hz=25.0, diagnostics_period_s=0.0001))
    emu = EmulatorProcess(args=["--link", link]).__enter__()
    clock = {"t": 0.0}

    def step(*cmds):
        clock["t"] += 0.04
        return node.step({"gimbal/command": list(cmds)}, clock["t"])

    try:
        node.start()
        step(GimbalCommand("move", 0.2, 0.05))
        assert wait_for(lambda: bool(step()["gimbal/state"]) and not node.last_state.moving, timeout_s=20.0)
        emu.stop()  # about 4 s in
        assert wait_for(lambda: step()["gimbal/diagnostics"][0].state == "port_lost", timeout_s=20.0)
        step(GimbalCommand("move", -0.25, 0.1))  # accepted while the port is gone
        diag = step()["gimbal/diagnostics"][0]
        assert diag.counters["port_losses"] == 1 and diag.counters["reconnects"] == 0
        emu = EmulatorProcess(args=["--link", link]).__enter__()  # 8 s: a new bus on the same path
        assert wait_for(lambda: step()["gimbal/diagnostics"][0].state == "ok", timeout_s=20.0)

        def arrived() -> bool:
            s = step()["gimbal/state"]
            return bool(s) and not s[0].moving and abs(s[0].pan_rad + 0.25) < 3e-3 and abs(s[0].tilt_rad - 0.1) < 3e-3

        assert wait_for(arrived, timeout_s=20.0)  # the kept move went through once the bus was back
        diag = step()["gimbal/diagnostics"][0]
        assert diag.counters["reconnects"] == 1 and diag.counters["moves"] == 2 and diag.counters["moves_resent"] == 1
    finally:
        node.stop()
        emu.stop()
