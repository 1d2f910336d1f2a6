"""The decoder's two framing loops (plain Python for small buffers, numpy-judged for large) agree exactly."""

from __future__ import annotations

from contextlib import contextmanager

from hypothesis import example, given, settings
from hypothesis import strategies as st

from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.problem import Problem

from .test_dynamixel import packet_bytes, reference_frames


def _patterned(blob: bytes) -> bytes:
    return blob.replace(b"\x01", b"\xff\xff\xfd")  # FF FF FD followed by anything, or by nothing


_ids = st.integers(0, 0xFE)
_codes = st.sampled_from([0x01, 0x02, 0x03, 0x55, 0x82, 0x83, 0x92, 0xFF])
# a leading FF FD makes FF FF FD right after an instruction code FF
_bodies = st.tuples(st.sampled_from([b"", b"\xff\xfd", b"\xff\xfd\xfd"]), st.binary(max_size=12)).map(
    lambda p: p[0] + _patterned(p[1])
)
#: What the spec sheet's tests send, plus the corner cases of the candidate checks: stuffed and
#: unstuffed bodies with FF FF FD at every place (the end of the body included), broadcast
#: instructions, statuses sent unstuffed, and 10-byte "statuses" (LENGTH 3).
stream_parts = st.one_of(
    packet_bytes,
    st.builds(dxl.instruction_packet, _ids, _codes, _bodies),
    st.builds(dxl.instruction_packet_unstuffed, _ids, _codes, _bodies),
    st.builds(lambda pid, err, data: dxl._frame(pid, bytes((0x55, err)) + data), _ids, st.integers(0, 255), _bodies),
)


@contextmanager
def framing(path: str):
    """Force every ``_scan`` through one path: ``"vector"`` (numpy) or ``"plain"``."""
    saved = dxl.VECTOR_MIN
    dxl.VECTOR_MIN = 0 if path == "vector" else 1 << 62
    try:
        yield
    finally:
        dxl.VECTOR_MIN = saved


def decode(stream: bytes, cuts: list[int], path: str, **kw) -> tuple[list, tuple]:
    with framing(path):
        dec = dxl.Decoder(**kw)
        items = []
        pos = 0
        for k, c in enumerate(cuts):
            items += dec.feed(stream[pos : pos + c], float(k))
            pos += c
        items += dec.feed(stream[pos:], -1.0) + dec.flush(-2.0)
    return items, (dec.packets, dec.bytes_skipped, dict(dec.problems), dec.bytes_in, dec.pending)


@settings(max_examples=600, deadline=None)
@given(
    st.lists(stream_parts, max_size=12),
    st.integers(0, 255),
    st.integers(0, 10_000),
    st.lists(st.integers(1, 60), max_size=6),
    st.sampled_from([20, 1024, 65535]),
    st.booleans(),
)
# the corners of the candidate checks, so every run covers them
@example([dxl.instruction_packet_unstuffed(1, 0x03, b"\x74\x00\xff\xff\xfd")], 0, 0, [], 1024, True)  # FF FF FD ends the body
@example([dxl.instruction_packet(0xFE, 0x83, b"\x74\x00\x04\x00\x01\xff\xff\xfd\x00")], 0, 0, [], 1024, False)
@example([dxl.instruction_packet(1, 0xFF, b"\xff\xfd\x00")], 0, 0, [], 1024, False)  # stuffing from the code byte
@example([dxl.instruction_packet_unstuffed(1, 0x55, b"")], 0, 0, [], 1024, False)  # a status with LENGTH 3
def test_vector_framing_equals_plain_framing(parts, flip, where, cuts, max_length, strict):
    stream = bytearray(b"".join(parts))
    if stream and flip:
        stream[where % len(stream)] ^= flip  # corrupt one byte somewhere
    stream = bytes(stream)
    kw = {"max_length": max_length, "strict_stuffing": strict}
    vector = decode(stream, cuts, "vector", **kw)
    assert vector == decode(stream, cuts, "plain", **kw)
    if not strict:
        got = [(i.kind, i.raw) if isinstance(i, Problem) else i[:4] for i in vector[0]]
        assert got == [r if type(r) is tuple else r[:4] for r in reference_frames(stream, max_length)]


def test_vector_framing_equals_plain_framing_on_the_capture(wolfgang_capture):
    data = wolfgang_capture
    for chunk in (len(data), 65536, 4096, 2500):
        cuts = [chunk] * (len(data) // chunk)
        for kw in ({}, {"max_length": 65535}):
            vector = decode(data, cuts, "vector", **kw)
            assert vector == decode(data, cuts, "plain", **kw)
            assert vector[1][0] == (23_478 if not kw else vector[1][0])


def test_scan_stores_the_expected_replies_and_yields_the_rest():
    def sync_read(ids):
        return dxl.instruction_packet_unstuffed(0xFE, 0x82, bytes((132, 0, 4, 0, *ids)))

    first = [
        sync_read([1, 2, 3]),
        dxl.status_packet(1, 0, b"\x01\x00\x00\x00"),  # slotted
        dxl.status_packet(2, 4, b"\x02\x00\x00\x00"),  # ERR 4: yielded
        dxl.status_packet(3, 0, b"\x03\x00\x00"),  # one byte short: yielded
        dxl.status_packet(1, 0, b"\x09\x00\x00\x00"),  # slot 0 already filled: yielded
        dxl.status_packet(7, 0, b"\x07\x00\x00\x00"),  # no slot: yielded
    ]
    second = [sync_read([7]), dxl.status_packet(7, 0, b"\x08\x00\x00\x00")]  # slotted after re-pointing
    stream = b"".join(first + second) + bytes(dxl.VECTOR_MIN)
    slots = dxl.ReplySlots()
    filled, store, stamps = bytearray(3), [None] * 3, [0.0] * 3
    slots.point({1: 0, 2: 1, 3: 2}, (15, 15, 15), filled, store, stamps)
    later = (bytearray(1), [None], [0.0])
    dec = dxl.Decoder()
    got = []
    for item in dec.scan(stream, 5.0, slots=slots):
        got.append(item.raw)
        if item.raw == second[0]:
            slots.point({7: 0}, (15,), *later)
    assert got == [first[0], *first[2:], second[0]]
    assert (filled, store, stamps, slots.fills) == (b"\x01\x00\x00", [b"\x01\x00\x00\x00", None, None], [5.0, 0, 0], [0, 0])
    assert later == (b"\x01", [b"\x08\x00\x00\x00"], [5.0])
    assert dec.packets == len(first) + len(second)  # slotted replies count as packets
    with framing("plain"):  # small chunks are framed in plain Python: every packet is yielded
        assert [i.raw for i in dxl.Decoder().scan(b"".join(first), slots=slots)] == first
