"""Dynamixel Protocol 1.0 codec: the spec sheet's vectors (§1.8, §9 #42-43), layouts, decoder."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols.checksums import dynamixel1_checksum
from hilbench.protocols.dynamixel_protocol1 import Instruction1 as I1  # noqa: N814


def h(s: str) -> bytes:
    return bytes.fromhex(s)


# (bytes, id, code, params) -- vectors 42, 43 and the other examples of §1.8
VECTORS = [
    ("FF FF 01 02 01 FB", 1, I1.PING, b""),  # 42: ping
    ("FF FF 01 02 00 FC", 1, 0, b""),  # ping status
    ("FF FF 01 04 02 2B 01 CC", 1, I1.READ, h("2B01")),  # 43: read 43/1
    ("FF FF 01 03 00 20 DB", 1, 0, h("20")),  # 43: status, value 32
    ("FF FF 01 05 03 0C 64 AA DC", 1, I1.WRITE, h("0C64AA")),  # e-Manual checksum example
]


@pytest.mark.parametrize("hexbytes,pid,code,params", VECTORS)
def test_vectors_build_parse_and_decode(hexbytes, pid, code, params):
    raw = h(hexbytes)
    assert p1.build(pid, code, params) == raw
    assert dynamixel1_checksum(raw[2:-1]) == raw[-1]
    pkt = p1.parse(raw)
    assert (pkt.id, pkt.code, pkt.params) == (pid, code, params)
    (item,) = p1.Decoder1().feed(raw)
    assert item == pkt


def test_named_parameter_layouts():
    assert p1.build_instruction(1, I1.READ, address=43, length=1) == h("FF FF 01 04 02 2B 01 CC")
    assert p1.build_instruction(1, I1.WRITE, address=12, data=h("64AA")) == h("FF FF 01 05 03 0C 64 AA DC")
    assert p1.parse(h("FF FF 01 04 02 2B 01 CC")).fields().address == 43
    sync = p1.build_instruction(0xFE, I1.SYNC_WRITE, address=30, length=2,
                                entries=[{"id": 1, "data": h("0002")}, {"id": 2, "data": h("1003")}])
    fields = p1.parse(sync).fields()
    assert (fields.address, fields.length) == (30, 2)
    assert [(e.id, e.data) for e in fields.entries] == [(1, h("0002")), (2, h("1003"))]
    bulk = p1.build_instruction(0xFE, I1.BULK_READ, zero=None,
                                entries=[{"length": 2, "id": 1, "address": 36}])
    assert p1.parse(bulk).params == h("00 02 01 24")


def test_bad_checksum_raises_in_parse_but_not_in_the_decoder():
    bad = h("FF FF 01 02 01 FA")
    with pytest.raises(Exception):  # noqa: B017 - construct's ChecksumError
        p1.parse(bad)
    dec = p1.Decoder1()
    items = dec.feed(bad + h("FF FF 01 02 01 FB"))
    assert [type(i).__name__ for i in items] == ["Problem", "Packet1"]
    assert items[0].kind == "checksum" and dec.problems["checksum"] == 1
    assert dec.packets == 1


def test_decoder_resynchronises_over_garbage_and_split_chunks():
    stream = h("00 13 FF") + h("FF FF 01 04 02 2B 01 CC") + h("AA") + h("FF FF 01 03 00 20 DB")
    dec = p1.Decoder1()
    items = []
    for i in range(len(stream)):  # byte by byte: a header may straddle chunks
        items += dec.feed(stream[i : i + 1])
    items += dec.flush()
    assert [(i.id, i.code, i.params) for i in items] == [(1, 2, h("2B01")), (1, 0, h("20"))]
    assert dec.bytes_skipped == 3 + 1


def test_truncated_packet_at_end_is_reported():
    dec = p1.Decoder1()
    assert dec.feed(h("FF FF 01 04 02 2B")) == []
    (problem,) = dec.flush()
    assert problem.kind == "truncated" and dec.problems["truncated"] == 1


@settings(max_examples=300)
@given(st.integers(0, 0xFD), st.integers(0, 0xFF), st.binary(max_size=40))
def test_roundtrip(pid, code, params):
    raw = p1.build(pid, code, params)
    (item,) = p1.Decoder1().feed(raw)
    assert (item.id, item.code, item.params, item.raw) == (pid, code, params, raw)


@settings(max_examples=500)
@given(st.binary(max_size=400), st.lists(st.integers(1, 30), max_size=20))
def test_random_bytes_never_crash(blob, cuts):
    dec = p1.Decoder1()
    pos = 0
    for c in cuts:
        dec.feed(blob[pos : pos + c])
        pos += c
    dec.feed(blob[pos:])
    dec.flush()
    assert dec._buf == b""
