"""The XRCE codec against the spec sheet's vectors (udp.md §4), both ways, and on garbage."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import xrce_dds as x

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
spec = importlib.util.spec_from_file_location("udp_vectors", Path(__file__).resolve().parents[1] / "udp_vectors.py")
V = importlib.util.module_from_spec(spec)
spec.loader.exec_module(V)
X, KEY = V.X, V.KEY


@pytest.mark.parametrize("name", sorted(set(X) - {"X21"}))
def test_every_vector_parses_clean(name: str) -> None:
    msg = x.parse_message(X[name])
    assert msg.flags == []
    assert all(s.problem is None for s in msg.submessages)
    assert msg.size == len(X[name])


def test_fields_of_the_vectors() -> None:
    cc = x.parse_message(X["X3"]).submessages[0].fields
    assert (cc.client_key, cc.session_id, cc.mtu, cc.xrce_cookie) == (KEY, 0x81, 508, b"XRCE")
    wd = x.parse_message(X["X8"]).submessages[0]
    assert wd.name == "WRITE_DATA" and wd.fields.object_id == b"\x00\x25"
    assert wd.fields.data == V.R6["string_hello"]  # the 2 trailing pad bytes are not data
    create = x.parse_message(X["X9"]).submessages[0]
    assert create.flags == x.FLAG_E | x.FLAG_REPLACE
    rep = create.fields.object_representation
    assert rep.kind == x.ObjectKind.PARTICIPANT and rep.rep.representation.value == "default_xrce_participant"
    rd = x.parse_message(X["X14"]).submessages[0].fields
    assert (rd.preferred_stream_id, rd.delivery_control.max_samples) == (1, 0xFFFF)
    ts = x.parse_message(X["X18"]).submessages[0].fields
    assert (ts.transmit.seconds, ts.transmit.nanoseconds, ts.originate.seconds) == (1742552565, 500010000, 100)
    info = x.parse_message(X["X2"]).submessages[0].fields
    assert info.activity.info.availability == 1 and info.implementation_status == 0
    assert x.parse_message(X["X5"]).client_key == KEY and x.parse_message(X["X7k"]).session_id == 1


def test_builders_reproduce_the_vectors() -> None:
    b = x.build_message
    assert b(0x80, 0, 0, [(0, 1, x.client_representation(KEY, 0x81))]) == X["X3"]
    assert b(0x00, 0, 0, [(0, 1, x.client_representation(KEY, 0x01))], client_key=KEY) == X["X5"]
    assert b(0x81, 0, 0, [(4, 1, x.status_agent())]) == X["X4"]
    assert b(0x01, 0, 0, [(4, 1, x.status_agent())], client_key=KEY) == X["X6"]
    assert b(0x80, 0, 0, [(6, 1, x.info_agent(b"\x00\x0a", x.OBJECT_AGENT, 0))]) == X["X2"]
    assert b(0x80, 0, 0, [(2, 1, x.get_info())]) == X["X1"]
    assert b(0x81, 1, 0, [(7, 1, x.data(b"\x00\x0a", x.object_id(1, x.ObjectKind.DATAWRITER),
                                         bytes.fromhex("2A000000")))]) == X["X7"]
    rep = {"representation": {"format": x.REPRESENTATION_BY_REFERENCE, "value": "default_xrce_participant"},
           "domain_id": 0}
    assert b(0x81, 0x80, 0, [(1, 5, x.create(b"\x00\x0d", x.object_id(1, 1), 1, rep))]) == X["X9"]
    assert b(0x81, 0, 0, [(11, 1, x.heartbeat(0, 0, 0x80))]) == X["X10"]
    assert b(0x81, 0, 0, [(10, 1, x.acknack(1, 0, 0x80))]) == X["X11"]
    assert b(0x81, 0x80, 0, [(5, 1, x.status(b"\x00\x0d", x.object_id(1, 1)))]) == X["X12"]
    assert b(0x81, 0x80, 1, [(8, 1, x.read_data(b"\x00\x0e", x.object_id(1, x.ObjectKind.DATAREADER), 1))]) \
        == X["X14"]
    assert b(0x81, 0, 0, [(10, 1, x.acknack(1, 0x0003, 0x80))]) == X["X16"]
    assert b(0x81, 0, 0, [(14, 1, x.timestamp(100, 0))]) == X["X17"]
    assert b(0x81, 0, 0, [(15, 1, x.timestamp_reply((1742552565, 500010000), (1742552565, 500000000),
                                                      (100, 0)))]) == X["X18"]
    assert b(0x81, 0, 0, [(3, 1, x.delete(b"\x00\x02", x.OBJECT_CLIENT))]) == X["X19"]
    assert b(0x81, 0, 0, [(5, 1, x.status(b"\x00\x02", x.OBJECT_CLIENT))]) == X["X20"]


def test_zeroed_datagram_raises_every_flag_the_sheet_names() -> None:
    msg = x.parse_message(X["X21"])
    assert {"xrce.zero_fill", "xrce.bad_length", "xrce.bad_create_client"} <= set(msg.flags)
    assert len(msg.submessages) == 1  # a run of zeros is not an endless series of CREATE_CLIENTs
    assert x.is_zero_fill(X["X21"]) and not x.is_zero_fill(X["X3"])


def test_object_ids_and_serial_arithmetic() -> None:
    assert x.object_id(1, x.ObjectKind.DATAWRITER) == b"\x00\x15"
    assert x.object_id(1, x.ObjectKind.DATAREADER) == b"\x00\x16"
    assert x.object_id(2, x.ObjectKind.DATAWRITER) == b"\x00\x25"
    assert x.split_object_id(b"\x12\x35") == (0x123, 5)
    assert x.seq_newer(1, 0) and x.seq_newer(0, 0xFFFF) and not x.seq_newer(0, 0) and not x.seq_newer(0, 1)


@pytest.mark.parametrize("name", sorted(X))
def test_fast_path_agrees_with_the_construct_parse(name: str) -> None:
    sid, stream, seq, subs, trailing = x.scan(X[name])
    msg = x.parse_message(X[name])
    assert (sid, stream, seq) == (msg.session_id, msg.stream_id, msg.sequence_nr)
    assert [(i, f, ln) for i, f, _, ln in subs] == [(s.id, s.flags, s.length) for s in msg.submessages]
    assert [X[name][o:o + ln] for _, _, o, ln in subs] == [s.payload for s in msg.submessages]


def test_bad_lengths_are_flags() -> None:
    short_hb = bytes.fromhex("81 00 00 00 0B 01 04 00 00 00 00 00")
    assert "xrce.bad_length" in x.parse_message(short_hb).flags
    beyond = bytes.fromhex("81 00 00 00 0B 01 50 00 00 00 00 00 80")
    assert "xrce.bad_length" in x.parse_message(beyond).flags
    trailing = X["X10"] + b"\x00" * 7
    assert "xrce.bad_length" in x.parse_message(trailing).flags
    assert x.parse_message(b"\x81").flags == ["xrce.malformed", "xrce.too_short"]
    assert x.looks_like_xrce(X["X3"]) and not x.looks_like_xrce(b"RTPS\x02\x01" + b"\x00" * 30)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=200))
def test_garbage_never_raises(data: bytes) -> None:
    x.parse_message(data)
    x.scan(data)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(sorted(X)), st.integers(0, 63), st.integers(0, 255))
def test_mutated_vectors_never_raise(name: str, pos: int, value: int) -> None:
    data = bytearray(X[name])
    data[pos % len(data)] = value
    x.parse_message(bytes(data))
    x.scan(bytes(data))
