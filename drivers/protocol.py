"""Dynamixel Protocol 2.0 packet codec: CRC, byte stuffing, packet build and stream parsing.

Packet layout (both directions)::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | [ERR] PARAMS... | CRC_L CRC_H

``LEN`` counts INST, the (stuffed) parameters and the CRC. A status packet has ``INST = 0x55``
and an error byte before its parameters. Byte stuffing runs over INST..last parameter: every
``FF FF FD`` gets an extra ``FD``; the CRC (CRC-16/BUYPASS: poly 0x8005, init 0, MSB first, no
final xor) is computed over the stuffed packet from the header to the last parameter.

The driver talks to servos through ``dynamixel_sdk``; this module is what the emulator (the servo
side) and the tests use. Pure Python, no SDK import.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "HEADER",
    "BROADCAST_ID",
    "Inst",
    "ErrNum",
    "ERRBIT_ALERT",
    "crc16",
    "stuff",
    "unstuff",
    "build_packet",
    "build_status",
    "Packet",
    "PacketParser",
]

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
STATUS_INST = 0x55
ERRBIT_ALERT = 0x80


class Inst:
    """Instruction codes of Protocol 2.0."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = STATUS_INST
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrNum:
    """The low 7 bits of a status packet's error byte (bit 7 is the hardware alert)."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16/BUYPASS of ``data`` (the bytes from the header to the last parameter)."""
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in ``body`` (INST..last parameter)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Remove the ``FD`` that :func:`stuff` inserted (drop the second FD of ``FF FF FD FD``)."""
    out = bytearray()
    i = 0
    while i < len(body):
        b = body[i]
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            if i + 1 < len(body) and body[i + 1] == 0xFD:
                i += 1  # the stuffing byte
        i += 1
    return bytes(out)


def build_packet(dxl_id: int, inst: int, params: bytes | bytearray = b"") -> bytes:
    """A complete packet: header, id, length, stuffed INST+params and CRC."""
    if not 0 <= dxl_id <= 0xFE:
        raise ValueError(f"id must be 0..254, got {dxl_id}")
    body = stuff(bytes([inst]) + bytes(params))
    length = len(body) + 2
    head = HEADER + bytes([dxl_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


def build_status(dxl_id: int, error: int, params: bytes | bytearray = b"") -> bytes:
    """A status packet (INST 0x55) with ``error`` and ``params``."""
    return build_packet(dxl_id, STATUS_INST, bytes([error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """A decoded packet: ``params`` are unstuffed; ``crc_ok`` tells whether the CRC matched."""

    dxl_id: int
    inst: int
    params: bytes
    crc_ok: bool = True

    @property
    def error(self) -> int:
        """The error byte of a status packet."""
        return self.params[0] if self.inst == STATUS_INST and self.params else 0


class PacketParser:
    """Incremental parser for a byte stream: ``feed(data)`` returns the packets completed.

    Bytes before a header are skipped (line noise, half packets). A packet whose CRC does not
    match is still returned, with ``crc_ok=False``, so that a servo can answer with a CRC error.
    """

    MAX_LENGTH = 1024

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes | bytearray) -> list[Packet]:
        self._buf.extend(data)
        packets: list[Packet] = []
        while True:
            start = self._buf.find(HEADER)
            if start < 0:
                # keep a possible partial header at the end
                keep = next((k for k in (3, 2, 1) if self._buf.endswith(HEADER[:k])), 0)
                del self._buf[: len(self._buf) - keep]
                return packets
            del self._buf[:start]
            if len(self._buf) < 7:
                return packets
            length = self._buf[5] | (self._buf[6] << 8)
            if length < 3 or length > self.MAX_LENGTH:
                del self._buf[:1]  # not a real header; resync on the next one
                continue
            total = 7 + length
            if len(self._buf) < total:
                return packets
            raw = bytes(self._buf[:total])
            del self._buf[:total]
            crc_ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
            body = unstuff(raw[7:-2])
            packets.append(Packet(raw[4], body[0], bytes(body[1:]), crc_ok))

    def clear(self) -> None:
        self._buf.clear()
