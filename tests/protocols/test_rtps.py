"""The RTPS codec against the spec sheet's vectors (udp.md §2, §4), both ways, and on garbage."""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import cdr
from hilbench.protocols import rtps as r

spec = importlib.util.spec_from_file_location("udp_vectors", Path(__file__).resolve().parents[1] / "udp_vectors.py")
V = importlib.util.module_from_spec(spec)
spec.loader.exec_module(V)
R = V.R


@pytest.mark.parametrize("name", sorted(R))
def test_every_vector_parses_clean(name: str) -> None:
    msg = r.parse_message(R[name])
    assert msg.flags == [] and msg.version == (2, 1) and msg.vendor_id == b"\x2f\x2c"
    assert all(s.problem is None for s in msg.submessages)


def test_user_data_vectors() -> None:
    m1 = r.parse_message(R["R1"])
    assert [s.name for s in m1.submessages] == ["INFO_TS", "DATA"]
    assert m1.submessages[0].fields == {"seconds": 1436564565, "fraction": 0}
    d = m1.submessages[1].fields
    assert (d["reader_id"], d["writer_id"], d["sn"]) == (bytes.fromhex("00000204"), bytes.fromhex("00000103"), 1)
    assert d["encapsulation"] == r.CDR_LE
    assert cdr.ros_type("std_msgs/UInt32").try_decode(d["payload"][4:])[0] == {"data": 1638}
    d2 = r.parse_message(R["R2"]).submessages[1].fields
    assert cdr.ros_type("std_msgs/String").try_decode(d2["payload"][4:])[0] == {"data": "Hello"}
    assert len(R["R1"]) == 64 and len(R["R2"]) == 70


def test_spdp_vector_fields() -> None:
    d = r.parse_message(R["R3"]).submessages[1]
    assert d.flags == r.FLAG_E | r.FLAG_Q | r.FLAG_D and d.length == 220
    p = d.fields["parameters"]
    assert p["participant_guid"] == V.PREFIX_PID_BOARD + r.ENTITYID_PARTICIPANT
    assert p["default_unicast_locator"] == [(1, "192.168.2.151", 7411)]
    assert p["metatraffic_unicast_locator"] == [(1, "192.168.2.151", 7410)]
    assert p["metatraffic_multicast_locator"] == [(1, "239.255.0.1", 7400)]
    assert p["lease_s"] == 100 and p["builtin_endpoints"] == 0x3F and p["vendor_id"] == b"\x2c\x2f"
    assert d.fields["inline_qos"]["key_hash"] == p["participant_guid"]


def test_heartbeat_and_acknack_vectors() -> None:
    hb = r.parse_message(R["R4"]).submessages[0].fields
    assert (hb["first_sn"], hb["last_sn"], hb["count"], hb["final"]) == (1, 1, 0, True)
    m = r.parse_message(R["R5"])
    assert m.submessages[0].fields["guid_prefix"] == bytes.fromhex("010F0A0B0C0D0E0F10111213")
    ack = m.submessages[1].fields
    assert (ack["base"], ack["num_bits"], ack["missing"], ack["count"]) == (2, 0, [], 1)


def test_builders_reproduce_the_vectors() -> None:
    p1 = bytes.fromhex("2C2F2C4D5901235200000000")
    payload = r.CDR_LE + b"\0\0" + V.R6["uint32_1638"]
    assert r.message(p1, r.info_ts(1436564565, 0),
                     r.data(bytes.fromhex("00000204"), bytes.fromhex("00000103"), 1, payload)) == R["R1"]
    p3 = bytes.fromhex("2C2F2C4D5901235300000000")
    assert r.message(p3, r.info_ts(1436564565, 0), r.data(r.ENTITYID_UNKNOWN, bytes.fromhex("00000103"), 1,
                                                           r.CDR_LE + b"\0\0" + V.R6["string_hello"])) == R["R2"]
    p = V.PREFIX_PID_BOARD
    assert r.message(p, r.heartbeat(r.SEDP_PUB_READER, r.SEDP_PUB_WRITER, 1, 1, 0, final=True)) == R["R4"]
    assert r.message(p, r.info_dst(bytes.fromhex("010F0A0B0C0D0E0F10111213")),
                     r.acknack(r.SEDP_PUB_READER, r.SEDP_PUB_WRITER, 2, [], 1, final=True)) == R["R5"]
    guid = p + r.ENTITYID_PARTICIPANT
    params = [(r.PID_PROTOCOL_VERSION, b"\x02\x01"), (r.PID_VENDOR_ID, b"\x2c\x2f"),
              (r.PID_DEFAULT_UNICAST_LOCATOR, r.locator(7411, "192.168.2.151")),
              (r.PID_DEFAULT_MULTICAST_LOCATOR, r.locator(7401, "239.255.0.1")),
              (r.PID_METATRAFFIC_UNICAST_LOCATOR, r.locator(7410, "192.168.2.151")),
              (r.PID_METATRAFFIC_MULTICAST_LOCATOR, r.locator(7400, "239.255.0.1")),
              (r.PID_PARTICIPANT_LEASE_DURATION, struct.pack("<iI", 100, 0)), (r.PID_PARTICIPANT_GUID, guid),
              (r.PID_BUILTIN_ENDPOINT_SET, struct.pack("<I", 0x3F))]
    spdp = r.data(r.ENTITYID_UNKNOWN, r.SPDP_WRITER, 1, r.PL_CDR_LE + b"\0\0" + r.parameter_list(params),
                  inline_qos=r.key_hash_qos(guid))
    assert r.message(p, r.info_ts(1436564565, 0), spdp) == R["R3"]


def test_ports_of_the_sheet() -> None:
    assert r.ports(0, 0) == {"metatraffic_multicast": 7400, "metatraffic_unicast": 7410, "user_multicast": 7401,
                             "user_unicast": 7411}
    assert r.ports(0, 1)["metatraffic_unicast"] == 7412 and r.ports(0, 1)["user_unicast"] == 7413
    assert r.ports(1, 0)["metatraffic_unicast"] == 7660 and r.ports(1, 0)["user_unicast"] == 7661
    assert r.port_owner(7413) == (0, 1, "user_unicast") and r.port_owner(7650) == (1, -1, "metatraffic_multicast")


def test_sequence_number_sets() -> None:
    nb, bitmap = r.sn_set(5, [5, 7, 40])
    assert nb == 36 and r.bitmap_members(5, nb, bitmap) == [5, 7, 40]
    ack = r.parse_message(r.message(V.PREFIX_PID_BOARD, r.acknack(r.SEDP_PUB_READER, r.SEDP_PUB_WRITER, 3, [3, 4],
                                                                   7))).submessages[0].fields
    assert ack["missing"] == [3, 4] and ack["count"] == 7


@pytest.mark.parametrize("name", sorted(R))
def test_fast_path_agrees_with_the_parse(name: str) -> None:
    msg = r.parse_message(R[name])
    assert [(i, f, ln) for i, f, _, ln in r.scan(R[name])] == [(s.id, s.flags, s.length) for s in msg.submessages]


def test_integrity_flags() -> None:
    assert r.parse_message(b"XTPS" + R["R1"][4:]).flags == ["rtps.bad_magic"]
    assert "rtps.bad_version" in r.parse_message(R["R1"][:4] + b"\x03" + R["R1"][5:]).flags
    assert "rtps.bad_length" in r.parse_message(R["R1"][:-3]).flags
    no_sentinel = R["R3"][:-4]
    assert "rtps.no_sentinel" in r.parse_message(no_sentinel[:34] + bytes([no_sentinel[34] - 4]) +
                                                 no_sentinel[35:]).flags
    both = bytearray(R["R1"])
    both[33] = r.FLAG_E | r.FLAG_D | r.FLAG_K
    assert "rtps.data_and_key" in r.parse_message(bytes(both)).flags


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=300))
def test_garbage_never_raises(data: bytes) -> None:
    r.parse_message(b"RTPS" + data)
    r.scan(b"RTPS" + data)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(R)), st.integers(0, 255), st.integers(0, 255))
def test_mutated_vectors_never_raise(name: str, pos: int, value: int) -> None:
    data = bytearray(R[name])
    data[pos % len(data)] = value
    r.parse_message(bytes(data))
