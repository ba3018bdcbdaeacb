"""Bad input at the gimbal boundaries: the CLI, the driver config, the emulator options,
the Protocol 2.0 parser and the servo bus. Every case ends in a clear error or a documented,
finite result: never a traceback, a hang or NaN."""

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aes_planner.cli import main
from aes_planner.config import ConfigError, from_dict
from aes_planner.devices import DeviceError
from aes_planner.drivers import dynamixel_models as dm
from aes_planner.drivers.dynamixel import DynamixelPanTiltConfig
from aes_planner.drivers.emulator import EmulatedServo, FaultPlan, ServoBus, ServoEmulator
from aes_planner.drivers.protocol import Inst, Packet, PacketParser, build_packet, build_status, crc16


# ------------------------------------------------------------------------------ CLI
@pytest.mark.parametrize(
    "argv, message",
    [
        (["gimbal", "emulate", "--baud", "0"], "not an X-series rate"),
        (["gimbal", "emulate", "--models", ",,,"], "at least one servo model"),
        (["gimbal", "emulate", "--models", "xm430-w350," * 40], "at most 32 servos"),
        (["gimbal", "emulate", "--drop-rate", "nan"], "drop_rate must be within [0, 1]"),
        (["gimbal", "emulate", "--corrupt-rate", "-1"], "corrupt_rate must be within [0, 1]"),
        (["gimbal", "emulate", "--link", "/nonexistent/dir/tty"], "does not exist"),
        (["gimbal", "emulate", "--link", "/tmp/" + "a" * 300], "--link"),
        (["gimbal", "emulate", "--link", "/proc/version"], "a file exists there"),
        (["gimbal", "scan", "--port", "/dev/null"], "cannot open serial port /dev/null"),
        (["gimbal", "scan", "--port", ""], "--port: an empty value"),
        (["gimbal", "scan", "--port", "/tmp"], "cannot open serial port /tmp"),
        (["gimbal", "scan", "--port", "/dev/x", "--baud", "-5"], "baud -5 is not one of"),
        (["gimbal", "state", "--port", "/dev/null"], "cannot open serial port /dev/null"),
        (["gimbal", "state", "--port", "/dev/x", "--pan-id", "999"], "pan_id: servo ids are 0..252"),
        (["gimbal", "state", "--port", "/dev/x", "--tilt-id", "-1"], "tilt_id: servo ids are 0..252"),
        (["gimbal", "reboot", "--port", "/etc/hostname"], "cannot open serial port"),
        (["gimbal", "move", "--port", "/dev/x", "--pan-deg", "1e400", "--tilt-deg", "0"], "finite number"),
        (["gimbal", "move", "--port", "/dev/x", "--pan-deg", "1", "--tilt-deg=-inf"], "--tilt-deg must be"),
        (["gimbal", "move", "--port", "/dev/x", "--pan-deg", "1", "--tilt-deg", "0", "--timeout-s", "inf"], "(0, 600]"),
        (["gimbal", "move", "--port", "/dev/x", "--pan-deg", "1", "--tilt-deg", "0", "--timeout-s", "0"], "(0, 600]"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


@pytest.mark.parametrize(
    "text, message",
    [
        ("- 1\n- 2\n", "expected a mapping of gimbal settings"),
        ("port: /dev/x\nbaud: 57601\n", "baud"),
        ("port: /dev/x\npoll_interval_s: 1000000.0\n", "poll_interval_s: must be at most 1"),
        ("port: /dev/x\nprofile_velocity_deg_s: 1.0e+30\n", "profile_velocity_deg_s: must be at most"),
        ("port: /dev/x\npan_limits_deg: [-1.0e+400, 10]\n", "pan_limits_deg"),
        ("port: /dev/x\nretries: 1000\n", "retries: must be 0..20"),
        ("port: [1, 2]\n", "port"),
        ("port: /dev/x\npan_direction: true\n", "pan_direction"),
        ("port: /dev/x\nport: /dev/y\n", "port"),  # duplicate keys are refused, not last-wins
        ("port: /dev/x\nprofile_velocity_deg_s: 1e30\n", "profile_velocity_deg_s: must be at most"),
        ("port: [1\n", "not valid YAML"),
        (
            "a: &a [1,2,3,4,5,6,7,8,9]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
            "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n",
            "gimbal.yaml",  # an alias bomb: refused by the shared loader, bounded message
        ),
    ],
)
def test_config_file_bad_values_are_one_line_exit_2(tmp_path, text, message, capsys):
    cfg = tmp_path / "gimbal.yaml"
    cfg.write_text(text)
    assert main(["gimbal", "state", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1 and len(err) < 600, err


@pytest.mark.parametrize("kind", ["folder", "binary"])
def test_config_that_is_not_a_yaml_file(tmp_path, kind, capsys):
    cfg = tmp_path / "gimbal.yaml"
    if kind == "folder":
        cfg.mkdir()
    else:
        cfg.write_bytes(b"\xff\xfe\x00\x81" * 10)
    assert main(["gimbal", "move", "--config", str(cfg), "--pan-deg", "1", "--tilt-deg", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(cfg) in err and err.count("\n") == 1, err


# ------------------------------------------------------------------------------ driver config
_EXTREME = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e-300, 1e300, 1e30, 2**31, 2**64, True, "1", None, [1.0]]),
    st.integers(-(2**40), 2**40),
)
_FIELDS = [
    "baud",
    "pan_id",
    "tilt_id",
    "pan_zero_offset_ticks",
    "pan_direction",
    "profile_velocity_deg_s",
    "profile_acceleration_deg_s2",
    "retries",
    "backoff_s",
    "latency_timer_ms",
    "move_timeout_s",
    "arrival_tolerance_deg",
    "poll_interval_s",
    "reboot_timeout_s",
]


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(_FIELDS), _EXTREME, max_size=4))
def test_driver_config_is_valid_or_a_config_error(values):
    try:
        c = from_dict(DynamixelPanTiltConfig, {"port": "/dev/x", **values}, "gimbal")
    except ConfigError as exc:
        assert exc.key.startswith("gimbal") and len(str(exc)) < 400
        return
    for name in ("backoff_s", "latency_timer_ms", "move_timeout_s", "poll_interval_s", "reboot_timeout_s"):
        assert math.isfinite(getattr(c, name)) and 0 <= getattr(c, name) <= 600
    assert c.retries <= 20
    for model in dm.MODELS:  # what the driver will write fits the registers, never wraps
        assert 0 <= model.velocity_units(c.profile_velocity_deg_s) <= model.item("profile_velocity").hi
        assert 0 <= model.acceleration_units(c.profile_acceleration_deg_s2) <= model.item("profile_acceleration").hi


# ------------------------------------------------------------------------------ emulator options
@pytest.mark.parametrize(
    "kwargs",
    [
        {"drop_rate": math.nan},
        {"corrupt_rate": 1.5},
        {"delay_s": math.nan},
        {"delay_s": -1.0},
        {"delay_s": 1e9},
        {"drop_next": -3},
        {"delay_next": 1.5},
    ],
)
def test_fault_plan_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        FaultPlan(**kwargs)


@pytest.mark.parametrize(
    "args, kwargs",
    [
        ((["nope"],), {}),
        (([],), {}),
        ((["xm430-w350"], [300]), {}),
        ((["xm430-w350", "xm430-w350"], [1, 1]), {}),
        ((["xm430-w350"], [1, 2]), {}),
        ((["xm430-w350"],), {"baud": 12345}),
    ],
)
def test_emulator_rejects_bad_options(args, kwargs):
    with pytest.raises((ValueError, KeyError)):
        ServoEmulator(*args, **kwargs)


# ------------------------------------------------------------------------------ Protocol 2.0 parser
_VALID = [
    build_packet(1, Inst.PING),
    build_packet(1, Inst.READ, bytes([0x84, 0, 4, 0])),
    build_packet(0xFE, Inst.SYNC_WRITE, bytes([0x74, 0, 4, 0, 1, 0xFF, 0xFF, 0xFD, 0, 2, 1, 2, 3, 4])),
    build_status(2, 0x80, bytes(range(31))),
]


def _check(packets):
    for p in packets:
        assert isinstance(p, Packet) and 0 <= p.dxl_id <= 0xFF and 0 <= p.inst <= 0xFF
        assert isinstance(p.crc_ok, bool) and isinstance(p.params, bytes) and len(p.params) <= PacketParser.MAX_LENGTH


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000), st.integers(1, 64))
def test_parser_never_crashes_on_random_bytes_in_any_chunking(data, chunk):
    whole = PacketParser().feed(data)
    _check(whole)
    parser, pieces = PacketParser(), []
    for i in range(0, len(data), chunk):
        pieces += parser.feed(data[i : i + chunk])
    assert pieces == whole  # the stream's chunking never changes what is parsed


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(_VALID), st.data())
def test_truncations_wait_and_bit_flips_are_caught(raw, data):
    cut = data.draw(st.integers(0, len(raw) - 1))
    parser = PacketParser()
    assert parser.feed(raw[:cut]) == []  # a prefix is incomplete, never a packet
    (whole,) = parser.feed(raw[cut:])
    assert whole.crc_ok
    bit = data.draw(st.integers(7 * 8, len(raw) * 8 - 1))  # after the header and id-length: LEN kept
    flipped = bytearray(raw)
    flipped[bit // 8] ^= 1 << (bit % 8)
    out = PacketParser().feed(bytes(flipped))
    _check(out)
    # CRC-16 catches every single-bit error of the part it covers (and of the CRC itself)
    assert all(not p.crc_ok for p in out if p.dxl_id == whole.dxl_id)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 0xFE), st.integers(0, 0xFF), st.binary(max_size=80), st.booleans())
def test_servo_bus_answers_any_instruction_without_crashing(dxl_id, inst, params, crc_ok):
    bus = ServoBus([EmulatedServo(dm.model_by_name("xm430-w350"), 1), EmulatedServo(dm.model_by_name("xl430-w250"), 2)])
    replies = bus.handle(Packet(dxl_id, inst, params, crc_ok))
    for servo, raw, _ in replies:
        (status,) = PacketParser().feed(raw)
        assert status.crc_ok and status.inst == Inst.STATUS and status.dxl_id == servo.dxl_id
    for servo in bus.servos.values():  # no instruction stores a value outside an item's range
        for name, item in servo.model.table.items():
            if item.access == "RW" and item.lo is not None:
                assert item.lo <= servo.get(name) <= item.hi, name


@settings(max_examples=300, deadline=None)
@given(st.integers(-(2**31), 2**31 - 1), st.integers(-1000, 1000), st.sampled_from([1, -1]))
def test_any_register_value_decodes_to_finite_radians(ticks, offset, direction):
    cal = dm.JointCalibration(offset, direction, (-1.0, 1.0))
    assert math.isfinite(cal.to_rad(ticks))


# ------------------------------------------------------------------------------ the driver on garbage
@pytest.mark.parametrize("seed", range(12))
def test_driver_on_replies_with_flipped_bits_reports_finite_state_or_a_device_error(emulator, gimbal, seed):
    """Bit flips in the replies (CRC recomputed, so the SDK accepts them): the driver returns finite
    numbers or raises a DeviceError; nothing else escapes."""
    import random

    rng = random.Random(seed)
    send = emulator._send

    def flip(raw):
        (pkt,) = PacketParser().feed(raw)
        body = bytearray(raw[:-2])
        i = rng.randrange(8, len(body))
        body[i] ^= 1 << rng.randrange(8)
        crc = crc16(bytes(body))
        send(bytes(body) + bytes([crc & 0xFF, crc >> 8]))

    emulator._send = flip
    try:
        for _ in range(3):
            try:
                s = gimbal.state()
            except DeviceError:
                continue
            for v in (s.pan_rad, s.tilt_rad, s.goal_pan_rad, s.goal_tilt_rad, *s.temperature_c):
                assert math.isfinite(v)
    finally:
        emulator._send = send
