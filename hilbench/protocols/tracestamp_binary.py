"""Compact binary trace stamps: one tagged 32-bit word per stamp (hilbench's design for spec §3.9).

Full description with a worked example: ``docs/formats/tracestamp-binary.md``. In short:

* **Word**: 4 bytes, little-endian. Every byte has bit 7 set, so words never
  look like the board's 7-bit ASCII text (logs, reports) and both share one
  UART. The first byte is ``11pppppp``, the other three ``10pppppp``; they
  carry a 24-bit payload P, most significant 6 bits first. A lost or extra byte
  damages one word only: the next ``11`` byte starts the next word.
* **Payload** ``[23:18]`` id. ids 0..59 are stamps: ``[17]`` edge (1 = begin),
  ``[16:0]`` time in µs modulo 2^17 (131.072 ms). id 62 is TIME: ``[17:0]`` =
  (t >> 15) mod 2^18, sent at window start, before the first stamp of each new
  32.768 ms period and after every DROPS word, so a host can always unwrap. id 63 is a control word: ``[17:13]``
  op, ``[12:0]`` argument (ops in :class:`Op`). ids 60 and 61 are reserved.
* **Drops**: a stamp that finds the sink full is counted, not written. Once
  space returns, DROPS words (up to 8191 each) report exactly how many were lost.
* **Check**: after every 64 words a CHECK word carries the XOR of
  ``fold13(P) = (P ^ P >> 13) & 0x1FFF`` over them, so any single-bit error in
  a block is detected. The accumulator also restarts at each WINDOW_START.
* **Name table**: text lines ``@tsb 1`` (a new table follows) and
  ``@id <id> <name>``, sent before each window; they are decoded by the text
  decoder (:class:`~hilbench.protocols.tracestamp.NameEntry`).

:class:`WordDecoder` decodes the words of a byte stream with numpy, whole chunks
at a time (``feed_batch``), and never raises; :func:`encode_payloads` and the
``*_payload`` helpers build words for the emulated board.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp import NameRegistry, StampBatch

VERSION = 1
MAX_STAMP_ID = 59
ID_TIME = 62
ID_CONTROL = 63
TIME_BITS = 17
TIME_WRAP = 1 << TIME_BITS
TIME_MASK = TIME_WRAP - 1
#: TIME words carry t >> HI_SHIFT, and are sent whenever that value changes.
HI_SHIFT = 15
HI_BITS = 18
HI_WRAP = 1 << HI_BITS
TIME_INTERVAL_US = 1 << HI_SHIFT  # 32,768 µs: the period whose first stamp a TIME word precedes
ARG_BITS = 13
ARG_MASK = (1 << ARG_BITS) - 1
MAX_DROPS_PER_WORD = ARG_MASK
CHECK_BLOCK = 64  #: words between two CHECK words
WORD_SIZE = 4


class Op(IntEnum):
    """Control word operations (payload bits 17..13 of id 63)."""

    WINDOW_START = 1  # arg: window number mod 8192
    WINDOW_STOP = 2  # arg: window number mod 8192
    DROPS = 3  # arg: stamps lost since the previous DROPS word (1..8191)
    CHECK = 4  # arg: XOR of fold13 over the words since the previous CHECK or WINDOW_START


OP_NAMES = {Op.WINDOW_START: "window_start", Op.WINDOW_STOP: "window_stop", Op.DROPS: "drops"}


class Marker(NamedTuple):
    """A control word the host acts on: ``kind`` is ``window_start``, ``window_stop`` or ``drops``.

    ``value`` is the window number (mod 8192) or the count of lost stamps;
    ``t_us`` is the stream time at that point (the last time-bearing word's).
    """

    kind: str
    value: int
    t_us: int


# --------------------------------------------------------------------------- encoding


def stamp_payload(stamp_id: int, begin: bool, t_us: int) -> int:
    """Payload of a stamp word."""
    if not 0 <= stamp_id <= MAX_STAMP_ID:
        raise ValueError(f"stamp id must be 0..{MAX_STAMP_ID}, got {stamp_id}")
    return stamp_id << 18 | (1 << 17 if begin else 0) | (t_us & TIME_MASK)


def time_payload(t_us: int) -> int:
    """Payload of a TIME word for stream time ``t_us``."""
    return ID_TIME << 18 | ((t_us >> HI_SHIFT) & (HI_WRAP - 1))


def control_payload(op: int, arg: int) -> int:
    """Payload of a control word."""
    if not 0 <= arg <= ARG_MASK:
        raise ValueError(f"control argument must be 0..{ARG_MASK}, got {arg}")
    return ID_CONTROL << 18 | (op & 0x1F) << ARG_BITS | arg


def drops_payloads(count: int) -> list[int]:
    """DROPS words reporting ``count`` lost stamps (several when above 8191)."""
    out = []
    while count > 0:
        n = min(count, MAX_DROPS_PER_WORD)
        out.append(control_payload(Op.DROPS, n))
        count -= n
    return out


def stamp_payloads(ids: np.ndarray, begin: np.ndarray, t_us: np.ndarray) -> np.ndarray:
    """Stamp payloads for arrays of ids, edges and times (vectorised)."""
    return (np.asarray(ids, np.uint32) << 18) | (np.asarray(begin, np.uint32) << 17) | \
        (np.asarray(t_us, np.int64) & TIME_MASK).astype(np.uint32)


def encode_payloads(payloads: np.ndarray | list[int]) -> bytes:
    """The wire bytes of payloads: four tagged bytes each."""
    p = np.asarray(payloads, dtype=np.uint32)
    out = np.empty((len(p), 4), dtype=np.uint8)
    out[:, 0] = 0xC0 | ((p >> 18) & 0x3F)
    out[:, 1] = 0x80 | ((p >> 12) & 0x3F)
    out[:, 2] = 0x80 | ((p >> 6) & 0x3F)
    out[:, 3] = 0x80 | (p & 0x3F)
    return out.tobytes()


def word_bytes(payload: int) -> bytes:
    """The 4 wire bytes of one payload."""
    return bytes((0xC0 | (payload >> 18) & 0x3F, 0x80 | (payload >> 12) & 0x3F, 0x80 | (payload >> 6) & 0x3F,
                  0x80 | payload & 0x3F))


def fold13(payloads: np.ndarray | int) -> np.ndarray | int:
    """The 13-bit fold CHECK words XOR together: ``(P ^ P >> 13) & 0x1FFF``."""
    if isinstance(payloads, int):
        return (payloads ^ payloads >> ARG_BITS) & ARG_MASK
    p = np.asarray(payloads, dtype=np.uint32)
    return (p ^ (p >> ARG_BITS)) & ARG_MASK


def name_table(names: Mapping[int, str]) -> bytes:
    """The name table as text lines: ``@tsb 1`` then ``@id <id> <name>`` per entry."""
    lines = [b"@tsb %d\n" % VERSION]
    for i, name in sorted(names.items()):
        raw = name.encode("ascii")
        if not 0 <= i <= MAX_STAMP_ID or not raw or b"\n" in raw or b"\t" in raw:
            raise ValueError(f"bad name table entry {i}: {name!r}")
        lines.append(b"@id %d %s\n" % (i, raw))
    return b"".join(lines)


class CheckInserter:
    """Inserts a CHECK word after every :data:`CHECK_BLOCK` words (the transmitting side's state).

    ``add(payloads)`` returns the payloads with CHECK words in place; call
    :meth:`restart` where a WINDOW_START word is sent (it opens a new block),
    and :meth:`close` to emit a CHECK for a partial block (before WINDOW_STOP).
    """

    def __init__(self, block: int = CHECK_BLOCK) -> None:
        self.block = block
        self.count = 0
        self.acc = 0

    def restart(self) -> None:
        self.count = 0
        self.acc = 0

    def close(self) -> list[int]:
        """A CHECK word for the words since the last one (none if there were none)."""
        if self.count == 0:
            return []
        p = control_payload(Op.CHECK, self.acc)
        self.count = 0
        self.acc = 0
        return [p]

    def add_list(self, payloads: list[int]) -> list[int]:
        """:meth:`add` for a few payloads as Python ints (cheaper than numpy for short runs)."""
        out = []
        count, acc, block = self.count, self.acc, self.block
        check_base = ID_CONTROL << 18 | Op.CHECK << ARG_BITS
        for p in payloads:
            out.append(p)
            acc ^= (p ^ p >> ARG_BITS) & ARG_MASK
            count += 1
            if count == block:
                out.append(check_base | acc)
                count = acc = 0
        self.count, self.acc = count, acc
        return out

    def add(self, payloads: np.ndarray) -> np.ndarray:
        p = np.asarray(payloads, dtype=np.uint32)
        n = len(p)
        if n == 0:
            return p
        room = self.block - self.count
        if n < room:
            self.count += n
            self.acc ^= int(np.bitwise_xor.reduce(fold13(p)))
            return p
        f = fold13(p)
        cuts = np.arange(room, n + 1, self.block)  # a CHECK goes after index cut-1
        starts = np.concatenate(([0], cuts[:-1]))
        xors = np.bitwise_xor.reduceat(f[: cuts[-1]], starts).astype(np.uint32)
        xors[0] ^= self.acc
        checks = (np.uint32(ID_CONTROL << 18 | Op.CHECK << ARG_BITS) | xors).astype(np.uint32)
        out = np.insert(p, cuts, checks)
        tail = p[cuts[-1]:]
        self.count = len(tail)
        self.acc = int(np.bitwise_xor.reduce(fold13(tail))) if len(tail) else 0
        return out


# --------------------------------------------------------------------------- decoding


def split_words(data: bytes | np.ndarray) -> tuple[np.ndarray, int, int]:
    """Extract payloads from tagged bytes (bytes below 0x80 are ignored).

    Returns ``(payloads, broken, consumed)``: the uint32 payloads of complete
    words in order, how many damaged words were skipped (a word that lost
    bytes, or continuation bytes without their first byte), and how many of
    the tagged bytes were used (the rest start an unfinished word).
    """
    a = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    p, broken, consumed, _ = _split(a[a >= 0x80])
    return p, broken, consumed


def _split(a: np.ndarray) -> tuple[np.ndarray, int, int, np.ndarray]:
    """:func:`split_words` of tagged bytes only, with the index of each good word's first byte."""
    n = len(a)
    leads = np.flatnonzero(a >= 0xC0)
    if len(leads) == 0:
        return np.zeros(0, np.uint32), int(n > 0), n, leads
    nxt = np.empty(len(leads), dtype=np.int64)
    nxt[:-1] = leads[1:]
    nxt[-1] = n
    span = nxt - leads
    complete = np.ones(len(leads), dtype=bool)
    if span[-1] < WORD_SIZE:  # the last word is unfinished: keep it for the next chunk
        complete[-1] = False
        consumed = int(leads[-1])
    else:
        consumed = n
    good = complete & (span >= WORD_SIZE)
    gi = leads[good]
    p = ((a[gi].astype(np.uint32) & 0x3F) << 18 | (a[gi + 1].astype(np.uint32) & 0x3F) << 12
         | (a[gi + 2].astype(np.uint32) & 0x3F) << 6 | (a[gi + 3].astype(np.uint32) & 0x3F))
    short = int((complete & (span < WORD_SIZE)).sum())  # words that lost bytes
    extra = int((complete & (span > WORD_SIZE)).sum())  # continuation bytes after a good word
    stray_head = int(leads[0] > 0)  # continuation bytes before the first lead
    return p.astype(np.uint32), short + extra + stray_head, consumed, gi


class WordDecoder:
    """Incremental decoder of binary stamp words; never raises.

    Feed it raw port bytes (text bytes are ignored) or only the tagged bytes.
    Set names with :meth:`set_name` / :meth:`reset_names` (the stream decoder
    does this from ``@tsb``/``@id`` lines); stamp ids index ``names``, a
    :class:`~hilbench.protocols.tracestamp.NameRegistry` that may be shared. Counters: ``words``, ``stamps``,
    ``time_words``, ``controls``, ``broken_words``, ``checks_ok``,
    ``checks_failed``, ``drops`` (sum of DROPS words: stamps the board lost),
    ``windows_started``, ``windows_stopped``, ``unsynced_stamps`` (before the
    first TIME word), ``unnamed_stamps``, ``reserved_words``, ``unknown_ops``.

    Damage comes out as :class:`~hilbench.protocols.problem.Problem` items: ``kind`` ``broken_word`` (bytes
    lost or added), ``reserved_id`` or ``unknown_op``, ``count`` the words it covers, ``t_us`` the trace time
    at the damage (None before the first TIME word). A CHECK word that disagrees with its block is counted
    (``checks_failed``), not reported as an item.
    """

    def __init__(self, registry: NameRegistry | None = None) -> None:
        self._pending = np.zeros(0, np.uint8)
        self.registry = registry or NameRegistry()
        self._lut = np.full(64, -1, dtype=np.int32)  # wire id -> index in names
        self._t: int | None = None  # last full time (µs)
        self._acc = 0  # XOR accumulator of the current check block
        self._acc_valid = False  # False until a block start has been seen
        self._synced = False
        self.words = 0
        self.stamps = 0
        self.time_words = 0
        self.controls = 0
        self.broken_words = 0
        self.checks_ok = 0
        self.checks_failed = 0
        self.drops = 0
        self.windows_started = 0
        self.windows_stopped = 0
        self.unsynced_stamps = 0
        self.unnamed_stamps = 0
        self.reserved_words = 0
        self.unknown_ops = 0

    # ------------------------------------------------------------------ names

    def reset_names(self) -> None:
        """Forget the id -> name table (a new ``@tsb`` table follows)."""
        self._lut[:] = -1

    def set_name(self, stamp_id: int, name: str) -> None:
        if 0 <= stamp_id < 64:
            self._lut[stamp_id] = self._index(name)

    def _index(self, name: str) -> int:
        return self.registry.id_of_str(name)

    @property
    def names(self) -> list[str]:
        return self.registry.names

    @property
    def synced(self) -> bool:
        """True once a TIME word has fixed the absolute time."""
        return self._synced

    # ------------------------------------------------------------------ feeding

    def feed(self, data: bytes) -> list:
        """Decode and return items with stamps as :class:`~hilbench.protocols.tracestamp.Stamp` tuples."""
        out = []
        for item in self.feed_batch(data):
            if type(item) is StampBatch:
                out.extend(item.stamps())
            else:
                out.append(item)
        return out

    def feed_batch(self, data: bytes | np.ndarray) -> list:
        """Decode and return ``StampBatch``, ``Marker`` and ``Problem`` items in stream order."""
        a = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
        a = a[a >= 0x80]
        if len(self._pending):
            a = np.concatenate((self._pending, a))
        payloads, broken, consumed = split_words(a)
        self._pending = a[consumed:].copy()
        out: list = []
        if broken:
            self.broken_words += broken
        if len(payloads) == 0:
            if broken:
                out.append(Problem("broken_word", count=broken, t_us=self._t))
            return out
        self._decode(payloads, out, broken)
        return out

    def feed_segments(self, tagged: np.ndarray, starts: np.ndarray) -> list[list]:
        """:meth:`feed_batch` of tagged bytes (all >= 0x80) that belong to consecutive segments of the
        stream, the first byte of segment ``k + 1`` at ``tagged[starts[k]]``; returns each segment's items.

        The stream decoder puts each segment's items before the text line that ends it, with one call
        for many segments (one numpy pass instead of one per line). Damaged words are reported in the
        first segment of the call.
        """
        nseg = len(starts) + 1
        outs: list[list] = [[] for _ in range(nseg)]
        a = tagged
        if len(self._pending):
            a = np.concatenate((self._pending, a))
            starts = starts + len(self._pending)
        payloads, broken, consumed, leads = _split(a)
        self._pending = a[consumed:].copy()
        if broken:
            self.broken_words += broken
        if len(payloads) == 0:
            if broken:
                outs[0].append(Problem("broken_word", count=broken, t_us=self._t))
            return outs
        seg = np.searchsorted(starts, leads + (WORD_SIZE - 1), side="right")  # where each word completes
        self._decode(payloads, outs, broken, seg)
        return outs

    def cut(self) -> int:
        """The input was cut off (see :meth:`TextDecoder.cut <hilbench.protocols.tracestamp.TextDecoder.cut>`): drop an unfinished word; returns its bytes."""
        n = len(self._pending)
        self._pending = np.zeros(0, np.uint8)
        return n

    def flush(self) -> list:
        """End of input: an unfinished word is a broken one."""
        if len(self._pending):
            self._pending = np.zeros(0, np.uint8)
            self.broken_words += 1
            return [Problem("broken_word", count=1, t_us=self._t)]
        return []

    # ------------------------------------------------------------------ internals

    def _decode(self, p: np.ndarray, out: list, broken: int, seg: np.ndarray | None = None) -> None:
        """Decode payloads into ``out`` (with ``seg``: into ``out[seg[i]]``, a list per segment)."""
        n = len(p)
        self.words += n
        ids = (p >> 18).astype(np.int64)
        is_ctrl = ids == ID_CONTROL
        op = np.where(is_ctrl, (p >> ARG_BITS) & 0x1F, 0)
        is_check = op == Op.CHECK
        is_start = op == Op.WINDOW_START
        self._verify_checks(p, is_check, is_start)
        # Time: stamps (ids <= 59) and TIME words (62) bear time.
        is_stamp = ids <= MAX_STAMP_ID
        is_time = ids == ID_TIME
        bearing = is_stamp | is_time
        t_full = self._unwrap(p, is_stamp, is_time, bearing)  # per word: time at or before it
        # Split at the words that need Python: markers, reserved ids, unknown ops.
        special = (is_ctrl & ~is_check) | ((ids > MAX_STAMP_ID) & (ids < ID_TIME))
        nst = int(is_stamp.sum())
        self.stamps += nst
        self.time_words += int(is_time.sum())
        self.controls += int(is_ctrl.sum())
        first = out if seg is None else out[int(seg[0])]
        if broken:
            first.append(Problem("broken_word", count=broken, t_us=int(t_full[0]) if self._t is not None else None))
        sp = np.flatnonzero(special)
        if seg is None:
            prev = 0
            for i in [*sp.tolist(), n]:
                if i > prev:
                    self._emit_stamps(p[prev:i], ids[prev:i], is_stamp[prev:i], t_full[prev:i], out)
                if i == n:
                    break
                self._special(int(p[i]), int(ids[i]), int(t_full[i]), out)
                prev = i + 1
            return
        # Split at special words and where a segment begins; each piece goes to its segment's list. The
        # stamp columns are made once for the call and sliced per piece (many pieces: one per line of noise).
        cuts = np.union1d(sp, np.flatnonzero(seg[1:] != seg[:-1]) + 1).tolist()
        segs = seg.tolist()
        spos = np.flatnonzero(is_stamp)
        if len(spos):
            idx = self._name_indices(ids[spos])
            cols = (idx.astype(np.int32), t_full[spos].astype(np.int64), ((p[spos] >> 17) & 1).astype(bool))
            names = self.registry.snapshot()
        bounds = np.searchsorted(spos, [*cuts, n]).tolist()  # stamps before each cut
        prev, sprev = 0, 0
        for i, s in zip([*cuts, n], bounds, strict=True):
            if s > sprev:
                out[segs[prev]].append(StampBatch(names, cols[0][sprev:s], cols[1][sprev:s], cols[2][sprev:s]))
            if i == n:
                break
            if special[i]:
                self._special(int(p[i]), int(ids[i]), int(t_full[i]), out[segs[i]])
                prev, sprev = i + 1, s
            else:
                prev, sprev = i, s

    def _emit_stamps(self, p, ids, is_stamp, t_full, out) -> None:
        if not is_stamp.any():
            return
        sel = is_stamp if not is_stamp.all() else slice(None)
        idx = self._name_indices(ids[sel])
        begin = ((p[sel] >> 17) & 1).astype(bool)
        out.append(StampBatch(self.registry.snapshot(), idx.astype(np.int32), t_full[sel].astype(np.int64), begin))

    def _name_indices(self, sid: np.ndarray) -> np.ndarray:
        """The name index of each stamp id; ids no NAME word declared get a name ``#<id>`` (counted)."""
        idx = self._lut[sid]
        missing = idx < 0
        if missing.any():
            for wid in np.unique(sid[missing]).tolist():
                self._lut[wid] = self._index(f"#{wid}")
            self.unnamed_stamps += int(missing.sum())
            idx = self._lut[sid]
        return idx

    def _special(self, payload: int, wid: int, t: int, out: list) -> None:
        if wid != ID_CONTROL:
            self.reserved_words += 1
            out.append(Problem("reserved_id", count=1, t_us=t))
            return
        op = (payload >> ARG_BITS) & 0x1F
        arg = payload & ARG_MASK
        if op == Op.DROPS:
            self.drops += arg
            out.append(Marker("drops", arg, t))
        elif op == Op.WINDOW_START:
            self.windows_started += 1
            out.append(Marker("window_start", arg, t))
        elif op == Op.WINDOW_STOP:
            self.windows_stopped += 1
            out.append(Marker("window_stop", arg, t))
        else:
            self.unknown_ops += 1
            out.append(Problem("unknown_op", count=1, t_us=t))

    def _verify_checks(self, p: np.ndarray, is_check: np.ndarray, is_start: np.ndarray) -> None:
        f = fold13(p).astype(np.uint32)
        f[is_check] = 0
        ye = np.zeros(len(p) + 1, dtype=np.uint32)  # ye[i] = XOR of f[0..i-1]
        np.bitwise_xor.accumulate(f, out=ye[1:])
        starts = np.zeros(len(p) + 1, dtype=bool)  # block starts: after each CHECK, at each WINDOW_START
        starts[1:] = is_check
        starts[:-1] |= is_start
        resets = np.flatnonzero(starts)
        checks = np.flatnonzero(is_check)
        if len(checks):
            pos = np.searchsorted(resets, checks, side="right") - 1  # the last block start <= each check
            inside = pos >= 0
            b = resets[np.maximum(pos, 0)]
            expect = np.where(inside, ye[checks] ^ ye[b], ye[checks] ^ np.uint32(self._acc))
            ok = expect == (p[checks] & ARG_MASK)
            judged = inside | self._acc_valid  # a block whose start we never saw cannot be judged
            self.checks_ok += int((ok & judged).sum())
            self.checks_failed += int((~ok & judged).sum())
        if len(resets):
            last = int(resets[-1])
            self._acc = int(ye[-1] ^ ye[last])
            self._acc_valid = True
        else:
            self._acc ^= int(ye[-1])

    def _unwrap(self, p, is_stamp, is_time, bearing) -> np.ndarray:
        """Full µs time of every word (non-bearing words get the time of the last bearing word)."""
        n = len(p)
        bi = np.flatnonzero(bearing)
        t_word = np.empty(n, dtype=np.int64)
        if len(bi) == 0:
            t_word[:] = self._t if self._t is not None else 0
            return t_word
        pb = p[bi].astype(np.int64)
        tb_is_time = is_time[bi]
        hi = pb & (HI_WRAP - 1)
        low = np.where(tb_is_time, (hi << HI_SHIFT) & TIME_MASK, pb & TIME_MASK)
        t0 = self._t
        before = t0 if t0 is not None else 0  # the time of words before the first time-bearing one
        unsynced = t0 is None
        if unsynced:
            t0 = int(low[0])  # epoch 0 until a TIME word says otherwise
        prev = np.empty(len(low), dtype=np.int64)
        prev[0] = t0 & TIME_MASK
        prev[1:] = low[:-1]
        d = (low - prev) & TIME_MASK
        d = np.where(d >= TIME_WRAP // 2, d - TIME_WRAP, d)
        rel = t0 + np.cumsum(d)
        # Anchor at TIME words: their high part fixes the epoch after long gaps.
        anchors = np.flatnonzero(tb_is_time)
        if len(anchors):
            # Each anchor shifts everything after it: record the steps, sum them once (linear time).
            steps = np.zeros(len(low), dtype=np.int64)
            shift = 0
            rel_at = rel[anchors].tolist()
            for j, r, h in zip(anchors.tolist(), rel_at, hi[anchors].tolist(), strict=True):
                est = r + shift
                h_est = est >> HI_SHIFT
                dh = (h - h_est) % HI_WRAP
                if dh >= HI_WRAP // 2:
                    dh -= HI_WRAP
                step = ((h_est + dh) << HI_SHIFT) - est
                shift += step
                steps[j] = step
            rel = rel + np.cumsum(steps)
            if unsynced:
                first = int(anchors[0])
                self.unsynced_stamps += int(is_stamp[bi[:first]].sum())
            self._synced = True
        elif unsynced:
            self.unsynced_stamps += int(is_stamp[bi].sum())
        self._t = int(rel[-1])
        # Spread to all words: each word gets the time of the last bearing word at or before it.
        k = np.cumsum(bearing) - 1  # the last bearing word at or before each word (linear, no search)
        t_word = np.where(k >= 0, rel[np.maximum(k, 0)], before)
        return t_word

