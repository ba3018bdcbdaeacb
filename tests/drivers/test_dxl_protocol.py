"""Protocol 2.0 codec: the e-manual CRC vectors, byte stuffing, packet round trips; and agreement
with dynamixel-sdk's own CRC and stuffing."""

import dynamixel_sdk as sdk
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.drivers.protocol import HEADER, Inst, PacketParser, build_packet, build_status, crc16, stuff, unstuff

# (bytes before the CRC, CRC_L CRC_H): the example packets of the ROBOTIS e-manual's Protocol 2.0 page.
VECTORS = [
    ("FF FF FD 00 01 03 00 01", "19 4E"),  # ping id 1
    ("FF FF FD 00 01 07 00 02 84 00 04 00", "1D 15"),  # read present position
    ("FF FF FD 00 01 09 00 03 74 00 00 02 00 00", "CA 89"),  # write goal 512
    ("FF FF FD 00 01 04 00 55 00", "A1 0C"),  # status, no error
    ("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02", "CE FA"),  # sync read ids 1, 2
    ("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00", "82 87"),  # sync write 150/170
]


def _hex(s):
    return bytes.fromhex(s)


@pytest.mark.parametrize("body, crc", VECTORS)
def test_crc_matches_the_e_manual(body, crc):
    value = crc16(_hex(body))
    assert bytes([value & 0xFF, value >> 8]) == _hex(crc)
    # the SDK computes the same
    assert sdk.PacketHandler(2.0).updateCRC(0, list(_hex(body)), len(_hex(body))) == value


@pytest.mark.parametrize("body, crc", VECTORS)
def test_build_packet_reproduces_the_vectors(body, crc):
    raw = _hex(body)
    dxl_id, inst, params = raw[4], raw[7], raw[8:]
    if inst == Inst.STATUS:
        built = build_status(dxl_id, params[0], params[1:])
    else:
        built = build_packet(dxl_id, inst, params)
    assert built == raw + _hex(crc)


def test_stuffing_example_and_length():
    params = bytes([0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00])
    pkt = build_packet(1, Inst.WRITE, params)
    body = pkt[7:-2]
    assert body == bytes([Inst.WRITE, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00])
    assert pkt[5] | pkt[6] << 8 == len(body) + 2  # LEN counts the stuffed bytes and the CRC
    assert crc16(pkt[:-2]) == pkt[-2] | pkt[-1] << 8  # CRC over the stuffed packet
    (decoded,) = PacketParser().feed(pkt)
    assert decoded.params == params and decoded.crc_ok


@given(st.binary(max_size=300))
def test_stuffing_round_trips(data):
    stuffed = stuff(data)
    assert unstuff(stuffed) == data
    # a header never appears inside a stuffed body: every FF FF FD is followed by FD
    for i in range(len(stuffed) - 2):
        if stuffed[i : i + 3] == b"\xff\xff\xfd":
            assert i + 3 < len(stuffed) and stuffed[i + 3] == 0xFD


@given(st.binary(max_size=200))
def test_stuffing_agrees_with_the_sdk(params):
    ph = sdk.PacketHandler(2.0)
    length = len(params) + 3
    packet = [0xFF, 0xFF, 0xFD, 0x00, 0x01, length & 0xFF, length >> 8, Inst.WRITE, *params, 0, 0]
    sdk_stuffed = ph.addStuffing(list(packet))
    sdk_length = sdk_stuffed[5] | sdk_stuffed[6] << 8
    ours = stuff(bytes([Inst.WRITE]) + params)
    assert bytes(sdk_stuffed[7 : 7 + sdk_length - 2]) == ours
    assert sdk_length == len(ours) + 2


@given(
    st.integers(0, 0xFE),
    st.sampled_from([Inst.PING, Inst.READ, Inst.WRITE, Inst.SYNC_READ, Inst.SYNC_WRITE, Inst.BULK_READ]),
    st.binary(max_size=120),
    st.binary(max_size=20),
    st.integers(1, 17),
)
def test_parser_recovers_packets_from_a_chunked_stream(dxl_id, inst, params, noise, chunk):
    noise = noise.replace(b"\xff", b"\x00")  # line noise without a header in it
    stream = noise + build_packet(dxl_id, inst, params) + build_status(dxl_id, 0x80, params)
    parser = PacketParser()
    packets = []
    for i in range(0, len(stream), chunk):
        packets += parser.feed(stream[i : i + chunk])
    assert [(p.dxl_id, p.inst, p.params, p.crc_ok) for p in packets] == [
        (dxl_id, inst, params, True),
        (dxl_id, Inst.STATUS, b"\x80" + params, True),
    ]
    assert packets[1].error == 0x80


def test_parser_flags_a_bad_crc():
    raw = bytearray(build_packet(1, Inst.PING))
    raw[-1] ^= 0x01
    (pkt,) = PacketParser().feed(bytes(raw))
    assert not pkt.crc_ok
    assert HEADER == b"\xff\xff\xfd\x00"
