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
from hilbench.protocols.tracestamp_binary import Marker, WordDecoder

StreamItem = Item | Marker


class StreamDecoder:
    """Incremental decoder of a mixed text/binary board stream; never raises.

    ``feed(data)`` returns :class:`Stamp`, :class:`~hilbench.protocols.tracestamp.LogMessage`,
    :class:`~hilbench.protocols.tracestamp.RuntimeReport`, :class:`NameEntry`, :class:`TableStart`,
    :class:`Marker` and :class:`~hilbench.protocols.problem.Problem` items (unreadable lines, damaged
    words) in arrival order; ``feed_batch(data)`` the same with runs of stamps
    as :class:`StampBatch` columns. ``text`` and ``words`` are the
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
        return self._mixed(a, hi)

    def _mixed(self, a: np.ndarray, hi: np.ndarray) -> list:
        """A chunk of both: its text lines are the segments items are ordered by.

        A text item is complete at its line's LF, so the words of each line's segment (from the byte
        after the previous LF to this LF) come before the line's items: what a byte-by-byte decoder
        would give. The text decoder reads each segment's text; the word decoder reads the words of
        many segments in one pass (:meth:`WordDecoder.feed_segments`), cut only after a name-table
        line, whose names hold for the words after it. Linear time: a chunk of noise (a line every
        few hundred bytes) costs one numpy pass, not one per run of text or words.
        """
        n = len(a)
        lf = a == 10
        ends = np.flatnonzero(lf) + 1  # each segment ends with its LF
        if not len(ends) or ends[-1] != n:
            ends = np.append(ends, n)
        hi_cum = np.concatenate(([0], np.cumsum(hi)))  # word bytes before each offset
        # Lines keep their order among themselves: only a segment in which a word completes needs a cut
        # before it, so runs of text lines stay one group, also when stray bytes with bit 7 set (damage)
        # are sprinkled among them: those only count as damaged words.
        done = self._completions(a, hi)
        has_words = np.zeros(len(ends), dtype=bool)
        if len(done):
            has_words[np.searchsorted(ends, done, side="right")] = True
        ends = ends[np.append(has_words[1:], True)]
        bounds = np.concatenate(([0], ends))  # group k is bytes bounds[k]:bounds[k + 1]
        hi_at = hi_cum[bounds].tolist()  # word bytes before each bound
        # All the text in one call (the text decoder's vectorised path), its items sorted into the groups
        # by the line that completed them.
        items, lines = self.text.feed_lines(a[~hi].tobytes())
        line_at = np.concatenate(([0], np.cumsum(lf)))[bounds]  # lines completed before each bound
        texts = self._by_group(items, lines, line_at[1:-1])
        words = a[hi]
        out: list = []
        first = 0  # the first group whose words are not decoded yet
        last = len(texts) - 1
        for k, items in enumerate(texts):
            meta = False
            for i in items:
                if type(i) is TableStart or type(i) is NameEntry:
                    meta = True
                    break
            if not meta and k < last:
                continue  # no name-table line here: the words go on in the same pass
            base = hi_at[first]
            seg_starts = np.asarray(hi_at[first + 1 : k + 1], dtype=np.int64) - base
            word_items = self.words.feed_segments(words[base : hi_at[k + 1]], seg_starts) \
                if hi_at[k + 1] > base else [[] for _ in range(k + 1 - first)]
            for j in range(first, k + 1):
                out += word_items[j - first]
                out += texts[j]
            if meta:  # names for the words after this line
                for item in items:
                    self._apply_meta(item)
            first = k + 1
        return out

    def _by_group(self, items: list, lines: list, cuts: np.ndarray) -> list[list]:
        """Text items (with the line index that completed each, a batch's range of lines) into groups:
        group k holds lines up to ``cuts[k]``; a batch of stamps spanning groups is split; each group's
        stamps are merged."""
        groups: list[list] = [[] for _ in range(len(cuts) + 1)]
        if not len(cuts):
            groups[0] = self.text.merge(items)
            return groups
        first = [li if type(li) is int else li[0] for li in lines]
        last = [li if type(li) is int else li[1] - 1 for li in lines]
        g_first = np.searchsorted(cuts, first, side="right").tolist()  # one search for every item
        g_last = np.searchsorted(cuts, last, side="right").tolist()
        for item, li, g, h in zip(items, lines, g_first, g_last, strict=True):
            if g == h:
                groups[g].append(item)
                continue
            gs = np.searchsorted(cuts, np.arange(li[0], li[1]), side="right")  # a batch across groups
            split = (np.flatnonzero(gs[1:] != gs[:-1]) + 1).tolist()
            for lo, hi in zip([0, *split], [*split, len(gs)], strict=True):
                groups[int(gs[lo])].append(StampBatch(item.names, item.ids[lo:hi], item.t_us[lo:hi], item.begin[lo:hi]))
        return [self.text.merge(g) if g else g for g in groups]

    def _completions(self, a: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Offsets in ``a`` of the last byte of every whole word (as :meth:`WordDecoder.feed_batch` would
        decode them, the word decoder's unfinished word included)."""
        hidx = np.flatnonzero(hi)
        pending = self.words._pending
        stream = np.concatenate((pending, a[hidx])) if len(pending) else a[hidx]
        leads = np.flatnonzero(stream >= 0xC0)
        if not len(leads):
            return leads
        nxt = np.append(leads[1:], len(stream))
        whole = leads[(nxt - leads) >= 4] + 3 - len(pending)  # index of each word's 4th byte in a[hidx]
        return hidx[whole[whole >= 0]]

    def cut(self) -> int:
        """The stream was cut off by the reader (a time limit), not ended: drop the unfinished line, report
        and word rather than decode them as damage (:meth:`flush` still follows); returns the bytes dropped."""
        return self.text.cut() + self.words.cut()

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
