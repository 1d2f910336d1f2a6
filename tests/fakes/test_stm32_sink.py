"""The trace sink: binary word acceptance (vectorised and small-batch paths agree), record buffers, the wire."""

from __future__ import annotations

import numpy as np

from hilbench.fakes.stm32_board.sink import BinaryWriter, RecordBuffer, Ring, Truth, Wire
from hilbench.protocols.tracestamp_stream import decode_all, stamps_of


def stamps(n: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 3000, n)).astype(np.int64)
    return t, rng.integers(0, 8, n).astype(np.int16), rng.integers(0, 2, n).astype(bool)


def fill(chunk: int, size: int):
    ring, truth = Ring(size), Truth()
    w = BinaryWriter(ring, truth)
    ring.write(w.start(1))
    t, ids, b = stamps(600)
    for i in range(0, len(t), chunk):
        w.write(t[i : i + chunk], ids[i : i + chunk], b[i : i + chunk])
    return bytes(ring.buf), truth, w


def test_small_batches_and_vectorised_batches_write_the_same_words():
    for size in (1 << 16, 2048):  # room for all, and a ring that fills up and drops
        big = fill(600, size)
        small = fill(7, size)
        assert big[0] == small[0]
        assert (big[1].stamps_sent, big[1].stamps_dropped) == (small[1].stamps_sent, small[1].stamps_dropped)
        assert big[2].pending_drops == small[2].pending_drops
    assert big[1].stamps_dropped > 0  # the small ring overflowed


def test_words_decode_and_drops_are_reported_after_space_returns():
    ring, truth = Ring(512), Truth()
    w = BinaryWriter(ring, truth)
    out = bytearray()
    ring.write(w.start(3))
    t, ids, b = stamps(600, seed=2)
    for i in range(0, 600, 150):  # 150 stamps need ~640 bytes: each batch overflows the 512-byte ring
        w.write(t[i : i + 150], ids[i : i + 150], b[i : i + 150])
        out += ring.buf  # drain everything (the DMA), so space returns
        ring.buf.clear()
    ring.write(w.stop(int(t[-1])))
    out += ring.buf
    names = "".join(f"@id {i} task{i}\n" for i in range(8)).encode()
    items = decode_all(b"@tsb 1\n" + names + bytes(out))
    got = stamps_of(items)
    assert truth.stamps_dropped > 0 and len(got) == truth.stamps_sent
    assert sum(i.value for i in items if type(i).__name__ == "Marker" and i.kind == "drops") == truth.stamps_dropped
    sent = set(zip(t.tolist(), ids.tolist(), strict=True))
    assert all((s.t_us, int(s.name[4:])) in sent for s in got)


def test_record_buffers_ring_and_array():
    ring = RecordBuffer(4, "ring")
    t = np.arange(10.0)
    assert ring.push(t, np.zeros(10, np.int16), np.ones(10, bool)) == 6 and list(ring.take()[0]) == [6, 7, 8, 9]
    arr = RecordBuffer(4, "array")
    arr.push(t, np.zeros(10, np.int16), np.ones(10, bool))  # the index wrapped twice: 10 % 4 = 2 survive
    assert list(arr.take()[0]) == [8.0, 9.0] and arr.lost == 8


def test_record_ring_keeps_the_newest_records_across_many_pushes():
    ring = RecordBuffer(5, "ring")
    lost = 0
    for start in range(0, 100, 3):  # 34 pushes of 3 (the last of 1): chunks pile up and get cut
        t = np.arange(start, min(start + 3, 100), dtype=float)
        lost += ring.push(t, t.astype(np.int16), np.ones(len(t), bool))
        assert len(ring) == min(5, start + len(t))
    t, ids, b = ring.take()
    assert t.tolist() == [95, 96, 97, 98, 99] and ids.tolist() == [95, 96, 97, 98, 99] and b.all()
    assert lost == ring.lost == 95 and len(ring) == 0 and len(ring.take()[0]) == 0


def test_wire_paces_bytes_at_the_baud():
    w = Wire(115_200)
    w.send(0.0, b"abcdefghij")  # 10 bytes = 868 µs
    data, t_last = w.take(200.0)
    assert data == b"ab" and abs(t_last - 2 * 86.8056) < 1e-3
    assert w.take(10_000.0)[0] == b"cdefghij" and w.pending() == 0
