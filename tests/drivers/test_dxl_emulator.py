"""The emulator through the real dynamixel-sdk, packet by packet: instructions, error statuses,
control tables, byte stuffing on the wire, baud rate, motion dynamics."""

import os
import subprocess
import sys
import termios
import time

import dynamixel_sdk as sdk
import pytest

from aes_planner.drivers.dynamixel_models import model_by_name, to_signed, to_unsigned
from aes_planner.drivers.emulator import ServoEmulator
from aes_planner.drivers.protocol import ErrNum, Inst, PacketParser, build_packet
from tests.helpers import wait_for

XM = model_by_name("xm430-w350")
A = {name: item.addr for name, item in XM.table.items()}


@pytest.fixture
def bus(emulator):
    """(port handler, packet handler) of the real SDK on the emulator's pty."""
    port = sdk.PortHandler(emulator.port)
    assert port.setBaudRate(1_000_000)
    try:
        yield port, sdk.PacketHandler(2.0)
    finally:
        port.closePort()


def test_ping_reports_model_and_unknown_ids_stay_silent(bus):
    port, ph = bus
    assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)
    assert ph.ping(port, 2)[:2] == (1020, sdk.COMM_SUCCESS)
    assert ph.ping(port, 7)[1] == sdk.COMM_RX_TIMEOUT  # "There is no status packet!"


def test_broadcast_ping_finds_every_servo(bus):
    port, ph = bus
    found, comm = ph.broadcastPing(port)
    assert comm == sdk.COMM_SUCCESS
    assert found == {1: [1020, 45], 2: [1020, 45]}


def test_read_and_write_each_size(bus):
    port, ph = bus
    assert ph.write1ByteTxRx(port, 1, A["led"], 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, A["led"]) == (1, sdk.COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 1, A["position_p_gain"], 1234) == (sdk.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 1, A["position_p_gain"]) == (1234, sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 2, A["profile_velocity"], 77) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 2, A["profile_velocity"]) == (77, sdk.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 1, A["model_number"])[0] == 1020
    # a read spanning several items returns them in one status packet
    data, comm, err = ph.readTxRx(port, 1, A["goal_position"], 31)
    assert comm == sdk.COMM_SUCCESS and len(data) == 31


@pytest.mark.parametrize(
    "addr, size, value, errnum",
    [
        (A["present_position"], 4, 0, ErrNum.ACCESS),  # read-only
        (A["model_number"], 2, 1, ErrNum.ACCESS),  # read-only EEPROM
        (A["torque_enable"], 1, 2, ErrNum.DATA_RANGE),  # 0/1 only
        (A["operating_mode"], 1, 2, ErrNum.DATA_RANGE),  # not a mode of this model
        (A["goal_position"], 2, 100, ErrNum.DATA_LENGTH),  # half of a 4-byte item
        (66, 1, 0, ErrNum.ACCESS),  # undefined address
        (A["goal_position"] + 1, 1, 0, ErrNum.ACCESS),  # the middle of an item
    ],
)
def test_write_errors(bus, addr, size, value, errnum):
    port, ph = bus
    comm, err = ph.writeTxRx(port, 1, addr, size, list(value.to_bytes(size, "little")))
    assert comm == sdk.COMM_SUCCESS and err == errnum


def test_eeprom_is_locked_while_torque_is_on(bus):
    port, ph = bus
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["max_position_limit"], 3000) == (sdk.COMM_SUCCESS, ErrNum.ACCESS)
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 0) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["max_position_limit"], 3000) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, A["max_position_limit"])[0] == 3000


def test_goal_outside_the_position_limits_is_a_data_limit_error(bus):
    port, ph = bus
    assert ph.write4ByteTxRx(port, 1, A["max_position_limit"], 3000) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["goal_position"], 3001) == (sdk.COMM_SUCCESS, ErrNum.DATA_LIMIT)
    assert ph.write4ByteTxRx(port, 1, A["goal_position"], 3000) == (sdk.COMM_SUCCESS, 0)


def test_read_beyond_the_table_is_an_access_error(bus):
    port, ph = bus
    data, comm, err = ph.readTxRx(port, 1, 140, 20)
    assert comm == sdk.COMM_SUCCESS and err == ErrNum.ACCESS
    # the status carries no data, yet the SDK hands back what follows the error byte (the CRC):
    # the reason the driver checks every read's length
    assert len(data) < 20


def test_unsupported_instruction_is_an_instruction_error(bus):
    port, ph = bus
    assert ph.clearMultiTurn(port, 1) == (sdk.COMM_SUCCESS, ErrNum.INSTRUCTION)


def test_a_corrupt_instruction_gets_a_crc_error_status(bus):
    port, ph = bus
    raw = bytearray(build_packet(1, Inst.PING))
    raw[-1] ^= 0xFF
    port.clearPort()
    port.writePort(bytes(raw))
    port.setPacketTimeout(14)
    rx, comm = ph.rxPacket(port, False)
    assert comm == sdk.COMM_SUCCESS and rx[8] == ErrNum.CRC


def test_byte_stuffing_both_ways_through_the_sdk(bus):
    port, ph = bus
    value = to_signed(0xFFFDFFFF, 4)  # little-endian bytes FF FF FD FF: stuffed on the wire
    assert ph.write4ByteTxRx(port, 1, A["homing_offset"], to_unsigned(value, 4)) == (sdk.COMM_SUCCESS, 0)
    raw, comm, err = ph.read4ByteTxRx(port, 1, A["homing_offset"])
    assert (comm, err) == (sdk.COMM_SUCCESS, 0)
    assert to_signed(raw, 4) == value


def test_sync_write_and_sync_read(bus):
    port, ph = bus
    write = sdk.GroupSyncWrite(port, ph, A["profile_velocity"], 4)
    assert write.addParam(1, [10, 0, 0, 0]) and write.addParam(2, [20, 0, 0, 0])
    assert write.txPacket() == sdk.COMM_SUCCESS
    read = sdk.GroupSyncRead(port, ph, A["profile_velocity"], 4)
    read.addParam(1)
    read.addParam(2)
    assert read.txRxPacket() == sdk.COMM_SUCCESS
    assert [read.getData(i, A["profile_velocity"], 4) for i in (1, 2)] == [10, 20]


def test_bulk_read_and_bulk_write(bus):
    port, ph = bus
    write = sdk.GroupBulkWrite(port, ph)
    assert write.addParam(1, A["led"], 1, [1]) and write.addParam(2, A["profile_velocity"], 4, [33, 0, 0, 0])
    assert write.txPacket() == sdk.COMM_SUCCESS
    read = sdk.GroupBulkRead(port, ph)
    read.addParam(1, A["led"], 1)
    read.addParam(2, A["profile_velocity"], 4)
    assert read.txRxPacket() == sdk.COMM_SUCCESS
    assert read.getData(1, A["led"], 1) == 1 and read.getData(2, A["profile_velocity"], 4) == 33


def test_reg_write_waits_for_action(bus):
    port, ph = bus
    assert ph.regWriteTxRx(port, 1, A["led"], 1, [1]) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, A["registered_instruction"])[0] == 1
    assert ph.read1ByteTxRx(port, 1, A["led"])[0] == 0
    ph.action(port, sdk.BROADCAST_ID)
    assert ph.read1ByteTxRx(port, 1, A["led"])[0] == 1


def test_status_return_level_one_answers_reads_only(emulator, bus):
    port, ph = bus
    with emulator.lock:
        emulator.servos[2].set("status_return_level", 1)
    assert ph.write1ByteTxRx(port, 2, A["led"], 1)[0] == sdk.COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 2, A["led"]) == (1, sdk.COMM_SUCCESS, 0)


def test_reboot_clears_a_hardware_error_and_keeps_eeprom(emulator, bus):
    port, ph = bus
    assert ph.write4ByteTxRx(port, 1, A["max_position_limit"], 3500) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 1) == (sdk.COMM_SUCCESS, 0)
    emulator.inject_hardware_error(1, "overload")
    value, comm, err = ph.read1ByteTxRx(port, 1, A["hardware_error_status"])
    assert comm == sdk.COMM_SUCCESS and err == 0x80 and value == 0b100000  # alert bit, overload bit
    assert ph.read1ByteTxRx(port, 1, A["torque_enable"])[0] == 0  # shut down
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 1) == (sdk.COMM_SUCCESS, 0x80)
    assert ph.read1ByteTxRx(port, 1, A["torque_enable"])[0] == 0  # stays off until reboot
    assert ph.reboot(port, 1) == (sdk.COMM_SUCCESS, 0x80)
    deadline = time.monotonic() + 2.0
    while ph.ping(port, 1)[1] != sdk.COMM_SUCCESS:  # deaf while it boots
        assert time.monotonic() < deadline
    assert ph.read1ByteTxRx(port, 1, A["hardware_error_status"]) == (0, sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, A["max_position_limit"])[0] == 3500


def test_a_servo_at_another_baud_rate_does_not_hear(emulator):
    port = sdk.PortHandler(emulator.port)
    assert port.setBaudRate(57_600)
    try:
        assert sdk.PacketHandler(2.0).ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    finally:
        port.closePort()


def _trapezoid_ticks(t_s: float, distance: float, v: float, a: float) -> float:
    """Where a trapezoidal profile (Dynamixel's, from rest to rest) stands ``t_s`` after it began."""
    if t_s <= 0.0:
        return 0.0
    t_acc = v / a
    t_end = distance / v + t_acc
    if t_s >= t_end:
        return distance
    if t_s < t_acc:
        return 0.5 * a * t_s**2
    if t_s < t_end - t_acc:
        return v * t_s - 0.5 * v * t_acc
    return distance - 0.5 * a * (t_end - t_s) ** 2


def test_motion_follows_the_profile(bus, emulator):
    """Timed on the servo's own Realtime Tick, read with Present Position in one READ: the test's
    polling may be late on a loaded machine, the samples' positions and ticks still agree."""
    port, ph = bus
    vel_units, acc_units = 50, 40  # 11.45 rpm = 4 deg/... ~ 782 ticks/s; 40 units ~ 2.4 rev/s^2
    assert ph.write4ByteTxRx(port, 1, A["profile_acceleration"], acc_units) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["profile_velocity"], vel_units) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 1) == (sdk.COMM_SUCCESS, 0)
    first, span = A["realtime_tick"], A["present_position"] + 4 - A["realtime_tick"]

    def sample() -> tuple[int, int, int]:  # (tick ms, moving, present position)
        while True:
            data, comm, err = ph.readTxRx(port, 1, first, span)
            if comm != sdk.COMM_RX_TIMEOUT:
                break
            # starved past the reply timeout: let the late reply land, drop it, ask again
            assert emulator.wait_idle(timeout_s=30.0)
            port.clearPort()
        assert (comm, err) == (sdk.COMM_SUCCESS, 0)
        at = lambda name, size: int.from_bytes(bytes(data[A[name] - first : A[name] - first + size]), "little")  # noqa: E731
        return at("realtime_tick", 2), at("moving", 1), to_signed(at("present_position", 4), 4)

    tick_before = sample()[0]
    assert ph.write4ByteTxRx(port, 1, A["goal_position"], 2048 + 400) == (sdk.COMM_SUCCESS, 0)
    tick_after, _, _ = sample()
    samples = []
    end = time.monotonic() + 30.0  # a bound for a starved machine, not a speed check
    while time.monotonic() < end:
        samples.append(sample())
        if not samples[-1][1] and samples[-1][2] == 2448:
            break
        time.sleep(0.005)
    assert samples[-1][2] == 2448 and any(moving for _, moving, _ in samples)
    positions = [pos for _, _, pos in samples]
    assert positions == sorted(positions)  # monotonic, no overshoot
    v_ticks_s = vel_units * 0.229 / 60 * 4096
    a_ticks_s2 = acc_units * 214.577 / 3600 * 4096
    since = lambda tick, start: ((tick - start) % 32768) / 1000.0  # noqa: E731  (the tick wraps at 32768 ms)
    for tick, _, pos in samples:  # the goal took effect between tick_before and tick_after
        lo = _trapezoid_ticks(since(tick, tick_after), 400, v_ticks_s, a_ticks_s2)
        hi = _trapezoid_ticks(since(tick, tick_before), 400, v_ticks_s, a_ticks_s2)
        assert lo - 8 <= pos - 2048 <= hi + 8, (tick, pos, lo, hi)
    # moving backwards reads a negative (two's complement) velocity
    assert ph.write4ByteTxRx(port, 1, A["goal_position"], 2048) == (sdk.COMM_SUCCESS, 0)
    assert wait_for(lambda: to_signed(ph.read4ByteTxRx(port, 1, A["present_velocity"])[0], 4) < 0, timeout_s=30.0)


def test_torque_off_stops_motion(bus):
    port, ph = bus
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["profile_velocity"], 5) == (sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, A["goal_position"], 3000) == (sdk.COMM_SUCCESS, 0)
    time.sleep(0.05)
    assert ph.write1ByteTxRx(port, 1, A["torque_enable"], 0) == (sdk.COMM_SUCCESS, 0)
    held = ph.read4ByteTxRx(port, 1, A["present_position"])[0]
    time.sleep(0.05)
    assert ph.read4ByteTxRx(port, 1, A["present_position"])[0] == held < 3000
    assert ph.read1ByteTxRx(port, 1, A["moving"])[0] == 0


def test_xl430_table_differs_where_it_should():
    with ServoEmulator(["xl430-w250"]) as emu:
        port = sdk.PortHandler(emu.port)
        assert port.setBaudRate(1_000_000)
        ph = sdk.PacketHandler(2.0)
        try:
            assert ph.ping(port, 1)[:2] == (1060, sdk.COMM_SUCCESS)
            assert ph.write2ByteTxRx(port, 1, 38, 100) == (sdk.COMM_SUCCESS, ErrNum.ACCESS)  # no Current Limit
            assert ph.write1ByteTxRx(port, 1, A["operating_mode"], 0) == (sdk.COMM_SUCCESS, ErrNum.DATA_RANGE)
        finally:
            port.closePort()


def test_the_emulator_parser_sees_every_instruction(emulator, bus):
    port, ph = bus
    before = emulator.packets_seen
    ph.ping(port, 1)
    ph.read1ByteTxRx(port, 1, A["led"])
    assert emulator.packets_seen == before + 2
    assert PacketParser().feed(build_packet(1, Inst.PING))[0].crc_ok


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return any(line.startswith("State:") and "Z" in line.split()[1] for line in f)  # a zombie has exited
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads /proc")
def test_the_emulator_process_ends_with_the_process_that_started_it():
    """A gimbal node killed outright (SIGKILL) left `gimbal emulate` running, holding its pty."""
    snippet = (
        "import time\n"
        "from aes_planner.drivers.emulator import EmulatorProcess\n"
        "e = EmulatorProcess().__enter__()\n"
        "print(e.proc.pid, flush=True)\n"
        "time.sleep(120)\n"
    )
    starter = subprocess.Popen([sys.executable, "-c", snippet], stdout=subprocess.PIPE, text=True)
    try:
        emulator_pid = int(starter.stdout.readline())
        assert not _gone(emulator_pid)
        starter.kill()
        starter.wait(10)
        assert wait_for(lambda: _gone(emulator_pid), timeout_s=10.0, poll_s=0.1)
    finally:
        starter.kill()


def test_wait_idle_returns_once_what_a_client_wrote_is_handled():
    """A client that exits leaves its last instructions in the pty; ``wait_idle`` is the barrier
    a test takes before it reads the servos' state (here the I/O loop is held up by the lock)."""
    torque = model_by_name("xm430-w350").item("torque_enable").addr
    with ServoEmulator() as emu:
        fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B1000000  # the servos' baud: at another they do not hear
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        try:
            with emu.lock:  # the I/O loop cannot answer while the test holds the servos
                os.write(fd, build_packet(1, Inst.WRITE, bytes([torque, 0, 1])))
                assert not emu.wait_idle(timeout_s=0.3)
                assert not emu.servos[1].torque_on
            assert emu.wait_idle(timeout_s=30.0)
            assert emu.servos[1].torque_on
        finally:
            os.close(fd)
