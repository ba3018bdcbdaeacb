"""Sweep: ``drone emulate`` arguments and MAVLink connection strings as a careless or hostile user
types them. Every case ends in one ``error:`` line and status 2, never a Python error, a hang or
a silent acceptance; the bridge's config refuses the same connection strings by the same parser."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.cli import main
from aes_planner.config import ConfigError, from_dict
from aes_planner.drone.connection import parse_connection
from aes_planner.drone.node import MavlinkDroneConfig

pytest.importorskip("pymavlink")
from aes_planner.drone.emulator import EmulatorConfig

BAD_CONNECTIONS = [
    "garbage",
    "",
    " udpin:127.0.0.1:14540",
    "udpin:127.0.0.1:70000",
    "udpin:127.0.0.1:0",
    "udpin:127.0.0.1:-1",
    "udpin:127.0.0.1:port",
    "udpin:127.0.0.1",
    "udpout::14540",
    "udpout:[::1]:14540",
    "udpout:::1:14540",
    "tcp:[::1]:5760",
    "udpin:bad host:14540",
    "udpin:127.0.0.1:１４５４０",  # full-width digits
    "serial:/dev/ttyUSB0",
    "serial:/dev/ttyUSB0:12345",
    "serial:ttyUSB0:57600",
    "/dev/ttyUSB0:57600",
    "ws:127.0.0.1:80",
    "udpin:127.0.0.1:14540\n",
    "udpin:" + "a" * 400 + ":1",
    "file:/etc/passwd",
]


@pytest.mark.parametrize("text", BAD_CONNECTIONS)
def test_the_bridge_and_the_emulator_refuse_the_same_connection_strings(text):
    with pytest.raises(ConfigError, match="connection"):
        parse_connection(text)
    with pytest.raises(ConfigError, match="connection"):
        from_dict(MavlinkDroneConfig, {"connection": text})
    with pytest.raises(ConfigError, match="connection"):
        from_dict(EmulatorConfig, {"connection": text})


@pytest.mark.parametrize(
    ("text", "scheme"),
    [
        ("udpin:127.0.0.1:14540", "udpin"),
        ("udp:0.0.0.0:14550", "udpin"),
        ("udpout:localhost:14540", "udpout"),
        ("tcp:127.0.0.1:5762", "tcp"),
        ("serial:/dev/ttyUSB0:921600", "serial"),
    ],
)
def test_the_forms_users_write_parse(text, scheme):
    assert parse_connection(text).scheme == scheme
    from_dict(MavlinkDroneConfig, {"connection": text})


def _run(capsys, *argv) -> tuple[int, str]:
    rc = main(["drone", "emulate", *argv])
    err = capsys.readouterr().err
    return rc, err


@pytest.mark.parametrize(
    "argv",
    [
        ["--connection", "garbage"],
        ["--connection", "tcp:127.0.0.1:1"],  # nothing listens there
        ["--connection", "udpout:127.0.0.1:70000"],
        ["--connection", "serial:/etc/passwd:57600"],  # a file, not a serial device
        ["--connection", "serial:/nonexistent/tty:57600"],
        ["--connection", "udpout:[::1]:14540"],
        ["--start-ned=1e300,0,0"],
        ["--start-ned=nan,0,0"],
        ["--duration", "inf"],
        ["--duration", "nan"],
        ["--duration", "0"],
        ["--duration", "-1"],
        ["--duration", "1e300"],
        ["--heading-deg", "1e308"],
        ["--heading-deg", "nan"],
        ["--fence-min-ned=1,1,1", "--fence-max-ned=0,0,0"],  # reversed
        ["--fence-min-ned=0,0,0", "--fence-max-ned=0,5,5"],  # zero size
        ["--fence-min-ned=0,0,0", "--fence-max-ned=1e300,5,5"],
        ["--max-speed", "1e9"],
        ["--max-speed", "-1"],
        ["--link-loss=-1:2"],
        ["--link-loss=1:1e308"],
        ["--link-loss=1:0"],
        ["--wind=1e9,0,0"],
        ["--wind=nan,0,0"],
        ["--packet-loss", "1.5"],
        ["--seed", "-1"],
        ["--seed", str(2**70)],
        ["--system-id", "0"],
    ],
)
def test_bad_emulate_arguments_are_one_line_errors(capsys, argv):
    rc, err = _run(capsys, *argv)
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "unexpected" not in err and "Traceback" not in err, err


@settings(max_examples=60, deadline=None)
@given(
    value=st.floats(allow_nan=True, allow_infinity=True, width=64),
    name=st.sampled_from(["start_heading_deg", "max_speed_m_s", "wind_m_s", "start_ned_m", "offboard_loss_s"]),
)
def test_every_number_of_the_emulator_is_bounded(value, name):
    data = {name: [value, 0.0, 0.0] if name in ("wind_m_s", "start_ned_m") else value}
    try:
        cfg = from_dict(EmulatorConfig, data)
    except ConfigError as exc:
        assert name in str(exc)
        return
    got = getattr(cfg, name)
    v = got[0] if isinstance(got, (tuple, list)) else got
    assert math.isfinite(v) and abs(v) <= 1e4
