"""MAVLink connection strings: one parser for the bridge and the emulator, and the one opener.

Forms (pymavlink's, less those that would surprise a user)::

    udpin:HOST:PORT     listen for the vehicle (PX4 SITL sends to 14540); udp:HOST:PORT is the same
    udpout:HOST:PORT    send to HOST (the emulator's side)
    tcp:HOST:PORT       connect to HOST (ArduPilot SITL: 5760, 5762)
    tcpin:HOST:PORT     accept one connection
    serial:DEVICE:BAUD  a serial device (a character device), e.g. serial:/dev/ttyUSB0:921600

HOST is an IPv4 address or a host name; an IPv6 address (``[::1]``) is refused by name, since
pymavlink opens IPv4 sockets only (use ``127.0.0.1`` for the loopback). PORT is 1-65535. A string
that names nothing else is refused with the forms above, before pymavlink sees it (pymavlink reads
``serial:/dev/x:57600`` as a UDP address, and a word as a serial device).
"""

from __future__ import annotations

import ipaddress
import os
import re
import stat
from dataclasses import dataclass

from aes_planner.config import ConfigError, short_repr
from aes_planner.errors import AesPlannerError

__all__ = ["Connection", "MavlinkConnectionError", "connect", "parse_connection"]

FORMS = "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or serial:DEVICE:BAUD"
NETWORK_SCHEMES = ("udpin", "udpout", "udp", "tcp", "tcpin")
#: Serial rates a MAVLink port runs at (ArduPilot's SERIALn_BAUD, PX4's SER_*_BAUD).
BAUD_RATES = (
    9600,
    19200,
    38400,
    57600,
    111100,
    115200,
    230400,
    256000,
    460800,
    500000,
    921600,
    1500000,
    2000000,
    3000000,
)
_HOST = re.compile(
    r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)


class MavlinkConnectionError(AesPlannerError):
    """The connection string is well formed, but what it names cannot be opened."""


@dataclass(frozen=True)
class Connection:
    """A parsed connection string: ``scheme`` (``udpin``... ``serial``), ``host``/``port`` for
    the network, ``device``/``baud`` for a serial port; ``text`` is the string as pymavlink takes it."""

    scheme: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def text(self) -> str:
        return (
            f"{self.scheme}:{self.device}:{self.baud}"
            if self.scheme == "serial"
            else f"{self.scheme}:{self.host}:{self.port}"
        )


def parse_connection(text, key: str = "connection") -> Connection:
    """``text`` as a :class:`Connection`, or a :class:`ConfigError` naming ``key`` and the forms."""

    def refuse(why: str) -> ConfigError:
        return ConfigError(key, f"{why}; give one of {FORMS}")

    if not isinstance(text, str) or not 0 < len(text) <= 300 or not text.isprintable() or text != text.strip():
        raise refuse(f"expected a connection string, got {short_repr(text)}")
    scheme, sep, rest = text.partition(":")
    if not sep or scheme not in (*NETWORK_SCHEMES, "serial"):
        hint = f" (a serial device is written serial:{text}:57600)" if text.startswith("/dev/") else ""
        raise refuse(f"{short_repr(text)} names no connection{hint}")
    if scheme == "serial":
        device, sep, baud = rest.rpartition(":")
        if not sep or not device.startswith("/") or not baud.isascii() or not baud.isdigit():
            raise refuse(f"{short_repr(text)}: a serial connection is serial:/dev/DEVICE:BAUD")
        if int(baud) not in BAUD_RATES:
            raise refuse(f"{short_repr(text)}: baud {baud} is not a serial rate ({', '.join(map(str, BAUD_RATES))})")
        return Connection("serial", device=device, baud=int(baud))
    host, sep, port = rest.rpartition(":")
    if host.startswith("[") or host.count(":") or _is_v6(host):
        raise refuse(
            f"{short_repr(text)}: an IPv6 address; pymavlink opens IPv4 sockets only (the loopback is 127.0.0.1)"
        )
    if not sep or not host:
        raise refuse(f"{short_repr(text)}: expected {scheme}:HOST:PORT")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise refuse(f"{short_repr(text)}: the port must be 1-65535, got {short_repr(port)}")
    if not _HOST.match(host):
        raise refuse(f"{short_repr(text)}: {short_repr(host)} is not an IPv4 address or a host name")
    return Connection("udpin" if scheme == "udp" else scheme, host=host, port=int(port))


def _is_v6(host: str) -> bool:
    try:
        return isinstance(ipaddress.ip_address(host), ipaddress.IPv6Address)
    except ValueError:
        return False


def connect(connection: str, source_system: int, source_component: int):
    """A pymavlink connection (MAVLink 2, the common dialect: gimbal protocol v2 and the ids above
    255 exist only there) to what ``connection`` names; :class:`MavlinkConnectionError` when it
    cannot be opened (no such device, not a character device, refused, no such host)."""
    from aes_planner.drone.modes import mavlink

    c = parse_connection(connection)
    mavlink()  # MAVLINK20 set before pymavlink loads its dialect
    from pymavlink import mavutil

    if c.scheme == "serial":
        try:
            mode = os.stat(c.device).st_mode
        except OSError as exc:
            raise MavlinkConnectionError(f"connection: {c.device}: {exc.strerror}; check the device path") from None
        if not stat.S_ISCHR(mode):
            raise MavlinkConnectionError(
                f"connection: {c.device} is not a serial device (not a character device); give the port, e.g. /dev/ttyUSB0"
            )
        target, kwargs = c.device, {"baud": c.baud}
    else:
        target, kwargs = c.text, {}
        if c.scheme == "tcp":
            kwargs["retries"] = 3
    try:
        return mavutil.mavlink_connection(
            target, source_system=source_system, source_component=source_component, dialect="common", **kwargs
        )
    except OSError as exc:
        why = exc.strerror or str(exc) or type(exc).__name__
        raise MavlinkConnectionError(f"connection: cannot open {c.text}: {why}") from None
    except Exception as exc:  # pymavlink's own errors (a serial port that will not open...)
        raise MavlinkConnectionError(f"connection: cannot open {c.text}: {short_repr(str(exc))}") from None
