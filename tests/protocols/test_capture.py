"""The capture format's layout: construct definitions and the per-record fast paths agree."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import capture as cap


def test_header_round_trip_and_byte_layout():
    raw = cap.build_header(flags=cap.Flags.MEASURED, baud=2_000_000, t0_wall=1.5, t0_monotonic=2.5,
                           protocol="dynamixel", description="bench wolfgang")
    assert raw[:8] == b"\x89HBC\r\n\x1a\n"
    assert raw[8:10] == b"\x01\x00"  # version 1
    assert cap.header_body_size(raw) == len(raw) - cap.HEADER_PREFIX_SIZE
    info = cap.parse_header(raw)
    assert info == cap.CaptureInfo(1, 1, 2_000_000, 1.5, 2.5, "dynamixel", "bench wolfgang")
    assert info.measured and not info.synthetic


def test_header_body_may_grow_in_later_versions():
    raw = cap.build_header(baud=0, protocol="dynamixel")
    body_size = cap.header_body_size(raw)
    longer = raw[:10] + (body_size + 3).to_bytes(2, "little") + raw[12:] + b"new"
    info = cap.parse_header(longer)
    assert info.protocol == "dynamixel" and info.baud is None


def test_bad_magic_and_newer_versions_are_refused_in_one_line():
    with pytest.raises(ValueError, match="bad magic"):
        cap.parse_header(b"\xff\xff\xfd\x00" + bytes(30))
    newer = bytearray(cap.build_header())
    newer[8] = 9
    with pytest.raises(ValueError, match="version 9 is newer"):
        cap.parse_header(bytes(newer))


@given(st.sampled_from(list(cap.RecordKind)), st.integers(0, 255), st.integers(-(2**63), 2**63 - 1),
       st.binary(max_size=300))
def test_record_fast_path_agrees_with_construct(kind, source, t_ns, payload):
    fast = cap.pack_record(kind, source, t_ns, payload)
    assert fast == cap.Record.build({"kind": kind, "source": source, "length": len(payload), "t_ns": t_ns,
                                     "payload": payload})
    assert cap.unpack_record_header(fast) == (kind, source, len(payload), t_ns)
    parsed = cap.Record.parse(fast)
    assert (parsed.kind, parsed.source, parsed.t_ns, parsed.payload) == (kind, source, t_ns, payload)
    assert len(fast) == cap.RECORD_HEADER_SIZE + len(payload)


def test_record_payload_is_bounded_by_its_length_field():
    assert cap.MAX_PAYLOAD == 0xFFFF
    with pytest.raises(Exception):  # noqa: B017 (struct.error: the u16 cannot hold it)
        cap.pack_record(cap.RecordKind.DATA, 0, 0, bytes(cap.MAX_PAYLOAD + 1))


def test_gap_record_is_one_layout():
    raw = cap.gap_record(3, 1_000, 70_000)
    rec = cap.Record.parse(raw)
    assert (rec.kind, rec.source, rec.t_ns, rec.length) == (cap.RecordKind.GAP, 3, 1_000, 4)
    assert cap.gap_lost(rec.payload) == 70_000 == cap.GapPayload.parse(rec.payload).lost
    assert cap.gap_lost(cap.gap_record(0, 0, 2**40)[cap.RECORD_HEADER_SIZE:]) == 0xFFFFFFFF  # capped
    assert cap.gap_lost(b"\x01") is None  # too short: not a count


def test_the_fast_paths_sizes_are_the_layouts():
    assert cap.RECORD_HEADER_SIZE == cap.RecordHeader.sizeof() == cap._RECORD.size
    assert cap.GapPayload.sizeof() == 4  # (gap_lost's length check)


@pytest.mark.parametrize("fields", [
    {},
    {"flags": cap.Flags.SYNTHETIC, "baud": 1_000_000, "t0_wall": 1.7e9, "t0_monotonic": 12.5, "protocol": "dynamixel",
     "description": "bench arm, endpoint arm"},
    {"protocol": None, "baud": 0xFFFFFFFF, "t0_wall": -0.0, "description": "é" * 200},  # cut inside a character
    {"protocol": "p" * 300, "description": "d" * 300},  # (cut to 255 characters each)
])
def test_the_header_s_fast_path_is_the_layout(fields):
    body = {"flags": int(fields.get("flags", cap.Flags.MEASURED)), "baud": fields.get("baud") or 0,
            "t0_wall": fields.get("t0_wall", 0.0), "t0_monotonic": fields.get("t0_monotonic", 0.0),
            "protocol": (fields.get("protocol") or "")[:255],
            "description": fields.get("description", "").encode()[:255].decode(errors="ignore")}
    fast = cap.build_header(**fields)
    assert fast == cap.Header.build({"version": cap.VERSION, "body": body})
    assert cap.parse_header(fast).description == body["description"]
