"""One decoder for everything the rover board sends on its UART: text and binary stamps mixed.

Bytes below 0x80 are the board's ASCII text (stamp lines, logs, reports, the
binary format's ``@`` name table); bytes from 0x80 up are binary stamp words
(:mod:`hilbench.protocols.tracestamp_binary`). :class:`StreamDecoder` splits a
chunk into runs of each, hands them to a :class:`~hilbench.protocols.tracestamp.TextDecoder`
and a :class:`~hilbench.protocols.tracestamp_binary.WordDecoder` in arrival
order, and feeds name-table lines to the word decoder as they pass, so words
are named by the table sent before them. Both decoders keep their own partial
input, so a word interrupted by a stray text byte, or a line interrupted by
a word, still decodes.

Stamps from text and binary share one name list (``names``), so the ids of
every :class:`StampBatch` index the same table.

One-shot helpers for a complete capture: :func:`decode_all` (every item) and
:func:`decode_words` (its stamps only); :func:`stamps_of` picks the stamps
out of decoded items.
"""

from __future__ import annotations

import numpy as np

from hilbench.protocols.tracestamp import (
    Item,
    NameEntry,
    NameRegistry,
    Stamp,
    StampBatch,
    TableStart,
    TextDecoder,
)
from hilbench.protocols.tracestamp_binary import Marker, WordDecoder, WordProblem

StreamItem = Item | Marker | WordProblem


class StreamDecoder:
    """Incremental decoder of a mixed text/binary board stream; never raises.

    ``feed(data)`` returns :class:`Stamp`, :class:`LogLine`, :class:`RuntimeReport`,
    :class:`NameEntry`, :class:`TableStart`, :class:`BadLine`, :class:`Marker` and
    :class:`WordProblem` items in arrival order; ``feed_batch(data)`` the same with
    runs of stamps as :class:`StampBatch` columns. ``text`` and ``words`` are the
    two decoders, with their counters.
    """

    def __init__(self) -> None:
        self.registry = NameRegistry()
        self.text = TextDecoder(self.registry)
        self.words = WordDecoder(self.registry)
        self.bytes_in = 0

    @property
    def names(self) -> list[str]:
        return self.text.names

    def feed(self, data: bytes) -> list[StreamItem]:
        out: list = []
        for item in self.feed_batch(data):
            if type(item) is StampBatch:
                out.extend(item.stamps())
            else:
                out.append(item)
        return out

    def feed_batch(self, data: bytes) -> list:
        self.bytes_in += len(data)
        if not data:
            return []
        a = np.frombuffer(data, dtype=np.uint8)
        hi = a >= 0x80
        nhi = int(np.count_nonzero(hi))
        if nhi == 0:
            return self._text(bytes(data))
        if nhi == len(a):
            return self.words.feed_batch(a)
        out: list = []
        change = np.flatnonzero(hi[1:] != hi[:-1]) + 1
        bounds = [0, *change.tolist(), len(a)]
        for s, e in zip(bounds[:-1], bounds[1:], strict=True):
            if hi[s]:
                out.extend(self.words.feed_batch(a[s:e]))
            else:
                out.extend(self._text(bytes(data[s:e])))
        return out

    def flush(self) -> list[StreamItem]:
        out = self.text.flush()
        for item in out:
            self._apply_meta(item)
        return out + self.words.flush()

    def _text(self, data: bytes) -> list:
        items = self.text.feed_batch(data)
        for item in items:
            self._apply_meta(item)
        return items

    def _apply_meta(self, item) -> None:
        t = type(item)
        if t is TableStart:
            self.words.reset_names()
        elif t is NameEntry:
            self.words.set_name(item.id, item.name)


def decode_all(data: bytes) -> list[StreamItem]:
    """Every item of a complete capture, stamps as :class:`Stamp` (a convenience for scripts and tests)."""
    dec = StreamDecoder()
    return dec.feed(data) + dec.flush()


def decode_words(data: bytes) -> list[Stamp]:
    """All stamps of a self-contained binary stream with its names (one-shot helper for tests and scripts)."""
    dec = StreamDecoder()
    items = dec.feed(data) + dec.flush()
    return [i for i in items if type(i) is Stamp]


def stamps_of(items) -> list[Stamp]:
    """The stamps among items (batches expanded)."""
    out: list[Stamp] = []
    for item in items:
        if type(item) is StampBatch:
            out.extend(item.stamps())
        elif type(item) is Stamp:
            out.append(item)
    return out
