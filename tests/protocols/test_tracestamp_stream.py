"""The mixed text/binary decoder: the same items in the same order as a decoder that alternates between
the two at every change of byte class, in linear time on noise."""

from __future__ import annotations

import random
import time

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp import NameEntry, NameRegistry, StampBatch, TableStart, TextDecoder
from hilbench.protocols.tracestamp_binary import WordDecoder
from hilbench.protocols.tracestamp_stream import StreamDecoder
from hilbench.protocols.tracestamp_targets import binary_traffic, stream_traffic, text_traffic


class RunDecoder:
    """The reference: one call per run of text or of words, in arrival order (the earlier design)."""

    def __init__(self) -> None:
        self.registry = NameRegistry()
        self.text = TextDecoder(self.registry)
        self.words = WordDecoder(self.registry)

    def feed(self, data: bytes) -> list:
        a = np.frombuffer(data, dtype=np.uint8)
        if not len(a):
            return []
        hi = a >= 0x80
        out: list = []
        change = np.flatnonzero(hi[1:] != hi[:-1]) + 1
        bounds = [0, *change.tolist(), len(a)]
        for s, e in zip(bounds[:-1], bounds[1:], strict=True):
            if hi[s]:
                out.extend(self.words.feed_batch(a[s:e]))
            else:
                items = self.text.feed_batch(bytes(data[s:e]))
                for item in items:
                    if type(item) is TableStart:
                        self.words.reset_names()
                    elif type(item) is NameEntry:
                        self.words.set_name(item.id, item.name)
                out.extend(items)
        return out

    def flush(self) -> list:
        return self.text.flush() + self.words.flush()


def normal(items: list) -> tuple[list, int]:
    """Items with batches expanded to stamps; damaged-word counts summed apart (reported per call)."""
    out, broken = [], 0
    for item in items:
        if type(item) is StampBatch:
            out.extend(item.stamps())
        elif type(item) is Problem and item.kind == "broken_word":
            broken += item.count
        else:
            out.append(item)
    return out, broken


def decode(dec, data: bytes, cuts: list[int]) -> tuple[list, int]:
    items, pos = [], 0
    for c in [*sorted(set(cuts)), len(data)]:
        items += dec.feed(data[pos:c]) if isinstance(dec, RunDecoder) else dec.feed_batch(data[pos:c])
        pos = c
    items += dec.flush()
    return normal(items)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32), cuts=st.lists(st.integers(0, 6000), max_size=8))
def test_the_same_items_as_the_run_by_run_decoder(seed, cuts):
    rng = random.Random(seed)
    pieces = []
    for _ in range(rng.randrange(1, 6)):
        kind = rng.random()
        size = rng.randrange(1, 2000)
        if kind < 0.3:
            pieces.append(stream_traffic(rng, size))
        elif kind < 0.5:
            pieces.append(binary_traffic(rng, size))
        elif kind < 0.7:
            pieces.append(text_traffic(rng, size))
        else:
            pieces.append(rng.randbytes(size))
    data = bytearray(b"".join(pieces))
    for _ in range(rng.randrange(0, 20)):
        data[rng.randrange(len(data))] = rng.randrange(256)
    data = bytes(data)
    (items, broken), (ref_items, ref_broken) = decode(StreamDecoder(), data, cuts), decode(RunDecoder(), data, cuts)
    assert items == ref_items
    # Stray continuation bytes between text bytes: the reference counts one damaged word per run of them,
    # this decoder per line; both see damage exactly where there is some.
    assert (broken > 0) == (ref_broken > 0)


def test_names_given_between_words_name_the_words_after_them():
    first = tb.name_table({0: "alpha"}) + tb.encode_payloads([tb.time_payload(0), tb.stamp_payload(0, True, 5)])
    second = tb.name_table({0: "beta"}) + tb.encode_payloads([tb.stamp_payload(0, False, 9)])
    items, _ = decode(StreamDecoder(), first + b"noise line\n" + second, [])
    stamps = [i for i in items if type(i).__name__ == "Stamp"]
    assert [(s.name, s.t_us, s.begin) for s in stamps] == [("alpha", 5, True), ("beta", 9, False)]


def test_noise_costs_linear_time():
    rng = random.Random(7)
    small, big = rng.randbytes(100_000), rng.randbytes(800_000)

    def cost(data: bytes) -> float:
        # This thread's CPU time (process_time would add any other thread still running in the test
        # process), best of three so that one garbage collection or preemption does not decide it.
        best = float("inf")
        for _ in range(3):
            dec = StreamDecoder()
            t0 = time.thread_time()
            for i in range(0, len(data), 65536):
                dec.feed_batch(data[i : i + 65536])
            dec.flush()
            best = min(best, time.thread_time() - t0)
        return best

    small_cost, big_cost = cost(small), cost(big)
    # eight times the bytes, well under sixty-four times the time (the run-by-run design was quadratic
    # in runs per chunk and took ~8 s per MB; this one measures ~7.5x); generous for a busy machine
    assert big_cost < 20 * max(small_cost, 1e-3)
    assert big_cost < 4.0
