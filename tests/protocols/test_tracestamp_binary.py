"""Binary stamp words: the documented worked example, round trips, unwrapping, drops, damage, mixed streams."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols.tracestamp import LogMessage, NameEntry, RuntimeReport, Stamp, StampBatch, TableStart
from hilbench.protocols.tracestamp_binary import Marker, Op, WordDecoder
from hilbench.protocols.tracestamp_stream import StreamDecoder, decode_all, decode_words, stamps_of

DOC = Path(__file__).resolve().parents[2] / "docs" / "formats" / "tracestamp-binary.md"


def test_worked_example_of_the_documentation():
    text = DOC.read_text()
    section = text[text.index("## Worked example") : text.index("## Robustness")]
    hex_block = section.split("```")[1]
    data = bytes.fromhex(" ".join(hex_block.split()))
    # The table: bytes -> uint32 -> payload -> id, row by row.
    rows = re.findall(r"^\| `([0-9a-f ]+)` \| 0x([0-9A-F]{8}) \| 0x([0-9A-F]{6}) \| (\d+) \|", section, re.M)
    assert len(rows) == 11
    words = data[data.index(b"\xff"):]
    for i, (bytes_hex, u32, payload, wid) in enumerate(rows):
        raw = bytes.fromhex(bytes_hex)
        assert words[4 * i : 4 * i + 4] == raw
        assert int.from_bytes(raw, "little") == int(u32, 16)
        p = int(payload, 16)
        assert tb.word_bytes(p) == raw and p >> 18 == int(wid)
    payloads, broken, consumed = tb.split_words(data)
    assert [f"{p:06X}" for p in payloads.tolist()] == [r[2] for r in rows] and broken == 0
    dec = StreamDecoder()
    items = dec.feed(data) + dec.flush()
    assert items == [
        TableStart(1), NameEntry(0, "IDLE"), NameEntry(1, "hal_fetch"), NameEntry(2, "wheel_ctrl"),
        Marker("window_start", 1, 0),
        Stamp("IDLE", 36, False), Stamp("hal_fetch", 37, True), Stamp("hal_fetch", 49, False),
        Stamp("wheel_ctrl", 49, True),
        Marker("drops", 3, 49),
        Stamp("IDLE", 131080, True),
        Marker("window_stop", 1, 131080),
    ]
    w = dec.words
    assert (w.checks_ok, w.checks_failed, w.drops, w.broken_words) == (1, 0, 3, 0)


def build_stream(ids, begin, t, names, window=1, block=tb.CHECK_BLOCK, drops_at=None) -> bytes:
    """What the board's sink emits for one window (TIME words at every 2^15 µs, CHECKs, DROPS)."""
    seq = [tb.control_payload(Op.WINDOW_START, window)]
    last_hi = None
    for i, (sid, b, tt) in enumerate(zip(ids, begin, t, strict=True)):
        if drops_at and i in drops_at:
            seq += tb.drops_payloads(drops_at[i]) + [tb.time_payload(int(tt))]
            last_hi = int(tt) >> 15
        if int(tt) >> 15 != last_hi:
            seq.append(tb.time_payload(int(tt)))
            last_hi = int(tt) >> 15
        seq.append(tb.stamp_payload(int(sid), bool(b), int(tt)))
    checker = tb.CheckInserter(block)
    out = list(checker.add(np.array(seq, np.uint32))) + checker.close()
    out.append(tb.control_payload(Op.WINDOW_STOP, window))
    return tb.name_table(names) + tb.encode_payloads(out)


def random_window(seed: int, n: int, max_step: int = 40):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, max_step, n))
    ids = rng.integers(0, 10, n)
    begin = rng.integers(0, 2, n).astype(bool)
    names = {i: f"task{i}" for i in range(10)}
    names[9] = "Tmr Svc"
    return ids, begin, t, names


@pytest.mark.parametrize("chunk,n", [(None, 20_000), (4096, 20_000), (1, 1500), (3, 1500)])
def test_round_trip_any_chunking(chunk, n):
    ids, begin, t, names = random_window(1, n, max_step=80 if n > 2000 else 900)
    data = b"00:00:01 [INFO]: boot\n" + build_stream(ids, begin, t, names) + b"00:00:02 [INFO]: done\n"
    dec = StreamDecoder()
    step = chunk or len(data)
    items = []
    for i in range(0, len(data), step):
        items += dec.feed_batch(data[i : i + step])
    items += dec.flush()
    stamps = stamps_of(items)
    assert [s.t_us for s in stamps] == t.tolist()  # unwrapped over many 131 ms wraps
    assert t[-1] > 5 * tb.TIME_WRAP
    assert [s.name for s in stamps] == [names[i] for i in ids.tolist()]
    assert [s.begin for s in stamps] == begin.tolist()
    w = dec.words
    n_words = 1 + len(t) + len(np.unique(t >> 15))  # WINDOW_START, stamps, TIME words
    assert w.checks_failed == 0 and w.checks_ok == -(-n_words // 64)
    assert (w.broken_words, w.unsynced_stamps, w.unnamed_stamps, dec.text.parse_errors) == (0, 0, 0, 0)
    assert [i for i in items if type(i) is LogMessage] == [LogMessage("00:00:01", "INFO", "boot"),
                                                         LogMessage("00:00:02", "INFO", "done")]


def test_late_stamps_unwrap_and_long_gaps_are_anchored():
    # Stamps up to 30 ms late across a wrap, then a 10 s gap (a stalled sink) announced by DROPS and TIME.
    t = np.array([131_000, 131_050, 131_100 - 30_000, 131_200, 200_000, 10_200_000, 10_200_010])
    ids, begin = np.zeros(len(t), int), np.ones(len(t), bool)
    data = build_stream(ids, begin, t, {0: "IDLE"}, drops_at={5: 70_000})
    items = decode_all(data)
    assert [s.t_us for s in stamps_of(items)] == t.tolist()
    assert Marker("drops", 8191, 200_000) in items
    assert sum(m.value for m in items if type(m) is Marker and m.kind == "drops") == 70_000


def test_one_lost_byte_costs_one_word():
    ids, begin, t, names = random_window(2, 2000)
    data = bytearray(build_stream(ids, begin, t, names))
    first_word = data.index(b"\xff")
    del data[first_word + 4 * 500 + 2]  # a continuation byte of word 500
    dec = StreamDecoder()
    stamps = stamps_of(dec.feed(bytes(data)) + dec.flush())
    assert len(stamps) == len(t) - 1
    assert dec.words.broken_words == 1 and dec.words.checks_failed == 1
    expected = [(names[i], tt) for i, tt in zip(ids.tolist(), t.tolist(), strict=True)]
    got = [(s.name, s.t_us) for s in stamps]
    assert len(set(expected) - set(got)) <= 1 and got[-100:] == expected[-100:]


def test_a_flipped_bit_fails_its_block_check():
    ids, begin, t, names = random_window(3, 1000)
    data = bytearray(build_stream(ids, begin, t, names))
    first_word = data.index(b"\xff")
    data[first_word + 4 * 300 + 3] ^= 0x04  # payload bit inside word 300, tags intact
    dec = StreamDecoder()
    dec.feed(bytes(data))
    assert dec.words.checks_failed == 1 and dec.words.broken_words == 0


def test_text_bytes_inside_a_word_do_not_break_it():
    ids, begin, t, names = random_window(4, 100)
    data = build_stream(ids, begin, t, names)
    first_word = data.index(b"\xff")
    mixed = data[: first_word + 41] + b"12:00:00 [INFO]: interleaved\n" + data[first_word + 41 :]
    items = decode_all(mixed)
    assert [s.t_us for s in stamps_of(items)] == t.tolist()
    assert LogMessage("12:00:00", "INFO", "interleaved") in items


def test_unnamed_and_unsynced_stamps_are_counted():
    words = tb.encode_payloads([tb.stamp_payload(5, True, 100), tb.time_payload(0), tb.stamp_payload(5, False, 140)])
    dec = WordDecoder()
    stamps = dec.feed(words)
    assert stamps == [Stamp("#5", 100, True), Stamp("#5", 140, False)]
    assert dec.unsynced_stamps == 1 and dec.unnamed_stamps == 2 and dec.synced


def test_reserved_ids_and_unknown_ops_are_reported():
    words = tb.encode_payloads([60 << 18, tb.control_payload(17, 1), tb.control_payload(Op.CHECK, 0)])
    dec = WordDecoder()
    kinds = [i.kind for i in dec.feed(words)]
    assert kinds == ["reserved_id", "unknown_op"]
    assert dec.checks_ok + dec.checks_failed == 0  # a block whose start was never seen is not judged


def test_drops_payloads_and_limits():
    assert [p & tb.ARG_MASK for p in tb.drops_payloads(20_000)] == [8191, 8191, 3618]
    with pytest.raises(ValueError):
        tb.stamp_payload(60, True, 0)
    with pytest.raises(ValueError):
        tb.name_table({1: "bad\tname"})


def test_check_inserter_is_chunking_invariant():
    p = np.arange(1000, dtype=np.uint32) * 7919 % (1 << 24)
    whole = tb.CheckInserter().add(p)
    c = tb.CheckInserter()
    parts = np.concatenate([c.add(p[i : i + 37]) for i in range(0, len(p), 37)])
    assert np.array_equal(whole, parts) and len(whole) == 1000 + 1000 // 64


def test_report_and_binary_share_the_port():
    ids, begin, t, names = random_window(5, 500)
    report = (b"=====\nfree heap:\t\t100\nctx switches:\t\t1000\nTask\t\tTime\t\t%%\nIDLE           \t50\t\t100%\r\n"
              b"-----\nTask\t\tState\tPrio\tStack\tNum\nIDLE           \tR\t0\t108\t8\r\n=====\noutput took 5 us\n")
    items = decode_all(build_stream(ids, begin, t, names) + report)
    (rep,) = [i for i in items if type(i) is RuntimeReport]
    assert rep.complete and rep.ctx_switches == 1000 and len(stamps_of(items)) == 500


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300), st.integers(1, 40))
def test_random_bytes_never_raise(data, chunk):
    dec = StreamDecoder()
    for i in range(0, len(data), chunk):
        dec.feed_batch(data[i : i + chunk])
    dec.flush()
    assert dec.words.words * 4 <= len(data)


def test_decode_speed_is_vectorised():
    """Not a benchmark: a guard that a chunk is decoded without per-word Python (10^5 words well under 1 s)."""
    ids, begin, t, names = random_window(6, 100_000)
    data = build_stream(ids, begin, t, names)
    dec = StreamDecoder()
    batches = [dec.feed_batch(data[i : i + 65536]) for i in range(0, len(data), 65536)]
    assert sum(b.count for part in batches for b in part if type(b) is StampBatch) == 100_000


def test_decode_words_decodes_a_stream():
    ids, begin, t, names = random_window(7, 200)
    data = build_stream(ids, begin, t, names)
    stamps = decode_words(data)
    assert len(stamps) == 200 and stamps == stamps_of(decode_all(data))
