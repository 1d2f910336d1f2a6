"""Dynamixel Protocol 2.0 codec: every vector of the spec sheet (§9), stuffing, fast replies, decoder."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.checksums import crc16_buypass
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814
from hilbench.protocols.problem import Problem


def h(s: str) -> bytes:
    return bytes.fromhex(s)


def test_crc_check_value_and_manual_example():
    assert crc16_buypass(b"123456789") == 0xFEE8  # vector 1
    assert crc16_buypass(h("FF FF FD 00 01 07 00 02 00 00 02 00")) == 0x5121  # vector 2


# (vector number, bytes, id, instruction, fields given to build())
INSTRUCTION_VECTORS = [
    (3, "FF FF FD 00 01 03 00 01 19 4E", 1, I.PING, {}),
    (4, "FF FF FD 00 FE 03 00 01 31 42", 0xFE, I.PING, {}),
    (9, "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", 1, I.READ, {"address": 132, "length": 4}),
    (11, "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", 1, I.WRITE, {"address": 116, "data": h("00020000")}),
    (13, "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E", 1, I.REG_WRITE, {"address": 104, "data": h("C8000000")}),
    (14, "FF FF FD 00 01 03 00 05 02 CE", 1, I.ACTION, {}),
    (15, "FF FF FD 00 01 04 00 06 FF A6 64", 1, I.FACTORY_RESET, {"mode": 0xFF}),
    (16, "FF FF FD 00 01 04 00 06 01 A1 E6", 1, I.FACTORY_RESET, {"mode": 0x01}),
    (17, "FF FF FD 00 01 04 00 06 02 AB E6", 1, I.FACTORY_RESET, {"mode": 0x02}),
    (18, "FF FF FD 00 01 03 00 08 2F 4E", 1, I.REBOOT, {}),
    (19, "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", 1, I.CLEAR, {"mode": 1, "key": b'DXL"'}),
    (20, "FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5", 1, I.BACKUP, {"mode": 1}),
    (21, "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA", 0xFE, I.SYNC_READ,
     {"address": 132, "length": 4, "ids": [1, 2]}),
    (23, "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87", 0xFE, I.SYNC_WRITE,
     {"address": 116, "length": 4, "entries": [{"id": 1, "data": h("96000000")}, {"id": 2, "data": h("AA000000")}]}),
    (24, "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05", 0xFE, I.BULK_READ,
     {"entries": [{"id": 1, "address": 144, "length": 2}, {"id": 2, "address": 146, "length": 1}]}),
    (27, "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68", 0xFE, I.BULK_WRITE,
     {"entries": [{"id": 1, "address": 32, "length": 2, "data": h("A000")},
                  {"id": 2, "address": 31, "length": 1, "data": h("50")}]}),
    (28, "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2", 0xFE, I.FAST_SYNC_READ,
     {"address": 132, "length": 4, "ids": [3, 7, 4]}),
    (30, "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D", 0xFE, I.FAST_BULK_READ,
     {"entries": [{"id": 3, "address": 132, "length": 4}, {"id": 7, "address": 124, "length": 2},
                  {"id": 4, "address": 146, "length": 1}]}),
    (32, "FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD 00 21 E7", 1, I.WRITE, {"address": 116, "data": h("FFFFFD00")}),
    (36, "FF FF FD 00 01 07 00 02 46 00 01 00 3C A3", 1, I.READ, {"address": 70, "length": 1}),
    (38, "FF FF FD 00 FE 1B 00 82 84 00 04 00 01 02 03 04 05 06 07 08 09 0A 0B 0C 0D 0E 0F 10 11 12 13 14 89 AF",
     0xFE, I.SYNC_READ, {"address": 132, "length": 4, "ids": list(range(1, 21))}),
    (40, "FF FF FD 00 65 07 00 02 24 00 10 00 62 2C", 101, I.READ, {"address": 36, "length": 16}),
    (41, "FF FF FD 00 01 06 00 03 40 00 00 DE E6", 1, I.WRITE, {"address": 64, "data": b"\x00"}),
]

# (vector number, bytes, id, error, data)
STATUS_VECTORS = [
    (5, "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D", 1, 0, h("060426")),
    (6, "FF FF FD 00 01 07 00 55 00 37 01 29 90 C0", 1, 0, h("370129")),
    (7, "FF FF FD 00 08 07 00 55 00 41 01 29 1D D6", 8, 0, h("410129")),
    (8, "FF FF FD 00 01 07 00 55 00 FC 03 34 42 C3", 1, 0, h("FC0334")),
    (10, "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0", 1, 0, (166).to_bytes(4, "little")),
    (12, "FF FF FD 00 01 04 00 55 00 A1 0C", 1, 0, b""),
    (22, "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE", 2, 0, (2079).to_bytes(4, "little")),
    (25, "FF FF FD 00 01 06 00 55 00 77 00 C3 69", 1, 0, (119).to_bytes(2, "little")),
    (26, "FF FF FD 00 02 05 00 55 00 24 8B A9", 2, 0, bytes([36])),
    (34, "FF FF FD 00 01 0F 00 55 00 FF FF FD FD 00 00 00 00 08 00 00 61 00", 1, 0,
     h("FFFF") + (253).to_bytes(4, "little") + (2048).to_bytes(4, "little")),
    (35, "FF FF FD 00 01 04 00 55 07 B0 8C", 1, 7, b""),
    (37, "FF FF FD 00 01 05 00 55 80 24 82 A1", 1, 0x80, bytes([0x24])),
    (39, "FF FF FD 00 01 08 00 55 00 32 08 00 00 15 50", 1, 0, (2098).to_bytes(4, "little")),
]


@pytest.mark.parametrize("num,hexbytes,pid,inst,fields", INSTRUCTION_VECTORS, ids=[f"v{v[0]}" for v in INSTRUCTION_VECTORS])
def test_instruction_vectors(num, hexbytes, pid, inst, fields):
    raw = h(hexbytes)
    # construct reference path, both directions
    assert dxl.build(pid, inst, **fields) == raw
    pkt = dxl.parse(raw)
    assert (pkt.id, pkt.instruction) == (pid, inst)
    decoded = pkt.fields()
    for key, value in fields.items():
        got = decoded[key]
        if key == "entries":
            got = [{k: v for k, v in e.items() if not k.startswith("_")} for e in got]
        assert got == value, key
    # fast path agrees with construct
    assert dxl.instruction_packet(pid, inst, pkt.params) == raw
    # stream decoder agrees with construct
    (item,) = dxl.Decoder().feed(raw)
    assert item == pkt
    assert dxl.check_instruction(pkt) is None


@pytest.mark.parametrize("num,hexbytes,pid,err,data", STATUS_VECTORS, ids=[f"v{v[0]}" for v in STATUS_VECTORS])
def test_status_vectors(num, hexbytes, pid, err, data):
    raw = h(hexbytes)
    pkt = dxl.parse(raw)
    assert isinstance(pkt, dxl.StatusPacket)
    assert (pkt.id, pkt.error, pkt.data) == (pid, err, data)
    assert dxl.status_packet(pid, err, data) == raw
    assert dxl.build(pid, I.STATUS, error=err, data=data) == raw
    (item,) = dxl.Decoder().feed(raw)
    assert item == pkt


def test_ping_reply_fields():
    pkt = dxl.parse(h("FF FF FD 00 01 07 00 55 00 37 01 29 90 C0"))
    reply = dxl.PingReply.parse(pkt.data)
    assert (reply.model_number, reply.firmware) == (311, 41)


def test_error_byte_meaning():
    access = dxl.parse(h("FF FF FD 00 01 04 00 55 07 B0 8C"))
    assert (access.alert, access.error_number) == (False, dxl.ErrorNumber.ACCESS_ERROR)
    assert dxl.describe_error(access.error) == "access error"
    alert = dxl.parse(h("FF FF FD 00 01 05 00 55 80 24 82 A1"))
    assert alert.alert and alert.error_number == 0
    assert dxl.describe_hardware_error(alert.data[0]) == ["overheating", "overload"]


def test_sdk_unstuffed_write_is_accepted_and_strict_mode_flags_it():
    raw = h("FF FF FD 00 01 09 00 03 74 00 FF FF FD 00 C9 07")  # vector 33
    assert dxl.instruction_packet_unstuffed(1, I.WRITE, h("7400FFFFFD00")) == raw
    (pkt,) = dxl.Decoder().feed(raw)
    assert pkt.fields().address == 116
    assert int.from_bytes(pkt.fields().data, "little") == 0x00FDFFFF
    strict = dxl.Decoder(strict_stuffing=True)
    (problem,) = strict.feed(raw)
    assert problem.kind == "stuffing" and strict.problems["stuffing"] == 1
    # the properly stuffed form (vector 32) passes strict mode
    (ok,) = dxl.Decoder(strict_stuffing=True).feed(h("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD 00 21 E7"))
    assert ok.params == h("7400FFFFFD00")


FAST_SYNC_REPLY = h("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E")
FAST_BULK_REPLY = h("FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1")


def test_fast_sync_read_reply_vector_29():
    slices = [(3, 0, (166).to_bytes(4, "little")), (7, 0, (2079).to_bytes(4, "little")),
              (4, 0, (1023).to_bytes(4, "little"))]
    assert dxl.build_fast_reply([(i, e, d) for i, e, d in slices]) == FAST_SYNC_REPLY
    (pkt,) = dxl.Decoder().feed(FAST_SYNC_REPLY)
    assert pkt.is_fast_reply and pkt.error == 0
    got = dxl.split_fast_reply(pkt.raw, [4, 4, 4])
    assert [(s.id, int.from_bytes(s.data, "little")) for s in got] == [(3, 166), (7, 2079), (4, 1023)]
    assert all(s.crc_ok for s in got)
    # slice CRCs as the sheet gives them
    assert FAST_SYNC_REPLY[14:16] == (0x0884).to_bytes(2, "little")
    assert FAST_SYNC_REPLY[22:24] == (0xCA16).to_bytes(2, "little")


def test_fast_bulk_read_reply_vector_31():
    reply = dxl.build_fast_reply([(3, 0, (166).to_bytes(4, "little")), (7, 0, (421).to_bytes(2, "little")),
                                  (4, 0, bytes([31]))])
    assert reply == FAST_BULK_REPLY
    got = dxl.split_fast_reply(reply, [4, 2, 1])
    assert [(s.id, int.from_bytes(s.data, "little"), s.crc_ok) for s in got] == [
        (3, 166, True), (7, 421, True), (4, 31, True)]
    # a reply shorter than the request yields fewer slices instead of raising
    assert len(dxl.split_fast_reply(reply, [4, 2, 1, 4])) == 3


def test_fast_reply_is_never_unstuffed():
    # a slice whose data holds FF FF FD FD must come back verbatim
    reply = dxl.build_fast_reply([(1, 0, h("FFFFFDFD"))])
    (pkt,) = dxl.Decoder().feed(reply)
    assert dxl.split_fast_reply(pkt.raw, [4])[0].data == h("FFFFFDFD")
    assert dxl.parse(reply).data[1:5] == h("FFFFFDFD")


@pytest.mark.parametrize(
    "pid,inst,params,reason",
    [
        (1, I.READ, b"\x84\x00\x04", "needs 4"),
        (1, I.PING, b"\x00", "needs 0"),
        (1, I.FACTORY_RESET, b"\x05", "mode"),
        (1, I.SYNC_READ, h("84000400 0102"), "broadcast"),
        (0xFE, I.SYNC_READ, h("84000400 01FE"), "broadcast id"),
        (0xFE, I.SYNC_WRITE, h("74000400 01960000"), "tile"),
        (0xFE, I.BULK_READ, h("0190000200 0192000100 01"), "5-byte"),
        (0xFE, I.BULK_READ, h("0190000200 0192000100"), "twice"),
        (0xFE, I.BULK_WRITE, h("0120000200A0"), "tile"),
        (1, 0x77, b"", "unknown"),
        (1, I.WRITE, b"\x74", "address"),
    ],
)
def test_validation_rules(pid, inst, params, reason):
    pkt = dxl.InstructionPacket(pid, inst, params, b"")
    assert reason in dxl.check_instruction(pkt)


def test_decoder_resynchronises_and_counts():
    good = h("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
    bad_crc = good[:-1] + b"\x00"
    garbage = b"\x00\x13\xff\xff\xfd"  # includes a partial header
    dec = dxl.Decoder()
    items = dec.feed(garbage + bad_crc + good + b"\xff\xff\xfd\x00\x01\xff\xff" + good)
    kinds = [getattr(i, "kind", "packet") for i in items]
    assert kinds == ["crc", "packet", "bad_length", "packet"]
    assert dec.packets == 2 and dec.problems["crc"] == 1 and dec.problems["bad_length"] == 1


def test_decoder_truncated_at_end_and_rescans_the_rest():
    good = h("FF FF FD 00 01 03 00 01 19 4E")
    # a header claiming 40 bytes, followed by a good packet that it would swallow
    dec = dxl.Decoder()
    assert dec.feed(h("FF FF FD 00 01 28 00 02") + good) == []
    items = dec.flush()
    assert [getattr(i, "kind", "packet") for i in items] == ["truncated", "packet"]
    assert items[1].instruction == I.PING


def test_decoder_inter_byte_timeout_drops_a_stalled_packet():
    good = h("FF FF FD 00 01 03 00 01 19 4E")
    dec = dxl.Decoder(inter_byte_timeout=0.0015)
    assert dec.feed(good[:6], t=0.0) == []
    items = dec.feed(good[6:] + good, t=0.010)
    assert [getattr(i, "kind", "packet") for i in items] == ["truncated", "packet"]


def test_decoder_memory_is_bounded_by_the_length_cap():
    dec = dxl.Decoder()
    dec.feed(h("FF FF FD 00 01 FF FF"))  # LENGTH 65535 rejected at once
    assert dec.pending <= 3
    dec.feed(h("FF FF FD 00 01 00 04") + bytes(500))  # LENGTH 1024: waits, but bounded
    assert dec.pending <= 7 + dxl.MAX_LENGTH
    for _ in range(100):
        dec.feed(bytes(1000))
    assert dec.pending <= 3


# ---------------------------------------------------------------- property tests

ids = st.integers(0, 0xFC)
payload = st.binary(max_size=64)


@st.composite
def instructions(draw):
    inst = draw(st.sampled_from([I.PING, I.READ, I.WRITE, I.REG_WRITE, I.SYNC_READ, I.SYNC_WRITE, I.BULK_READ]))
    if inst == I.PING:
        return draw(ids), inst, {}
    if inst == I.READ:
        return draw(ids), inst, {"address": draw(st.integers(0, 0xFFFF)), "length": draw(st.integers(0, 0xFFFF))}
    if inst in (I.WRITE, I.REG_WRITE):
        return draw(ids), inst, {"address": draw(st.integers(0, 0xFFFF)), "data": draw(payload)}
    if inst == I.SYNC_READ:
        return 0xFE, inst, {"address": draw(st.integers(0, 700)), "length": draw(st.integers(0, 8)),
                            "ids": draw(st.lists(ids, max_size=20))}
    if inst == I.SYNC_WRITE:
        n = draw(st.integers(1, 4))
        return 0xFE, inst, {"address": draw(st.integers(0, 700)), "length": n,
                            "entries": draw(st.lists(st.builds(dict, id=ids, data=st.binary(min_size=n, max_size=n)),
                                                     max_size=10))}
    return 0xFE, inst, {"entries": draw(st.lists(st.builds(dict, id=ids, address=st.integers(0, 700),
                                                           length=st.integers(0, 8)), max_size=10))}


@settings(max_examples=300)
@given(instructions())
def test_roundtrip_instruction(spec):
    pid, inst, fields = spec
    raw = dxl.build(pid, inst, **fields)
    pkt = dxl.parse(raw)
    assert raw == dxl.instruction_packet(pid, inst, pkt.params)
    (item,) = dxl.Decoder(strict_stuffing=True).feed(raw)
    assert item == pkt
    assert dxl.PARAMS[inst].build(pkt.fields()) == dxl.PARAMS[inst].build(fields)


@settings(max_examples=300)
@given(ids, st.integers(0, 0xFF), payload)
def test_roundtrip_status_with_stuffing(pid, err, data):
    raw = dxl.status_packet(pid, err, data)
    assert raw == dxl.build(pid, I.STATUS, error=err, data=data)
    (item,) = dxl.Decoder(strict_stuffing=True).feed(raw)
    assert (item.id, item.error, item.data) == (pid, err, data)


@settings(max_examples=500)
@given(st.binary(max_size=600), st.lists(st.integers(1, 50), max_size=20))
def test_random_bytes_never_crash(blob, cuts):
    dec = dxl.Decoder()
    pos = 0
    for c in cuts:
        dec.feed(blob[pos:pos + c])
        pos += c
    dec.feed(blob[pos:])
    dec.flush()
    assert dec.pending == 0
    assert dec.bytes_in == len(blob)


@settings(max_examples=300)
@given(st.lists(instructions(), min_size=1, max_size=8), st.binary(max_size=40), st.integers(0, 10_000))
def test_mutated_streams_keep_every_untouched_packet(specs, junk, seed):
    """Garbage between packets never costs a packet that arrived intact."""
    packets = [dxl.build(p, i, **f) for p, i, f in specs]
    junk = junk.replace(b"\xff\xff\xfd", b"")  # junk must not forge headers
    stream = junk.join(packets) + junk
    cut = seed % (len(stream) + 1)
    dec = dxl.Decoder()
    items = dec.feed(stream[:cut]) + dec.feed(stream[cut:]) + dec.flush()
    got = [i.raw for i in items if not isinstance(i, Problem)]
    for raw in packets:
        assert raw in got


def reference_frames(stream: bytes, max_length: int = dxl.MAX_LENGTH) -> list:
    """Spec §1.7 framed the slow, obvious way, with the construct layout judging each candidate."""
    out = []
    pos = 0
    while (start := stream.find(dxl.HEADER, pos)) >= 0:
        pos = start + 1
        if start + 7 > len(stream):
            out.append(("truncated", stream[start:]))
            continue
        length = stream[start + 5] | stream[start + 6] << 8
        end = start + 7 + length
        if not 3 <= length <= max_length:
            out.append(("bad_length", stream[start : start + 7]))
        elif end > len(stream):
            out.append(("truncated", stream[start:]))
        elif length == 3 and stream[start + 7] == dxl.STATUS:
            out.append(("bad_length", stream[start:end]))
        else:
            try:
                out.append(dxl.parse(stream[start:end]))
                pos = end
            except Exception:
                out.append(("crc", stream[start:end]))
    return out


packet_bytes = st.one_of(
    st.builds(dxl.instruction_packet_unstuffed, st.integers(0, 0xFE), st.sampled_from([1, 2, 3, 0x82, 0x83]),
              st.binary(max_size=12).map(lambda b: b.replace(b"\x01", b"\xff\xff\xfd\x00"))),
    st.builds(dxl.status_packet, st.integers(0, 0xFC), st.integers(0, 255),
              st.binary(max_size=12).map(lambda b: b.replace(b"\x01", b"\xff\xff\xfd"))),
    st.builds(lambda d: dxl.build_fast_reply([(3, 0, d), (7, 0, d)]), st.binary(min_size=4, max_size=4)),
    st.binary(max_size=16),
    st.just(dxl.HEADER),
)


@settings(max_examples=400)
@given(st.lists(packet_bytes, max_size=10), st.integers(0, 255), st.integers(0, 10_000), st.sampled_from([20, 1024]))
def test_split_fast_path_frames_exactly_like_the_reference(parts, flip, where, max_length):
    stream = bytearray(b"".join(parts))
    if stream and flip:
        stream[where % len(stream)] ^= flip  # corrupt one byte somewhere
    stream = bytes(stream)
    dec = dxl.Decoder(max_length=max_length)
    cut = where % (len(stream) + 1)
    items = dec.feed(stream[:cut]) + dec.feed(stream[cut:]) + dec.flush()
    got = [(i.kind, i.raw) if isinstance(i, Problem) else i for i in items]
    assert got == reference_frames(stream, max_length)
