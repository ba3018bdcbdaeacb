"""Every injected fault, and what the driver does about it."""

import logging
import math
import re
import threading

import dynamixel_sdk as sdk
import pytest

from aes_planner.devices import GimbalCommError, GimbalHardwareError, GimbalPortLostError
from aes_planner.drivers.dynamixel_models import model_by_name
from aes_planner.drivers.emulator import ServoEmulator

PRESENT_POSITION = model_by_name("xm430-w350").item("present_position").addr


def _torque(emu):
    with emu.lock:
        return [s.torque_on for _, s in sorted(emu.servos.items())]


@pytest.mark.parametrize("fault", ["drop_next", "corrupt_next", "truncate_next"])
def test_a_bad_reply_is_retried(emulator, gimbal, caplog, fault):
    gimbal.move_to(0.1, 0.1)
    setattr(emulator.faults, fault, 1)
    seen = emulator.packets_seen
    with caplog.at_level(logging.DEBUG, logger="aes_planner.drivers.dynamixel"):
        st = gimbal.state()
    assert st.goal_pan_rad == pytest.approx(0.1, abs=2e-3)
    assert getattr(emulator.faults, fault) == 0
    assert emulator.packets_seen >= seen + 2  # the sync read went out again
    assert "retry 1/3" in caplog.text


@pytest.mark.parametrize(
    "fault, message", [("drop_next", "There is no status packet"), ("corrupt_next", "Incorrect status packet")]
)
def test_a_dead_bus_is_fatal_torque_goes_off(emulator, gimbal, fault, message):
    gimbal.move_to(0.1, 0.1)
    assert _torque(emulator) == [True, True]
    setattr(emulator.faults, fault, 8)  # the 4 tries of the read (2 replies each) all fail
    with pytest.raises(GimbalCommError, match=message):
        gimbal.state()
    setattr(emulator.faults, fault, 0)
    assert _torque(emulator) == [False, False]
    gimbal.move_to(0.2, 0.2)  # takes control again once the bus answers
    assert gimbal.wait_until_reached(3.0).pan_rad == pytest.approx(0.2, abs=2e-3)


def test_short_status_packets_are_never_trusted(emulator, gimbal):
    # the SDK itself takes the CRC of a short reply for data, or indexes past its end...
    port = sdk.PortHandler(emulator.port)
    assert port.setBaudRate(1_000_000)
    ph = sdk.PacketHandler(2.0)
    try:
        emulator.faults.truncate_next = 1
        value, comm, err = ph.read4ByteTxRx(port, 1, PRESENT_POSITION)
        assert comm == sdk.COMM_SUCCESS and value != 2048  # silently wrong
        with pytest.raises(IndexError):
            ph.read4ByteTxRx(port, 1, 145)  # an access-error status has no data at all
    finally:
        port.is_using = False
        port.closePort()
    # ...the driver retries instead, and leaves the SDK's port usable
    emulator.faults.truncate_next = 1
    assert gimbal._read_item("pan", "present_position") == 2048
    assert not gimbal._port.is_using


def test_is_using_is_reset_after_an_exception_mid_exchange(gimbal, monkeypatch):
    calls = []
    original = gimbal._ph.rxPacket

    def explode_once(*args):
        if not calls:
            calls.append(1)
            raise IndexError("status packet shorter than asked")
        return original(*args)

    monkeypatch.setattr(gimbal._ph, "rxPacket", explode_once)
    assert gimbal.state().pan_rad == 0.0
    assert calls and not gimbal._port.is_using


# The reply timeout is 2 x 100 + 2 ms (FAST); a late reply within it is taken, a later one is
# waited out by the retries (the stale reply then answers a retry of the same read). The late
# reply comes 500 ms late, more than two timeouts' worth, so that a test process starved of CPU
# for a while still finds the first try timed out. The tries end at 202, 405, 609 and 815 ms
# (1 ms backoff, doubling), so it lands in the third.
@pytest.mark.parametrize("delay_s, retried", [(0.002, False), (0.5, True)])
def test_delayed_replies(emulator, gimbal, caplog, delay_s, retried):
    emulator.faults.delay_s = delay_s
    emulator.faults.delay_next = 1
    with caplog.at_level(logging.DEBUG, logger="aes_planner.drivers.dynamixel"):
        assert gimbal._read_item("tilt", "present_position") == 2048
    assert ("There is no status packet!; retry 1/3" in caplog.text) == retried


def test_a_late_reply_never_answers_a_later_instruction(emulator, gimbal, caplog):
    """A reply the driver gave up on (here 500 ms late: a servo behind a loaded USB adapter, an
    emulator starved of CPU) must not be taken for the reply to the next instruction. The SDK takes
    any status of the id: on a loaded CI machine a late reply to a READ of Firmware Version (45)
    came back from a PING as model number 48429 (45 and its CRC's low byte, 0xbd)."""
    emulator.faults.delay_s = 0.5
    emulator.faults.delay_next = 1
    with pytest.raises(GimbalCommError, match="no status packet"):
        gimbal._read_item("pan", "firmware_version", retries=0)  # gives up after 202 ms
    with caplog.at_level(logging.DEBUG, logger="aes_planner.drivers.dynamixel"):
        number, _ = gimbal._exchange("pan", "ping pan", gimbal._ping)  # the late reply comes meanwhile
    assert number == model_by_name("xm430-w350").model_number
    # the late reply was seen and dropped (with the first clearing READ's reply, which came behind it
    # after that READ gave up: the next clearing READ has another length and does not take it)
    assert re.search(r"dropped [12] late replies", caplog.text)
    # and a 1-byte read after a late 1-byte reply gets its own item, not the late one
    emulator.faults.delay_next = 1
    with pytest.raises(GimbalCommError):
        gimbal._read_item("pan", "firmware_version", retries=0)
    assert gimbal._read_item("pan", "hardware_error_status") == 0
    assert gimbal._read_item("pan", "firmware_version") == 45


@pytest.mark.parametrize("fault, servo_id, joint", [("overload", 2, "tilt"), ("overheating", 1, "pan")])
def test_hardware_error_is_reported_and_blocks_motion_until_reboot(emulator, gimbal, fault, servo_id, joint):
    gimbal.move_to(0.1, 0.1)
    gimbal.wait_until_reached(3.0)
    emulator.inject_hardware_error(servo_id, fault)
    st = gimbal.state()
    assert st.hardware_error == (f"{joint}: {fault}",)
    assert gimbal.faults == {joint: (fault,)}
    assert _torque(emulator) == [False, False]  # the faulted one shut down, the other turned off
    if fault == "overheating":
        assert max(st.temperature_c) > 80
    with pytest.raises(GimbalHardwareError, match=f"refusing to move.*{fault}.*reboot") as info:
        gimbal.move_to(0.0, 0.0)
    assert info.value.faults == {joint: (fault,)}
    gimbal.reboot()
    assert gimbal.faults == {} and gimbal.state().hardware_error == ()
    gimbal.move_to(-0.1, -0.1)
    assert gimbal.wait_until_reached(3.0).pan_rad == pytest.approx(-0.1, abs=2e-3)


def test_a_fault_on_the_way_stops_the_wait(emulator, make_gimbal):
    with make_gimbal(emulator.port, profile_velocity_deg_s=20.0) as g:
        g.move_to(math.radians(40), 0.0)
        timer = threading.Timer(0.05, emulator.inject_hardware_error, (1, "overload"))
        timer.start()
        try:
            with pytest.raises(GimbalHardwareError, match="stopped on the way: pan: overload"):
                g.wait_until_reached(3.0)
        finally:
            timer.cancel()
            timer.join(2.0)


def test_a_fault_present_at_connect_is_latched(emulator, make_gimbal):
    emulator.inject_hardware_error(1, "overload")
    with make_gimbal(emulator.port) as g:
        assert g.faults == {"pan": ("overload",)}
        with pytest.raises(GimbalHardwareError):
            g.move_to(0.0, 0.0)


def test_a_vanishing_port_is_reported_and_reconnected(tmp_path, make_gimbal):
    link = tmp_path / "ttyDXL"
    with ServoEmulator(link=link) as emu, make_gimbal(str(link)) as g:
        g.move_to(0.2, 0.0)
        g.wait_until_reached(3.0)
        emu.vanish()
        assert not link.exists()
        with pytest.raises(GimbalPortLostError, match="disappeared"):
            g.state()
        with pytest.raises(GimbalPortLostError, match="still missing"):
            g.move_to(0.0, 0.0)
        emu.restore()
        assert g.state().pan_rad == pytest.approx(0.2, abs=2e-3)  # servos kept their state
        g.move_to(-0.2, 0.0)
        assert g.wait_until_reached(3.0).pan_rad == pytest.approx(-0.2, abs=2e-3)
    assert not link.exists()


def test_flaky_bus_by_rate_still_works(emulator, make_gimbal):
    # a sync read fails with p = 1 - 0.9**4 = 0.34 here; 7 tries all failing: p = 5e-4 per call
    gimbal = make_gimbal(emulator.port, retries=6)
    gimbal.connect()
    emulator.faults.drop_rate = 0.1
    emulator.faults.corrupt_rate = 0.1
    for i in range(20):
        gimbal.move_to(0.01 * i, 0.0)
        gimbal.state()
    emulator.faults.drop_rate = emulator.faults.corrupt_rate = 0.0
    assert gimbal.wait_until_reached(3.0).pan_rad == pytest.approx(0.19, abs=2e-3)
