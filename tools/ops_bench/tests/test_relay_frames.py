"""ops_bench.relay's frame parsing: which flows carry DDS user traffic (the stuck-links fault)
and the UDP checksum it clears, on frames built here byte by byte."""

from __future__ import annotations

import struct

import pytest

from ops_bench.relay import is_user_port, user_flow, without_udp_checksum


def udp_frame(src_port: int, dst_port: int, payload: bytes = b"RTPS", fragment: int = 0) -> bytes:
    ethernet = b"\x02" * 6 + b"\x04" * 6 + b"\x08\x00"
    ip = struct.pack(
        "!BBHHHBBH4s4s",
        0x45,  # IPv4, a 20-byte header
        0,
        20 + 8 + len(payload),
        1,
        fragment,  # flags and fragment offset
        64,
        17,  # UDP
        0,
        bytes([10, 231, 0, 2]),
        bytes([10, 231, 0, 1]),
    )
    udp = struct.pack("!HHHH", src_port, dst_port, 8 + len(payload), 0xBEEF)
    return ethernet + ip + udp + payload


@pytest.mark.parametrize(
    ("port", "user"),
    [
        (7400, False),  # domain 0: discovery multicast
        (7401, True),  # user multicast
        (7410, False),  # discovery unicast, participant 0
        (7411, True),  # user unicast, participant 0
        (7412, False),
        (7413, True),  # user unicast, participant 1
        (7400 + 250 * 42 + 10, False),  # domain 42
        (7400 + 250 * 42 + 11 + 2 * 7, True),
        (7400 + 250 * 42 + 3, False),  # not in the mapping
        (5353, False),
        (53, False),
    ],
)
def test_user_ports_follow_the_rtps_mapping(port, user):
    assert is_user_port(port) is user


def test_a_flow_is_named_by_addresses_and_ports_and_only_for_user_traffic():
    flow = user_flow(udp_frame(40123, 7411))
    assert flow == (bytes([10, 231, 0, 2]), 40123, bytes([10, 231, 0, 1]), 7411)
    assert user_flow(udp_frame(40123, 7410)) is None  # discovery passes whatever happens
    assert user_flow(udp_frame(40123, 7411, fragment=185)) is None  # no UDP header in it
    arp = b"\xff" * 6 + b"\x04" * 6 + b"\x08\x06" + b"\x00" * 28
    assert user_flow(arp) is None


def test_the_checksum_is_cleared_and_nothing_else_changes():
    frame = udp_frame(40123, 7411, payload=b"RTPS\x02\x03")
    cleared = without_udp_checksum(frame)
    at = 14 + 20
    assert cleared[at + 6 : at + 8] == b"\x00\x00" and frame[at + 6 : at + 8] == b"\xbe\xef"
    assert cleared[: at + 6] == frame[: at + 6] and cleared[at + 8 :] == frame[at + 8 :]
    later = udp_frame(40123, 7411, fragment=185)
    assert without_udp_checksum(later) == later
