"""Parsing bus captures: bytes of a hilbench capture or a raw dump in, chunks out, damage counted.

:class:`CaptureParser` is a push parser: it is fed whatever bytes arrive (a
file's reads, a pipe, the bench's TCP tap) and returns the
:class:`~hilbench.transports.chunk.Chunk` s they complete. It decides on the
first bytes whether the input is a hilbench capture (the format of
:mod:`hilbench.protocols.capture`) or a raw headerless dump (one source named
``bus``, stamped with byte time when a baud rate is given), and finds, counts
and survives damage (see the class). :mod:`~hilbench.transports.capture_file`
reads files and writes captures with it.
"""

from __future__ import annotations

import bisect

from hilbench.protocols import capture as cap
from hilbench.protocols.capture import MAX_PAYLOAD, RECORD_HEADER_SIZE, CaptureInfo, Flags, RecordKind
from hilbench.transports.chunk import CaptureError, Chunk

#: Read size for files; also the chunk size of raw dumps without a baud rate.
READ_SIZE = 65536
#: Chunk size of raw dumps read with a baud rate: the resolution of their byte time.
RAW_TIMED_CHUNK = 64
#: Source name of a raw dump's bytes.
RAW_SOURCE = "bus"


#: Times may step back this much between records without a finding (a tap's two directions are
#: stamped by two threads).
TIME_TOLERANCE = 1e-3
#: A step between consecutive records larger than this (either way) is damage, not a pause: that
#: record's time is repaired instead of moving the whole timeline.
MAX_TIME_STEP = 86_400.0
#: Findings kept as text (their counts are exact).
MAX_FINDINGS = 20
#: A version field above this is damage, not a newer format (which is refused in one line).
MAX_PLAUSIBLE_VERSION = 16
#: SOURCE records longer than this are not plausible (a source's name).
MAX_SOURCE_NAME = 1024

_DATA, _SOURCE, _GAP = int(RecordKind.DATA), int(RecordKind.SOURCE), int(RecordKind.GAP)
_ADDRESS = int(RecordKind.ADDRESS)
#: An ADDRESS payload's sizes: family byte, two IPv4 (or IPv6) addresses and two ports.
_ADDRESS_SIZES = (13, 37)
_HEAD = RECORD_HEADER_SIZE
_MAX_STEP_NS = int(MAX_TIME_STEP * 1e9)


def _utf8(data: bytes) -> bool:
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _looks_like_magic(buf: bytes) -> bool:
    """The capture magic, or a damaged copy of it (at most two bytes differ and the version follows)."""
    magic = cap.MAGIC
    if buf[: len(magic)] == magic:
        return True
    if len(buf) < cap.HEADER_PREFIX_SIZE:
        return False
    differ = sum(a != b for a, b in zip(buf[: len(magic)], magic, strict=True))
    return differ <= 2 and buf[8] | buf[9] << 8 == cap.VERSION


class CaptureParser:
    """Push parser: bytes of a capture (or raw dump) in, :class:`Chunk` s out.

    Decides on the first bytes whether the input is a hilbench capture (the
    magic, or a copy damaged in at most two bytes) or a raw dump. Used by
    :class:`~hilbench.transports.capture_file.CaptureReader` for files and by the stream sources for pipes and
    the bench's TCP tap, so a live stream decodes as it arrives.

    Damage is found, counted and survived, and everything readable is read;
    :meth:`quality` reports it (the data-quality findings of ``hilbench
    monitor`` and ``hilbench trace``):

    - **truncation**: a record cut off by the end of the input (a recording
      that was killed): :attr:`truncated_bytes`;
    - **corruption**: a record header no writer makes (a kind, source or
      length that cannot be), or a length that does not lead to a plausible
      next record, starts a search for the next offset where two plausible
      records follow each other; the bytes in between are skipped and counted
      (:attr:`corrupt_bytes`, :attr:`corruptions`), and reading resumes there;
    - **time**: a record stamped out of order with both neighbours, or more
      than :data:`MAX_TIME_STEP` from its predecessor, gets its predecessor's
      time (:attr:`time_faults`); a lasting step back (a clock reset, two
      captures joined with ``cat``) is counted (:attr:`time_resets`) and the
      later times continue from the earlier ones, so durations and rates stay
      meaningful. Steps back within :data:`TIME_TOLERANCE` are no finding.

    With ``lookahead`` (files) a record is handed out once the header after it
    has vouched for its length, so a damaged length never hands out a wrong
    payload; live streams (``lookahead=False``) hand a record out as soon as
    it is complete. Memory is bounded by two records (a record is at most
    65,547 bytes).
    """

    def __init__(self, *, raw_baud: int | None = None, name: str = "stream", lookahead: bool = True) -> None:
        self.name = name
        self.raw_baud = raw_baud
        self.lookahead = lookahead
        self.info: CaptureInfo | None = None
        self.mode: str | None = None  # None (undecided), "header", "records" or "raw"
        self.records = 0
        #: Bytes of a record cut off by the end of the input.
        self.truncated_bytes = 0
        #: Bytes skipped while resynchronising after damage, and the number of damaged places.
        self.corrupt_bytes = 0
        self.corruptions = 0  #: damaged places
        #: Records of kinds this version does not know (skipped by their length).
        self.unknown_records = 0
        #: Records whose time was out of order (repaired), and lasting steps back (continued).
        self.time_faults = 0
        self.time_resets = 0  #: lasting steps back in time (continued)
        #: One line per finding (at most :data:`MAX_FINDINGS`; the counters are exact).
        self.findings: list[str] = []
        self._buf = bytearray()
        self._need = 0  # parse again once _buf holds this many bytes
        self._need_rel = 0  # set by _records: bytes of what it kept that a decision needs
        self._verdicts: dict[int, bool] = {}  # stream offset -> whether reading can resume there
        self._wait_at = 0  # set by _chain/_search: the buffer length an undecided verdict needs
        self._resyncing = False  # a search for a place to resume waits for more input
        self._memo: tuple | None = None  # (search context, where it goes on)
        self._epoch = 0  # counts source names (plausibility depends on them)
        self._cand: tuple | None = None  # (buffer, epoch, candidate offsets) of the last prefilter
        self._names: dict[int, str] = {}
        self._declared = bytearray(256)  # source ids a SOURCE record named (1)
        self._named = False  # any source named yet
        self._addr: dict[int, tuple[str, int, str, int] | None] = {}  # ADDRESS records waiting for their DATA
        self._offset = 0  # raw: bytes emitted so far
        self._base = 0  # records: stream offset of the first byte of _buf
        self._t0 = 0.0
        self._timed = False
        self._t_prev: float | None = None  # time of the last record handed out (capture clock)
        self._t_prev_ns: int | None = None  # its stamp as written (for judging places to resume)
        self._t_before: float | None = None  # the time before _t_prev (where a record jumped away from)
        self._t_first = 0.0  # the first record's time
        self._shift = 0.0  # added to later times after a lasting step back
        self._skip: list[int] | None = None  # the damaged stretch being skipped: [start, bytes, finding]

    @property
    def decided(self) -> bool:
        """The header is read (or the input is known to be raw)."""
        return self.mode in ("records", "raw")

    # ------------------------------------------------------------------ findings

    def quality(self) -> dict:
        """Data-quality counters and findings (one line each); ``findings`` is empty for a sound input."""
        return {"truncated_bytes": self.truncated_bytes, "corrupt_bytes": self.corrupt_bytes,
                "corruptions": self.corruptions, "time_faults": self.time_faults,
                "time_resets": self.time_resets, "unknown_records": self.unknown_records,
                "findings": list(self.findings)}

    def _note(self, text: str) -> int:
        """Add a finding; returns its index (-1 once the list is full)."""
        if len(self.findings) < MAX_FINDINGS:
            self.findings.append(text)
            return len(self.findings) - 1
        if len(self.findings) == MAX_FINDINGS:
            self.findings.append("... (further findings are only counted)")
        return -1

    def _skipped(self, pos: int, nbytes: int, resumed: bool) -> None:
        """Count ``nbytes`` of damage from ``pos`` of the buffer (one finding per damaged stretch)."""
        if nbytes <= 0:
            return
        start = self._base + pos
        self.corrupt_bytes += nbytes
        skip = self._skip
        if skip is not None and skip[0] + skip[1] == start:
            skip[1] += nbytes  # the same stretch, continued
        else:
            self.corruptions += 1
            skip = self._skip = [start, nbytes, self._note("")]
        if skip[2] >= 0:
            where = f"reading resumed at byte {skip[0] + skip[1]}" if resumed else "up to the end"
            self.findings[skip[2]] = (f"corrupt: {skip[1]} bytes from byte {skip[0]} are no records (a damaged "
                                      f"record); {where}")

    def _truncated(self, pos: int, have: int, whole: int | None) -> None:
        self.truncated_bytes += have
        at = self._base + pos
        if whole is None:
            self._note(f"truncated: the capture ends {have} bytes into a record header at byte {at} (the "
                       "recording was cut off)")
        else:
            self._note(f"truncated: the capture ends inside its last record at byte {at} ({have} of its {whole} "
                       "bytes; the recording was cut off)")

    # ------------------------------------------------------------------ input

    def feed(self, data: bytes) -> list[Chunk]:
        """Bytes of the input in (any split); the chunks they complete out."""
        out: list[Chunk] = []
        self._buf += data
        if self.mode == "raw":
            self._buf = bytearray(self._raw(bytes(self._buf), out, final=False))
            return out
        if len(self._buf) < self._need:
            return out  # nothing can be decided before that many bytes are here (a long record, a search)
        buf = bytes(self._buf)
        if self.mode is None:
            if len(buf) < cap.HEADER_PREFIX_SIZE:
                if sum(a != b for a, b in zip(buf, cap.MAGIC, strict=False)) <= 2:
                    self._need = len(buf) + 1  # could still be a (damaged) magic
                    return out
                self.mode = "raw"  # cannot be: a live raw stream is not held back
            else:
                self.mode = "header" if _looks_like_magic(buf) else "raw"
        if self.mode == "raw":
            self._buf = bytearray(self._raw(buf, out, final=False))
            return out
        if self.mode == "header":
            size = cap.HEADER_PREFIX_SIZE + cap.header_body_size(buf)
            if len(buf) < size:
                self._need = size
                return out
            self._header(buf[:size])
            self.mode = "records"
            self._base = size
            buf = buf[size:]
        if self.mode == "raw":
            self._buf = bytearray(self._raw(buf, out, final=False))
            self._need = 0
        else:
            rest = self._records(buf, out, final=False)
            self._buf = bytearray(rest)
            self._need = max(self._need_rel, len(rest) + 1)
        return out

    def finish(self) -> list[Chunk]:
        """End of input: emit what a raw dump still holds and the records left; count a cut-off record."""
        buf, self._buf = bytes(self._buf), bytearray()
        out: list[Chunk] = []
        if self.mode in (None, "raw"):
            self.mode = "raw"
            self._raw(buf, out, final=True)
        elif self.mode == "records":
            self._records(buf, out, final=True)
        return out

    def _header(self, head: bytes) -> None:
        magic = head[: len(cap.MAGIC)]
        if magic != cap.MAGIC:
            self._note(f"header: the magic is damaged ({magic.hex(' ')}); read as a capture all the same")
            head = cap.MAGIC + head[len(cap.MAGIC):]
        version = head[8] | head[9] << 8
        if version == 0 or version > MAX_PLAUSIBLE_VERSION:
            self._note(f"header: the version field is damaged ({version}); read as version {cap.VERSION}")
            head = head[:8] + cap.VERSION.to_bytes(2, "little") + head[10:]
        try:
            self.info = cap.parse_header(head)
        except ValueError as exc:  # a newer version: refused, this reader does not know its records
            raise CaptureError(f"{self.name}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 (construct's errors: a damaged header body)
            self.info = CaptureInfo(cap.VERSION, int(Flags.MEASURED), None, 0.0, 0.0, "", "")
            self._note(f"header: the header body is damaged ({type(exc).__name__}); its line rate, protocol "
                       "and description are lost")
        self._t0 = self.info.t0_monotonic
        self._timed = bool(self.info.flags & (Flags.MEASURED | Flags.SYNTHETIC))

    def _raw(self, buf: bytes, out: list[Chunk], final: bool) -> bytes:
        baud = self.raw_baud
        if not baud:
            if buf:
                self._offset += len(buf)
                self.records += 1
                out.append(Chunk(0.0, RAW_SOURCE, buf))
            return b""
        step = RAW_TIMED_CHUNK
        pos = 0
        n = len(buf)
        while n - pos >= step or (final and pos < n):
            piece = buf[pos : pos + step]
            pos += len(piece)
            self._offset += len(piece)
            self.records += 1
            out.append(Chunk(self._offset * 10 / baud, RAW_SOURCE, piece))
        return buf[pos:]

    # ------------------------------------------------------------------ records

    def _level(self, buf: bytes, off: int, after: tuple | None = None) -> tuple:
        """The record header at ``off`` with its plausibility: ``(off, kind, source, length, t_ns, level)``.

        ``level`` 2: a header a writer makes (a DATA or GAP record of a source a SOURCE record named,
        or a SOURCE record); 1: plausible but of a source no SOURCE record named (its name record may
        be damaged); 0: a kind this version does not know; -1: impossible. ``after`` is the header
        before it (a SOURCE record names the source whose data may follow at once).
        """
        kind, source, length, t_ns = cap.unpack_record_header(buf, off)
        if kind == _DATA:
            level = (2 if self._declared[source] else 1) if length > 0 else -1
        elif kind == _SOURCE:
            level = 2 if 0 < length <= MAX_SOURCE_NAME else -1
        elif kind == _GAP:
            level = (2 if self._declared[source] else 1) if length == 4 else -1
        elif kind == _ADDRESS:
            level = (2 if self._declared[source] else 1) if length in _ADDRESS_SIZES else -1
        else:
            level = 0
        if level == 1 and after is not None and after[1] == _SOURCE and after[2] == source:
            level = 2
        return off, kind, source, length, t_ns, level

    def _plain(self, buf: bytes, pos: int, out: list[Chunk]) -> int:
        """The fast path: hand out DATA records of named sources whose next two headers are DATA records
        of named sources too, stamped in order with them; return where it stopped (everything else,
        and the last two records of ``buf``, go the general way). Nine records in ten of a capture."""
        if self._addr:  # a datagram's ADDRESS record waits for its DATA: that one goes the general way
            return pos
        n = len(buf) - _HEAD
        unpack = cap.unpack_record_header
        declared = self._declared
        names = self._names
        append = out.append
        t0 = self._t0
        timed = self._timed
        shift_ns = round(self._shift * 1e9)
        tol_ns = int(TIME_TOLERANCE * 1e9)
        prev = self._t_prev
        prev_ns = None if prev is None else round(prev * 1e9) - shift_ns  # p1 in stamp units
        before = self._t_before
        if pos > n:
            return pos
        k0, s0, l0, t0_ns = unpack(buf, pos)
        e1 = pos + _HEAD + l0
        if k0 != _DATA or not l0 or not declared[s0] or e1 > n:
            return pos
        k1, s1, l1, t1_ns = unpack(buf, e1)
        e2 = e1 + _HEAD + l1
        if k1 != _DATA or not l1 or not declared[s1] or e2 > n:
            return pos
        taken = 0
        while True:
            k2, s2, l2, t2_ns = unpack(buf, e2)
            if k2 != _DATA or not l2 or not declared[s2]:
                break
            if timed:
                if prev_ns is None or not (prev_ns - tol_ns <= t0_ns <= min(t1_ns, t2_ns) + tol_ns
                                           and t0_ns - prev_ns <= _MAX_STEP_NS):
                    break
                if t0_ns != prev_ns:
                    before = prev
                prev = (t0_ns + shift_ns) * 1e-9
                prev_ns = t0_ns
                append(Chunk(t0 + prev, names[s0], buf[pos + _HEAD : e1]))
            else:
                append(Chunk(t0 + t0_ns * 1e-9, names[s0], buf[pos + _HEAD : e1]))
            taken += 1
            pos, e1, s0, l0, t0_ns = e1, e2, s1, l1, t1_ns
            s1, l1, t1_ns = s2, l2, t2_ns
            e2 = e1 + _HEAD + l1
            if e2 > n:
                break
        if taken:
            self.records += taken
            if timed:
                self._t_prev, self._t_before, self._t_prev_ns = prev, before, prev_ns
        return pos

    def _records(self, buf: bytes, out: list[Chunk], final: bool) -> bytes:
        """Hand out every record of ``buf`` that is known good; return the bytes to keep for later.

        A record is good when its header is plausible and the next two headers its length leads to
        are plausible too (or the input ends at a record boundary): a damaged length lands on a
        plausible header by chance about once in a thousand, on two in a row about once in a million.
        """
        level = self._level
        hold = self.lookahead and not final
        n = len(buf)
        pos = 0
        walk: list[tuple] = []  # plausible headers chained from pos (walk[0] is the record at pos)
        self._need_rel = 0
        while True:
            if not walk:
                pos = self._plain(buf, pos, out)
                if n - pos < _HEAD:
                    if final and pos < n:
                        self._truncated(pos, n - pos, None)
                        pos = n
                    self._need_rel = _HEAD
                    break
                h = level(buf, pos)
                if h[5] < 0 or self._resyncing:
                    # damage: resume where a chain of good records starts (from pos itself when a search
                    # that waited for more input goes on)
                    q, sure = self._search(buf, pos if self._resyncing else pos + 1, final)
                    if not sure:
                        if not self._resyncing and h[1] in (_DATA, _SOURCE, _GAP, _ADDRESS) and q < pos + _HEAD + h[3]:
                            self._need_rel = self._wait_at - pos  # its length may yet be mended: keep it
                            break
                        self._resyncing = True
                        self._skipped(pos, q - pos, False)
                        pos = q
                        self._need_rel = self._wait_at - pos
                        break
                    self._resyncing = False
                    if q == pos or not self._repair(buf, h, q, out):  # a name record too long?
                        self._skipped(pos, q - pos, q < n)
                    pos = q
                    continue
                walk.append(h)
            state = "chain"
            while len(walk) < 3:
                last = walk[-1]
                e = last[0] + _HEAD + last[3]
                if e > n:
                    state = "past"
                    break
                if n - e < _HEAD:
                    state = "end"
                    break
                h = level(buf, e, last)
                if h[5] < 1:
                    state = "bad"
                    break
                if h[1] == _SOURCE:  # a name record vouches only with a name in it
                    ne = e + _HEAD + h[3]
                    if ne > n:
                        state = "past"
                        break
                    if not _utf8(buf[e + _HEAD : ne]):
                        state = "bad"
                        break
                walk.append(h)
            if state == "chain" and (
                    (walk[1][5] == 2 and walk[2][5] == 2) if walk[0][5] == 0
                    else (walk[0][5] == 2 or walk[1][5] == 2 or walk[2][5] == 2 or not self._named)):
                self._take(buf, walk, out)
                pos = walk[0][0] + _HEAD + walk[0][3]
                del walk[0]
                if walk[0][1] == _DATA:
                    walk.clear()  # back to the fast path where it can take over
                continue
            if state in ("end", "past") and not final:
                if hold or state == "past" and len(walk) == 1:
                    last = walk[-1]
                    self._need_rel = last[0] + _HEAD + last[3] + _HEAD - pos
                    break  # wait for more input to vouch for (or complete) the record at pos
                self._take(buf, walk, out)  # live: hand out what is complete
                pos = walk[0][0] + _HEAD + walk[0][3]
                del walk[0]
                continue
            if state == "end" and walk[0][5] == 2:  # final: the input ends at a record boundary
                for _ in range(len(walk)):
                    self._take(buf, walk, out)
                    pos = walk[0][0] + _HEAD + walk[0][3]
                    del walk[0]
                continue
            if state == "past" and len(walk) > 1 and (walk[0][5] == 2 or walk[0][5] == 1 and walk[1][5] == 2):
                # final: the records before the last one are vouched for
                self._take(buf, walk, out)
                pos = walk[1][0]
                del walk[0]
                continue
            h = walk[0]
            end = pos + _HEAD + h[3]
            if state == "bad" and len(walk) > 1 and (h[5] == 2 or h[5] == 1 and walk[1][5] == 2):
                # the record's length led to a plausible header: the damage is in the next record
                self._take(buf, walk, out)
                pos = end
                del walk[0]
                walk.clear()  # judged afresh (its successor is the damage)
                continue
            # damage at or right after the record at pos: where reading can resume says which
            q, sure = self._search(buf, pos + 1, final)
            if not sure:
                self._need_rel = self._wait_at - pos
                break  # decided when more input arrives (bounded: a record is at most 65,547 bytes)
            walk.clear()
            if state == "past" and q >= n:
                self._truncated(pos, n - pos, _HEAD + h[3])
                pos = n
                break
            if q >= end and h[5] == 2:
                # the damage is after this record (or its length is short; its own length is the safer
                # reading: no bytes are made part of a record that may not be)
                self._take(buf, [h, *self._after(buf, q)], out)
                pos = end
                continue
            # the record's length runs over a good record: that one says where this one really ends
            if not self._repair(buf, h, q, out):
                self._skipped(pos, q - pos, q < n)
            pos = q
        self._base += pos
        return buf[pos:]

    def _take(self, buf: bytes, walk: list[tuple], out: list[Chunk]) -> None:
        """Hand out the record ``walk[0]`` (its successor, if known, tells whether its time is sane)."""
        off, kind, source, length, t_ns, lvl = walk[0]
        payload = buf[off + _HEAD : off + _HEAD + length]
        self.records += 1
        if kind in (_DATA, _GAP):
            if self._timed:
                after = [h[4] for h in walk[1:3] if h[1] in (_DATA, _GAP)]
                t = self._time(t_ns, (*after, None, None)[:2], off)
            else:
                t = self._t0 + t_ns * 1e-9
            name = self._names.get(source)
            if name is None:
                name = self._unnamed(source, off)
            if kind == _DATA:
                addr = self._addr.pop(source, None) if self._addr else None
                out.append(Chunk(t, name, payload, 0, addr))
            else:
                out.append(Chunk(t, name, b"", cap.gap_lost(payload) or 0))
        elif kind == _SOURCE:
            self._name(source, payload, off)
        elif kind == _ADDRESS:
            self._addr[source] = cap.parse_address(payload)
        else:
            self.unknown_records += 1
            if self.unknown_records == 1:
                self._note(f"unknown: a record of kind {kind} at byte {self._base + off} was skipped (a newer "
                           "writer, or damage)")

    def _name(self, source: int, payload: bytes, off: int) -> None:
        name = payload.decode("utf-8", errors="replace")
        old = self._names.get(source)
        if old is not None and old != name:
            self._note(f"corrupt: source {source} renamed from {old!r} to {name[:40]!r} at byte {self._base + off}; "
                       "the first name is kept")
            return
        self._names[source] = name
        if not self._declared[source]:
            self._declared[source] = 1
            self._named = True
            self._verdicts.clear()  # plausibility depends on which sources are named
            self._epoch += 1

    def _unnamed(self, source: int, off: int) -> str:
        name = self._names[source] = f"source{source}"
        self._note(f"unnamed: data of source {source} at byte {self._base + off}, which no SOURCE record names "
                   "(a damaged name record?); read as {name!r}".replace("{name!r}", repr(name)))
        return name

    def _repair(self, buf: bytes, h: tuple, q: int, out: list[Chunk]) -> bool:
        """A record whose length is damaged, read up to ``q`` where the next good record starts; False if
        its bytes cannot be such a record."""
        off, kind, source, length, t_ns, lvl = h
        size = q - off - _HEAD
        if size >= length:
            return False  # only a length that runs over a good record is mended
        payload = buf[off + _HEAD : q]
        if kind == _DATA:
            ok = 0 < size <= MAX_PAYLOAD
        elif kind == _SOURCE:
            ok = 0 < size <= MAX_SOURCE_NAME and _utf8(payload)
        elif kind == _GAP:
            ok = size == 4
        elif kind == _ADDRESS:
            ok = size in _ADDRESS_SIZES
        else:
            ok = False
        if not ok:
            return False
        self.corruptions += 1
        self._note(f"corrupt: the record at byte {self._base + off} has a damaged length ({length}); read as the "
                   f"{size} bytes up to the next good record")
        self._take(buf, [(off, kind, source, size, t_ns, lvl), *self._after(buf, q)], out)
        return True

    def _after(self, buf: bytes, q: int) -> list[tuple]:
        """The header at ``q`` (where reading resumes) as the next record, if it is in ``buf``."""
        return [self._level(buf, q)] if q + _HEAD <= len(buf) else []

    def _chain(self, buf: bytes, q: int, final: bool) -> bool | None:
        """Whether reading can resume at ``q``: True, False, or None when the input does not reach far
        enough yet to tell.

        A place to resume is a header a writer makes (a SOURCE record, or data of a named source) followed
        by two more plausible records, or by the end of the input, stamped within a day of the last good
        record. Before any source is named (the first name record damaged), data of unnamed sources
        count, but then five records in a row must fit, stamped within a day of each other. The verdicts
        on structure are remembered (a wait re-reads the buffer); the times are judged afresh.
        """
        key = self._base + q
        hit = self._verdicts.get(key)
        if hit is None:
            hit = self._structure(buf, q, final)
            if hit[0] is not None and not final:
                if len(self._verdicts) > 65536:
                    self._verdicts = {k: v for k, v in self._verdicts.items() if k >= self._base}
                self._verdicts[key] = hit
        verdict, stamps = hit
        if verdict is False or not self._timed or not stamps:
            return verdict
        if self._named:
            ref = self._t_prev_ns
            if ref is not None and (max(stamps) - ref > _MAX_STEP_NS or ref - min(stamps) > _MAX_STEP_NS):
                return False
        elif max(stamps) - min(stamps) > _MAX_STEP_NS:
            return False
        return verdict

    def _structure(self, buf: bytes, q: int, final: bool) -> tuple[bool | None, tuple[int, ...]]:
        """:meth:`_chain` without the times: the verdict on structure and the stamps of the chain's records."""
        n = len(buf)
        h = self._level(buf, q)
        named = self._named
        if h[5] < (2 if named else 1):
            return False, ()
        if h[1] == _SOURCE:
            e = q + _HEAD + h[3]
            if e > n:
                self._wait_at = e
                return (False if final else None), ()
            if not _utf8(buf[q + _HEAD : e]):
                return False, ()
        stamps = []
        need = 2 if named else 4
        for k in range(need + 1):
            if h[1] != _SOURCE:
                stamps.append(h[4])
            if k == need:
                break
            e = h[0] + _HEAD + h[3]
            if e + _HEAD > n:
                self._wait_at = e + _HEAD
                if e > n:
                    return (False if final else None), tuple(stamps)
                return (True if final else None), tuple(stamps)
            h = self._level(buf, e, h)
            if h[5] < 1:
                return False, ()
        return True, tuple(stamps)

    def _candidates(self, buf: bytes, start: int, stop: int) -> list[int]:
        """Offsets in ``[start, stop)`` where a plausible record header could begin.

        A numpy prefilter from the first offset asked for to the end of the buffer, made once per
        buffer and naming of sources (a damaged stretch makes hundreds of searches, each a record or
        two long: one pass, not hundreds).
        """
        import numpy as np  # here: only a damaged stretch needs it, and reading a capture starts without it

        cache = self._cand
        if cache is None or cache[0] is not buf or cache[1] != self._epoch or start < cache[2]:
            n = len(buf)
            count = n - _HEAD + 1 - start
            if count <= 0:
                found: list[int] = []
            else:
                kind = np.frombuffer(buf, dtype=np.uint8, count=count, offset=start)
                length = np.ndarray((count,), "<u2", buf, start + 2, (1,))  # unaligned view: no copy
                data, gap, addr = kind == _DATA, kind == _GAP, kind == _ADDRESS
                if self._named:  # where reading resumes, a data record must be of a named source
                    named = np.frombuffer(self._declared, dtype=bool)[np.frombuffer(buf, dtype=np.uint8, count=count, offset=start + 1)]
                    data &= named
                    gap &= named
                    addr &= named
                mask = ((data & (length > 0)) | ((kind == _SOURCE) & (length > 0) & (length <= MAX_SOURCE_NAME))
                        | (gap & (length == 4)) | (addr & ((length == 13) | (length == 37))))
                found = (np.flatnonzero(mask) + start).tolist()
            cache = self._cand = (buf, self._epoch, start, found)
        found = cache[3]
        return found[bisect.bisect_left(found, start) : bisect.bisect_left(found, stop)]

    def _search(self, buf: bytes, start: int, final: bool) -> tuple[int, bool]:
        """Where reading can resume, from ``start`` on: ``(offset, True)``, ``len(buf)`` if nowhere; or
        ``(offset, False)``: everything before it is damage, from there on it is decided by more input.

        A chain whose first record would swallow another place to resume is no place to resume: a length
        read from damaged bytes that happens to end on a real record boundary chains on for ever. The
        search looks near ``start`` first and widens (a place to resume is usually a record away).
        """
        n = len(buf)
        chain = self._chain
        base = self._base
        # A search that waited for input goes on where it stopped (what it judged stays judged).
        context = (base + start, self._t_prev_ns, self._epoch)
        lo, width = start, 256
        if self._memo is not None and self._memo[0] == context:
            lo = max(start, self._memo[1] - base)
        while lo <= n - _HEAD:
            hi = lo + width
            for q in self._candidates(buf, lo, hi):
                verdict = chain(buf, q, final)
                if verdict is None:
                    self._memo = (context, base + q)
                    return q, False
                if not verdict:
                    continue
                end = q + _HEAD + (buf[q + 2] | buf[q + 3] << 8)
                inside = False
                for q2 in self._candidates(buf, q + 1, end):
                    v2 = chain(buf, q2, final)
                    if v2 is None:
                        self._memo = (context, base + q)
                        return q, False  # cannot tell yet
                    if v2:
                        inside = True
                        break
                if not inside:
                    return q, True
            lo, width = hi, width * 4
        if final:
            return n, True
        self._wait_at = n + 1
        q = max(start, n - _HEAD + 1)
        self._memo = (context, base + q)
        return q, False

    # ------------------------------------------------------------------ time

    def _time(self, t_ns: int, after: tuple[int | None, int | None], pos: int) -> float:
        """The time of a record (capture clock), repaired where it cannot be right (see the class doc).

        Judged against the two records before it and, where known, the two after it (``after``: their
        stamps): a record out of order with both neighbours takes its predecessor's time; a step back to
        where the time was before the previous record shows that one was the odd one out (counted then);
        a step back to the capture's start that the next two records confirm is a restart (two captures
        joined), and later times continue from the earlier ones; any other lasting step back is kept and
        counted.
        """
        shift = self._shift
        t = t_ns * 1e-9 + shift
        p1, p2 = self._t_prev, self._t_before
        nxt = None if after[0] is None else after[0] * 1e-9 + shift
        tol = TIME_TOLERANCE
        if p1 is None:
            if (nxt is not None and t > nxt + tol) or abs(t) > MAX_TIME_STEP:
                repaired = nxt if nxt is not None and abs(nxt) <= MAX_TIME_STEP else 0.0
                self._time_fault(pos, t, repaired)
                t = repaired
            self._t_first = t
        else:
            step = t - p1
            if step < -tol and p2 is not None and p2 - tol <= t and p1 - p2 > 2 * tol and (
                    nxt is None or nxt >= t - tol):
                self._time_fault(pos, p1, t, earlier=True)  # the previous record had jumped ahead of both
            elif abs(step) > MAX_TIME_STEP:
                self._time_fault(pos, t, p1)
                t = p1
            elif step < -tol:
                nxt2 = None if after[1] is None else after[1] * 1e-9 + shift
                if nxt is not None and nxt >= p1 - tol:
                    self._time_fault(pos, t, p1)  # behind both neighbours
                    t = p1
                elif (nxt is not None and nxt2 is not None and t - tol <= nxt < p1 - tol
                      and nxt - tol <= nxt2 < p1 - tol and t <= self._t_first + 1.0):
                    # back to the start, and staying there: a second capture joined to the first
                    self.time_resets += 1
                    self._note(f"time: restarts at byte {self._base + pos} ({-step:.6f} s back: two captures "
                               "joined?); later times continue from the earlier ones")
                    self._shift -= step
                    t = p1
                else:
                    self.time_resets += 1
                    self._note(f"time: goes back {-step:.6f} s at byte {self._base + pos} and stays back; kept")
            elif step > tol and any(x is not None and t > x + tol and x >= p1 - tol for x in (
                    nxt, None if after[1] is None else after[1] * 1e-9 + shift)):
                self._time_fault(pos, t, p1)  # ahead of a later record that is in line with the earlier one
                t = p1
        if t != p1:
            self._t_before = p1
        self._t_prev = t
        self._t_prev_ns = round((t - self._shift) * 1e9)  # what a stamp in line with it reads
        return self._t0 + t

    def _time_fault(self, pos: int, t: float, repaired: float, earlier: bool = False) -> None:
        self.time_faults += 1
        if self.time_faults <= 3 and earlier:
            self._note(f"time: the record before byte {self._base + pos} was stamped {t:+.6f} s, ahead of its "
                       f"neighbours (at {repaired:+.6f} s); its data was kept")
        elif self.time_faults <= 3:
            self._note(f"time: the record at byte {self._base + pos} is stamped {t:+.6f} s, out of order with its "
                       f"neighbours; taken as {repaired:+.6f} s")
        elif self.time_faults == 4:
            self._note("time: more records out of order (counted in time_faults)")


__all__ = ["RAW_SOURCE", "RAW_TIMED_CHUNK", "READ_SIZE", "CaptureParser"]
