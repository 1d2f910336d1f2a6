"""Trace stamps as text: stamp lines, log lines and run-time statistics blocks on one port.

The rover board (spec sheet stm32_board.md §3) sends everything as ASCII lines
on one UART: trace stamps in two dialects (thesis ``wheel_ctrl 96 1``, branch
heads ``wheel_ctrl 96 in``), ulog lines (``12:00:01 [INFO]: ...``) and the
run-time statistics report (vTaskGetRunTimeStats and vTaskList tables between
separator lines, closed by ``output took N us`` or ``profiled for N us``).

:class:`TextDecoder` separates them in one incremental pass and never raises:
lines it cannot classify become :class:`~hilbench.protocols.problem.Problem`
items of kind :data:`UNREADABLE` (``detail`` says why) and are counted. Two
entry points share one state:

- ``feed(data)`` returns small NamedTuples: :class:`Stamp`, :class:`LogMessage`,
  :class:`RuntimeReport`, :class:`NameEntry`, :class:`TableStart`, and the
  problems;
- ``feed_batch(data)`` returns the same items in the same order, except that
  runs of consecutive stamps come as one :class:`StampBatch` of numpy columns.
  This is the fast path for a profiler: the stamp lines of a chunk are parsed
  with vectorised numpy operations over the raw bytes, and only the other
  lines (logs, report rows) go through the per-line classifier.

The per-line classifier (:func:`classify`, §3.8) is the definition; a test
proves the vectorised path agrees with it line for line. The binary stamp
format is in :mod:`hilbench.protocols.tracestamp_binary`; a port that carries
both is read with :class:`hilbench.protocols.tracestamp_stream.StreamDecoder`.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Sequence
from typing import NamedTuple

import numpy as np

from hilbench.protocols.problem import Problem

# --------------------------------------------------------------------------- constants

#: Edge tokens per dialect: index 0 = end (switch-out / scope exit), 1 = begin.
DIALECTS: dict[str, tuple[bytes, bytes]] = {"thesis": (b"0", b"1"), "branch": (b"out", b"in")}
EDGE_TOKENS: dict[bytes, bool] = {b"1": True, b"0": False, b"in": True, b"out": False}
#: Lines longer than this without a newline are dropped as one :data:`UNREADABLE` problem (bounded memory).
MAX_LINE = 4096
#: The :class:`~hilbench.protocols.problem.Problem` kind of a line that fits no format (one per line).
UNREADABLE = "unreadable"
#: FreeRTOS ``configMAX_TASK_NAME_LEN`` 16: names are padded to 15 characters in report rows.
NAME_FIELD = 15
SEPARATOR_WIDTH = 45

_SEP_EQ = re.compile(rb"={3,}")
_SEP_DASH = re.compile(rb"-{3,}")
_CLOSING = re.compile(rb"(output took|profiled for) (\d+) us")
_LOG = re.compile(rb"(\d\d:\d\d:\d\d) \[([A-Z]+)\]: (.*)", re.S)
#: At most 18 digits: every stamp time fits an int64 (a longer digit run is a bad line, not a crash).
_STAMP = re.compile(rb"([^\t]+) (\d{1,18}) (0|1|in|out)", re.S)
_META = re.compile(rb"@(tsb|id)(?: (.*))?", re.S)
_META_ID = re.compile(rb"(\d+) ([^\t]+)", re.S)
_FREE_HEAP = re.compile(rb"free heap:[\t ]*(\d+)")
_CTX = re.compile(rb"ctx switches:[\t ]*(\d+)")
_RT_HEADER = re.compile(rb"Task\t+Time\t+(%%?)")
_TASK_HEADER = re.compile(rb"Task\t+State\t+Prio\t+Stack\t+Num")
_RT_ROW = re.compile(rb"([^\t]+)\t+(\d+)\t+(<1|\d+)%")
_TASK_ROW = re.compile(rb"([^\t]+)\t+([XRBSD])\t+(\d+)\t+(\d+)\t+(\d+)")
#: Last bytes a stamp line can end with (its edge token: 0, 1, in, out): a cheap test before the regex.
_STAMP_LAST = frozenset(b"01nt")
#: Last bytes a report row, header or key line can end with (a digit, ``%``, or ``Num``).
_REPORT_LAST = frozenset(b"0123456789%m")


# --------------------------------------------------------------------------- items


class Stamp(NamedTuple):
    """One trace stamp: ``name`` (task or function), time in µs, begin (in/1) or end (out/0)."""

    name: str
    t_us: int
    begin: bool


class LogMessage(NamedTuple):
    """A ulog line ``HH:MM:SS [LEVEL]: message`` (``clock`` is the board's RTC time text)."""

    clock: str
    level: str
    message: str


class RuntimeRow(NamedTuple):
    """A vTaskGetRunTimeStats row: run-time counter (≈92.6 µs units) and the printed integer %."""

    name: str
    abs_time: int
    percent: int  # 0 where the board printed "<1%"


class TaskRow(NamedTuple):
    """A vTaskList row: state letter (X R B S D), priority, stack high-water mark (words), creation number."""

    name: str
    state: str
    priority: int
    stack_hwm: int
    number: int


class RuntimeReport(NamedTuple):
    """The run-time statistics block printed after a sampling window (§3.7).

    ``closing`` is ``"output took"`` (branch heads) or ``"profiled for"`` (thesis)
    and ``closing_us`` its value. ``complete`` is true when the block was seen
    from its opening separator through its closing line; a report picked up in
    the middle, or whose closing line never came, is still returned.
    """

    free_heap: int | None
    ctx_switches: int | None
    runtime: tuple[RuntimeRow, ...]
    tasks: tuple[TaskRow, ...]
    closing: str | None
    closing_us: int | None
    percent_header: str
    complete: bool

    @property
    def total_abs(self) -> int:
        """Sum of the run-time counters (the divisor's base)."""
        return sum(r.abs_time for r in self.runtime)

    def recomputed_percent(self) -> dict[str, int]:
        """The kernel's integer % from the counters: abs // (total // 100)."""
        div = self.total_abs // 100
        return {r.name: (r.abs_time // div if div else 0) for r in self.runtime}

    @property
    def output_took_us(self) -> int | None:
        return self.closing_us if self.closing == "output took" else None

    @property
    def profiled_for_us(self) -> int | None:
        return self.closing_us if self.closing == "profiled for" else None


class NameEntry(NamedTuple):
    """One entry of a binary stream's name table (text line ``@id <id> <name>``)."""

    id: int
    name: str


class TableStart(NamedTuple):
    """``@tsb <version>``: a binary stream's name table follows and replaces the old one."""

    version: int


class StampBatch(NamedTuple):
    """Consecutive stamps as numpy columns (the fast path of ``feed_batch``).

    ``ids`` index into ``names`` (the decoder's name list when the batch was made;
    an id keeps its meaning for the decoder's lifetime). ``t_us`` is int64
    microseconds, ``begin`` bool. ``len(batch.t_us)`` is the stamp count.
    """

    names: tuple[str, ...]
    ids: np.ndarray
    t_us: np.ndarray
    begin: np.ndarray

    @property
    def count(self) -> int:
        return len(self.t_us)

    def stamps(self) -> list[Stamp]:
        """The batch as :class:`Stamp` tuples."""
        names = self.names
        new = tuple.__new__
        return [new(Stamp, (names[i], t, b)) for i, t, b in
                zip(self.ids.tolist(), self.t_us.tolist(), self.begin.tolist(), strict=True)]


Item = Stamp | LogMessage | RuntimeReport | NameEntry | TableStart | Problem


# --------------------------------------------------------------------------- formatting (board side)


def format_stamp(name: str, t_us: int, begin: bool, dialect: str = "branch") -> bytes:
    """One stamp line, LF-terminated: ``b"wheel_ctrl 96 in\\n"``."""
    return b"%s %d %s\n" % (name.encode("latin-1"), t_us, DIALECTS[dialect][1 if begin else 0])


def format_stamps(names: Sequence[bytes], ids: Iterable[int], t_us: Iterable[int], begin: Iterable[bool],
                  dialect: str = "branch") -> list[bytes]:
    """Many stamp lines; ``names`` are the encoded names ``ids`` index."""
    end_tok, begin_tok = DIALECTS[dialect]
    tokens = (end_tok, begin_tok)
    ids, t_us, begin = (np.asarray(x).tolist() for x in (ids, t_us, begin))
    return [b"%s %d %s\n" % (names[i], t, tokens[b]) for i, t, b in zip(ids, t_us, begin, strict=True)]


def stamp_line_lengths(name_lengths: np.ndarray, ids: np.ndarray, t_us: np.ndarray, begin: np.ndarray,
                       dialect: str = "branch") -> np.ndarray:
    """Byte lengths of stamp lines without formatting them (vectorised); ``name_lengths[id]``."""
    t = np.asarray(t_us, dtype=np.int64)
    digits = np.ones(len(t), dtype=np.int64)
    p = 10
    while True:
        more = t >= p
        if not more.any():
            break
        digits += more
        p *= 10
    end_tok, begin_tok = DIALECTS[dialect]
    edge = np.where(np.asarray(begin, dtype=bool), len(begin_tok), len(end_tok))
    return np.asarray(name_lengths)[ids] + digits + edge + 3  # two spaces and LF


def format_log(clock_s: float, level: str, message: str) -> bytes:
    """A ulog line; ``clock_s`` is seconds on the board's RTC (wraps at 24 h)."""
    s = int(clock_s) % 86400
    return f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d} [{level}]: {message}\n".encode()


def format_report(report: RuntimeReport, *, separator_width: int = SEPARATOR_WIDTH) -> bytes:
    """The report block byte for byte as the branch heads print it (§3.7, §6.5).

    ``percent_header`` ``"%%"`` reproduces V3's literal ``%%``; ``"%"`` V2's. A
    ``"profiled for"`` closing is framed by separators as in the thesis.
    """
    eq = b"=" * separator_width + b"\n"
    out = [eq, b"free heap:\t\t%d\n" % (report.free_heap or 0), b"ctx switches:\t\t%d\n" % (report.ctx_switches or 0),
           b"Task\t\tTime\t\t%s\n" % report.percent_header.encode()]
    for r in report.runtime:
        pct = b"<1%" if r.percent == 0 else b"%d%%" % r.percent
        out.append(b"%s\t%d\t\t%s\r\n" % (r.name.ljust(NAME_FIELD).encode(), r.abs_time, pct))
    out.append(b"-" * separator_width + b"\n")
    out.append(b"Task\t\tState\tPrio\tStack\tNum\n")
    for t in report.tasks:
        out.append(b"%s\t%s\t%d\t%d\t%d\r\n" % (t.name.ljust(NAME_FIELD).encode(), t.state.encode(), t.priority,
                                                t.stack_hwm, t.number))
    out.append(eq)
    if report.closing == "profiled for":
        out.append(b"profiled for %d us\n" % (report.closing_us or 0))
        out.append(eq)
    elif report.closing is not None:
        out.append(b"%s %d us\n" % (report.closing.encode(), report.closing_us or 0))
    return b"".join(out)


def runtime_percentages(abs_times: Sequence[int]) -> list[int]:
    """vTaskGetRunTimeStats' integer %: abs // (total // 100) (0 prints as ``<1%``)."""
    div = sum(abs_times) // 100
    return [a // div if div else 0 for a in abs_times]


# --------------------------------------------------------------------------- classification


def parse_stamp(line: bytes | str) -> Stamp | None:
    """A stamp from one line (trailing CR/LF ignored), or None; no block context (TAB lines are never stamps)."""
    if isinstance(line, str):
        line = line.encode("latin-1")
    line = line.rstrip(b"\n")
    if line.endswith(b"\r"):
        line = line[:-1]
    if _LOG.match(line) or line.startswith(b"@"):
        return None
    m = _STAMP.fullmatch(line)
    if m is None:
        return None
    return Stamp(m[1].decode("latin-1"), int(m[2]), EDGE_TOKENS[m[3]])


def classify(line: bytes | str) -> str:
    """The kind of one line by §3.8's rules, without block context.

    One of ``separator``, ``report`` (key/value lines, table headers and TAB
    rows), ``closing``, ``log``, ``meta`` (``@`` name-table lines of the binary
    format), ``stamp``, ``blank`` or ``error``. A TAB never occurs in a stamp,
    so a vTaskList row (``tsink\\tB\\t32\\t483\\t1``) is ``report``, not a stamp
    named ``tsink B 32`` (§3.8's pitfall).
    """
    if isinstance(line, str):
        line = line.encode("latin-1")
    line = line.rstrip(b"\n")
    if line.endswith(b"\r"):
        line = line[:-1]
    return _kind(line)


def _kind(line: bytes) -> str:
    if not line:
        return "blank"
    c = line[0]
    if c in b"=-" and (_SEP_EQ.fullmatch(line) or _SEP_DASH.fullmatch(line)):
        return "separator"
    if b"\t" in line:
        return "report" if _report_row(line) is not None else "error"
    if _CLOSING.fullmatch(line):
        return "closing"
    if _LOG.match(line):
        return "log"
    if c == 0x40:  # '@'
        return "meta" if _meta(line) is not None else "error"
    if _STAMP.fullmatch(line):
        return "stamp"
    return "error"


def _report_row(line: bytes) -> tuple[str, object] | None:
    """A TAB-bearing report line: ('free_heap', n) / ('ctx', n) / ('rt_header', pct) / ('task_header', None)
    / ('rt_row', RuntimeRow) / ('task_row', TaskRow); None if it is none of them."""
    if not line or line[-1] not in _REPORT_LAST:
        return None  # every report line ends with a digit, % or "Num": garbage is turned away at once
    m = _RT_ROW.fullmatch(line)
    if m:
        name = m[1].decode("latin-1").rstrip(" ")
        if name == "Task":
            return None
        return "rt_row", RuntimeRow(name, int(m[2]), 0 if m[3] == b"<1" else int(m[3]))
    m = _TASK_ROW.fullmatch(line)
    if m:
        return "task_row", TaskRow(m[1].decode("latin-1").rstrip(" "), m[2].decode(), int(m[3]), int(m[4]),
                                   int(m[5]))
    m = _FREE_HEAP.fullmatch(line)
    if m:
        return "free_heap", int(m[1])
    m = _CTX.fullmatch(line)
    if m:
        return "ctx", int(m[1])
    m = _RT_HEADER.fullmatch(line)
    if m:
        return "rt_header", m[1].decode()
    if _TASK_HEADER.fullmatch(line):
        return "task_header", None
    return None


def _meta(line: bytes) -> NameEntry | TableStart | None:
    m = _META.fullmatch(line)
    if m is None:
        return None
    if m[1] == b"tsb":
        arg = (m[2] or b"").split(b" ")[0]
        return TableStart(int(arg)) if arg.isdigit() else None
    m2 = _META_ID.fullmatch(m[2] or b"")
    if m2 is None:
        return None
    return NameEntry(int(m2[1]), m2[2].decode("latin-1"))


# --------------------------------------------------------------------------- report assembly


class _ReportBuilder:
    __slots__ = ("free_heap", "ctx", "runtime", "tasks", "closing", "closing_us", "pct", "section", "opened",
                 "sep_after_end")

    def __init__(self, opened: bool) -> None:
        self.free_heap: int | None = None
        self.ctx: int | None = None
        self.runtime: list[RuntimeRow] = []
        self.tasks: list[TaskRow] = []
        self.closing: str | None = None
        self.closing_us: int | None = None
        self.pct = "%%"
        self.section = "head"  # head -> tasks (after '-') -> end (after the closing '=')
        self.opened = opened  # saw the opening separator
        self.sep_after_end = False  # a separator followed the end: maybe the next block's opening

    @property
    def has_content(self) -> bool:
        return bool(self.runtime or self.tasks or self.free_heap is not None or self.ctx is not None)

    def build(self) -> RuntimeReport:
        complete = self.opened and self.section == "end" and self.closing is not None
        return RuntimeReport(self.free_heap, self.ctx, tuple(self.runtime), tuple(self.tasks), self.closing,
                             self.closing_us, self.pct, complete)


# --------------------------------------------------------------------------- decoder

#: At most this many distinct names are kept; further new names all map to :data:`OVERFLOW_NAME`.
MAX_NAMES = 65536
OVERFLOW_NAME = "<too many names>"  #: what every new name beyond MAX_NAMES becomes


class NameRegistry:
    """The names decoders have seen; ``StampBatch.ids`` index :attr:`names`. Bounded by :data:`MAX_NAMES`."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self._ids: dict[bytes, int] = {}

    def id_of(self, raw: bytes) -> int:
        """The id of a name given as bytes (latin-1), adding it if new."""
        nid = self._ids.get(raw)
        if nid is None:
            if len(self.names) >= MAX_NAMES:
                raw = OVERFLOW_NAME.encode()
                nid = self._ids.get(raw)
                if nid is not None:
                    return nid
            nid = self._ids[raw] = len(self.names)
            self.names.append(raw.decode("latin-1"))
        return nid

    def id_of_str(self, name: str) -> int:
        return self.id_of(name.encode("latin-1"))

    def snapshot(self) -> tuple[str, ...]:
        """The names as a tuple (cached until a name is added)."""
        snap = self._snapshot
        if snap is None or len(snap) != len(self.names):
            snap = self._snapshot = tuple(self.names)
        return snap

    _snapshot: tuple[str, ...] | None = None


class TextDecoder:
    """Incremental decoder for the board's text output; never raises.

    Counters (read them any time): ``bytes_in``, ``lines``, ``stamp_lines``,
    ``log_lines``, ``report_lines`` (separators, report rows and closing
    lines), ``meta_lines``, ``blank_lines``, ``parse_errors``, ``reports``, and
    ``dialects`` (stamp lines per dialect, ``{"thesis": n, "branch": n}``).
    ``names`` is the list ``StampBatch.ids`` index into; pass a shared
    :class:`NameRegistry` to give several decoders one list.
    """

    def __init__(self, registry: NameRegistry | None = None) -> None:
        self._buf = b""
        self._skipping = False  # inside an over-long line, discarding to the next LF
        self._report: _ReportBuilder | None = None
        self.registry = registry or NameRegistry()
        self._key_ids: dict[tuple[int, int], int] = {}
        self.bytes_in = 0
        self.lines = 0
        self.stamp_lines = 0
        self.log_lines = 0
        self.report_lines = 0
        self.meta_lines = 0
        self.blank_lines = 0
        self.parse_errors = 0
        self.reports = 0
        self.dialects = {"thesis": 0, "branch": 0}

    # ------------------------------------------------------------------ public

    @property
    def names(self) -> list[str]:
        return self.registry.names

    @property
    def pending(self) -> int:
        """Bytes of an unfinished line held for the next call."""
        return len(self._buf)

    @property
    def in_report(self) -> bool:
        """True while a report block is open."""
        return self._report is not None

    def feed(self, data: bytes) -> list[Item]:
        """Decode ``data``; return the complete items in arrival order (stamps as :class:`Stamp`)."""
        out: list[Item] = []
        for item in self._decode(data):
            if type(item) is StampBatch:
                out.extend(item.stamps())
            else:
                out.append(item)
        return out

    def feed_batch(self, data: bytes) -> list[StampBatch | Item]:
        """Decode ``data``; like :meth:`feed` but runs of stamps come as :class:`StampBatch` columns."""
        return self._batched(self._decode(data))

    def cut(self) -> int:
        """The input was cut off where nobody chose (a capture stopped at a time limit): drop the unfinished
        line and the open report instead of decoding them as damage; returns the bytes dropped."""
        n = len(self._buf)
        self._buf = b""
        self._skipping = False
        self._report = None
        return n

    def flush(self) -> list[Item]:
        """End of input: decode a final unterminated line and return any open report."""
        out: list = []
        if self._buf:
            buf, self._buf = self._buf, b""
            self._lines_into(buf + b"\n", out)
        if self._report is not None and (self._report.has_content or self._report.closing is not None):
            out.append(self._emit_report())
        self._report = None
        expanded: list[Item] = []
        for item in out:
            expanded.extend(item.stamps() if type(item) is StampBatch else [item])
        return expanded

    def feed_lines(self, data: bytes) -> tuple[list, list]:
        """:meth:`feed` for a caller that interleaves the items with other input: returns the items
        (stamps as :class:`Stamp` or unmerged :class:`StampBatch` runs; merge with :meth:`merge`) and,
        for each, the index of the line that completed it among the lines this call completed (an int,
        or for a batch the range of its lines, ``(first, last + 1)``; one stamp per line)."""
        pos: list = []
        return self._decode(data, pos), pos

    def merge(self, items: list) -> list[StampBatch | Item]:
        """Runs of stamps among ``items`` (from :meth:`feed_lines`) merged into batches."""
        return self._batched(items)

    def _decode(self, data: bytes, pos: list | None = None) -> list:
        self.bytes_in += len(data)
        out: list = []
        buf = self._buf + bytes(data) if self._buf else bytes(data)
        if self._skipping:
            nl = buf.find(b"\n")
            if nl < 0:
                self._buf = b""
                return out
            self._skipping = False
            buf = buf[nl + 1 :]
        last = buf.rfind(b"\n")
        if last < 0:
            self._buf = self._cap(buf, out)
            if pos is not None:
                pos.extend([0] * len(out))
            return out
        self._buf = self._cap(buf[last + 1 :], out)
        if pos is not None:
            pos.extend([0] * len(out))
        self._lines_into(buf[: last + 1], out, pos)
        return out

    def _batched(self, items: list) -> list:
        """Merge runs of :class:`Stamp` and :class:`StampBatch` items into single batches."""
        if len(items) < 2:
            if not items or type(items[0]) is not Stamp:
                return items
        elif not any(type(i) is Stamp for i in items) and sum(type(i) is StampBatch for i in items) <= 1:
            return items
        out: list = []
        run: list = []

        def close() -> None:
            if not run:
                return
            if len(run) == 1 and type(run[0]) is StampBatch:
                out.append(run[0])
            else:
                ids, ts, bs = [], [], []
                for it in run:
                    if type(it) is StampBatch:
                        ids.append(it.ids)
                        ts.append(it.t_us)
                        bs.append(it.begin)
                    else:
                        ids.append(np.array([self._name_id(it.name.encode("latin-1"))], np.int32))
                        ts.append(np.array([it.t_us], np.int64))
                        bs.append(np.array([it.begin], bool))
                out.append(StampBatch(self.registry.snapshot(), np.concatenate(ids), np.concatenate(ts),
                                      np.concatenate(bs)))
            run.clear()

        for it in items:
            if type(it) is Stamp or type(it) is StampBatch:
                run.append(it)
            else:
                close()
                out.append(it)
        close()
        return out

    # ------------------------------------------------------------------ internals

    def _cap(self, rest: bytes, out: list) -> bytes:
        if len(rest) <= MAX_LINE:
            return rest
        self.lines += 1
        self.parse_errors += 1
        out.append(Problem(UNREADABLE, rest[:80], f"line longer than {MAX_LINE} bytes"))
        self._skipping = True
        return b""

    def _lines_into(self, chunk: bytes, out: list, pos: list | None = None) -> None:
        """Decode complete lines (``chunk`` ends with LF); with ``pos``, note each item's line index."""
        fast = _vector_parse(chunk) if chunk.count(b"\n") >= _MIN_VECTOR_LINES else None
        if fast is None:  # too few lines for numpy to pay off
            if pos is None:
                for line in chunk[:-1].split(b"\n"):
                    self._slow_line(line, out)
                return
            for i, line in enumerate(chunk[:-1].split(b"\n")):
                self._slow_line(line, out)
                pos.extend([i] * (len(out) - len(pos)))
            return
        starts, ends, ok, t_us, begin, name_start, name_end, word_edges = fast
        n = len(starts)
        self.lines += n
        if not ok.any():
            for i in range(n):
                self._other_line(chunk[starts[i] : ends[i]], out)
                if pos is not None:
                    pos.extend([i] * (len(out) - len(pos)))
            return
        ids = self._name_ids_for(chunk, name_start, name_end, ok)
        nwords = int(word_edges[ok].sum())
        nok = int(ok.sum())
        self.stamp_lines += nok
        self.dialects["branch"] += nwords
        self.dialects["thesis"] += nok - nwords
        bad = np.flatnonzero(~ok)
        if len(bad) == 0:
            out.append(StampBatch(self.registry.snapshot(), ids, t_us, begin))
            if pos is not None:
                pos.append((0, n))
            return
        # Interleave: runs of stamp lines between the other lines, in arrival order.
        prev = 0
        for i in bad.tolist():
            if i > prev:
                out.append(StampBatch(self.registry.snapshot(), ids[prev:i], t_us[prev:i], begin[prev:i]))
                if pos is not None:
                    pos.append((prev, i))
            self._other_line(chunk[starts[i] : ends[i]], out)
            if pos is not None:
                pos.extend([i] * (len(out) - len(pos)))
            prev = i + 1
        if prev < n:
            out.append(StampBatch(self.registry.snapshot(), ids[prev:], t_us[prev:], begin[prev:]))
            if pos is not None:
                pos.append((prev, n))

    def _name_ids_for(self, chunk: bytes, ns: np.ndarray, ne: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Decoder-wide name ids for the stamp lines (``ok``); other rows get 0 (unused)."""
        n = len(ns)
        ids = np.zeros(n, dtype=np.int32)
        length = ne - ns
        short = ok & (length <= 16)
        idx_short = np.flatnonzero(short)
        if len(idx_short):
            a = np.frombuffer(chunk + b"\0" * 16, dtype=np.uint8)
            s = ns[idx_short]
            ln = length[idx_short]
            cols = np.arange(16)
            gathered = a[s[:, None] + cols[None, :]]
            gathered[cols[None, :] >= ln[:, None]] = 0
            words = gathered.view(np.uint64)  # shape (m, 2); names hold no NUL, so zero padding is exact
            w0 = words[:, 0]
            w1 = words[:, 1]
            key = w0 ^ (w1 * np.uint64(0x9E3779B97F4A7C15))
            uniq, first, inv = np.unique(key, return_index=True, return_inverse=True)
            rep0, rep1 = w0[first], w1[first]
            if not (np.array_equal(rep0[inv], w0) and np.array_equal(rep1[inv], w1)):
                # A hash collision (never seen in practice): map name by name.
                lut_ids = [self._name_id(chunk[a0:b0]) for a0, b0 in zip(s.tolist(), (s + ln).tolist(),
                                                                          strict=True)]
                ids[idx_short] = lut_ids
            else:
                lut = np.empty(len(uniq), dtype=np.int32)
                key_ids = self._key_ids
                for j, (k0, k1, f) in enumerate(zip(rep0.tolist(), rep1.tolist(), first.tolist(), strict=True)):
                    nid = key_ids.get((k0, k1))
                    if nid is None:
                        start = int(s[f])
                        nid = self._name_id(chunk[start : start + int(ln[f])])
                        if len(key_ids) < 65536:
                            key_ids[(k0, k1)] = nid
                    lut[j] = nid
                ids[idx_short] = lut[inv.reshape(-1)]
        for i in np.flatnonzero(ok & (length > 16)).tolist():
            ids[i] = self._name_id(chunk[ns[i] : ne[i]])
        return ids

    def _name_id(self, raw: bytes) -> int:
        return self.registry.id_of(raw)

    def _slow_line(self, line: bytes, out: list) -> None:
        """Classify one line (no LF) on the reference path."""
        self.lines += 1
        if line.endswith(b"\r"):
            line = line[:-1]
        if line and line[-1] in _STAMP_LAST and line[0] != 0x40 and b"\t" not in line and not _LOG.match(line):
            m = _STAMP.fullmatch(line)
            if m is not None:
                self.stamp_lines += 1
                edge = m[3]
                self.dialects["branch" if len(edge) > 1 else "thesis"] += 1
                nid = self._name_id(m[1])
                out.append(Stamp(self.names[nid], int(m[2]), EDGE_TOKENS[edge]))
                return
        self._classified(line, out)

    def _other_line(self, line: bytes, out: list) -> None:
        """A line the vectorised path did not take as a stamp (no LF; already counted in ``lines``)."""
        if line.endswith(b"\r"):
            line = line[:-1]
        if line and line[-1] in _STAMP_LAST and line[0] != 0x40 and b"\t" not in line and not _LOG.match(line):
            m = _STAMP.fullmatch(line)
            if m is not None:  # e.g. a time with more digits than the fast path reads
                self.stamp_lines += 1
                edge = m[3]
                self.dialects["branch" if len(edge) > 1 else "thesis"] += 1
                out.append(Stamp(self.names[self._name_id(m[1])], int(m[2]), EDGE_TOKENS[edge]))
                return
        self._classified(line, out)

    def _classified(self, line: bytes, out: list) -> None:
        """Everything but stamps, with block context (§3.8 steps 1-4 and 6)."""
        if not line:
            self.blank_lines += 1
            return
        c = line[0]
        if c in b"=-":
            if _SEP_EQ.fullmatch(line):
                self.report_lines += 1
                self._equals(out)
                return
            if _SEP_DASH.fullmatch(line):
                self.report_lines += 1
                rep = self._open(out, implicit=True)
                rep.section = "tasks"
                return
        if b"\t" in line:
            row = _report_row(line)
            if row is None:
                self._error(line, "TAB-separated line that is no report row", out)
                return
            self.report_lines += 1
            kind, value = row
            rep = self._report
            if kind in ("free_heap", "ctx") and rep is not None and (rep.runtime or rep.tasks):
                # A new report began without the old one's closing line: hand the old one out as incomplete.
                opened = rep.sep_after_end
                out.append(self._emit_report())
                rep = self._open(out, implicit=not opened)
            if rep is None:
                rep = self._open(out, implicit=True)
            if kind == "free_heap":
                rep.free_heap = value
            elif kind == "ctx":
                rep.ctx = value
            elif kind == "rt_header":
                rep.pct = value
            elif kind == "task_header":
                rep.section = "tasks"
            elif kind == "rt_row":
                rep.runtime.append(value)
            else:
                rep.tasks.append(value)
            return
        m = _CLOSING.fullmatch(line) if line.endswith(b" us") else None
        if m:
            self.report_lines += 1
            rep = self._report or self._open(out, implicit=True)
            rep.closing = m[1].decode()
            rep.closing_us = int(m[2])
            if rep.has_content:  # (if the end separator was lost, the report is marked incomplete)
                out.append(self._emit_report())
            return
        m = _LOG.fullmatch(line) if 0x30 <= c <= 0x39 else None
        if m:
            self.log_lines += 1
            out.append(LogMessage(m[1].decode(), m[2].decode(), m[3].decode("latin-1")))
            return
        if c == 0x40:
            meta = _meta(line)
            if meta is not None:
                self.meta_lines += 1
                out.append(meta)
                return
        self._error(line, "not a stamp, log line or report line", out)

    def _error(self, line: bytes, reason: str, out: list) -> None:
        self.parse_errors += 1
        out.append(Problem(UNREADABLE, line, reason))  # positional: noise makes thousands per megabyte

    def _open(self, out: list, implicit: bool) -> _ReportBuilder:
        if self._report is None:
            self._report = _ReportBuilder(opened=not implicit)
        return self._report

    def _equals(self, out: list) -> None:
        rep = self._report
        if rep is None:
            self._report = _ReportBuilder(opened=True)
            return
        if not rep.has_content:
            rep.opened = True
            return
        if rep.section != "end":
            rep.section = "end"
            if rep.closing is not None:
                out.append(self._emit_report())
        else:
            # After the end and before the closing line: the thesis frames its closing line so, or the
            # closing line was lost and this opens the next block (decided by what follows).
            rep.sep_after_end = True

    def _emit_report(self) -> RuntimeReport:
        rep = self._report
        self._report = None
        self.reports += 1
        return rep.build()  # type: ignore[union-attr]


# --------------------------------------------------------------------------- vectorised stamp parsing

_MAX_DIGITS = 12
_POW10 = np.array([10**k for k in range(_MAX_DIGITS)], dtype=np.int64)
_MIN_VECTOR_LINES = 24


def _vector_parse(chunk: bytes):
    """Find the stamp lines of ``chunk`` (complete lines, ending in LF) with numpy.

    Returns ``(starts, ends, ok, t_us, begin, name_start, name_end, word_edges)``
    per line (``ends`` excludes LF, not CR); ``ok`` marks lines that are certainly
    stamps by §3.8. Lines not ``ok`` go through the per-line classifier, which
    also catches the rare stamp this path does not read (e.g. very long times).
    None when the chunk has too few lines to be worth it.
    """
    a = np.frombuffer(chunk, dtype=np.uint8)
    nl = np.flatnonzero(a == 10)
    n = len(nl)
    if n < _MIN_VECTOR_LINES:
        return None
    starts = np.empty(n, dtype=np.int64)
    starts[0] = 0
    starts[1:] = nl[:-1] + 1
    ends = nl.astype(np.int64)
    e = ends - (a[np.maximum(ends - 1, 0)] == 13) * (ends > starts)
    length = e - starts
    ok = length >= 5
    last = a[np.maximum(e - 1, 0)]
    m2 = a[np.maximum(e - 2, 0)]
    m3 = a[np.maximum(e - 3, 0)]
    is_digit_edge = (last == 0x31) | (last == 0x30)
    is_in = (last == 0x6E) & (m2 == 0x69)
    is_out = (last == 0x74) & (m2 == 0x75) & (m3 == 0x6F)
    tok = np.where(is_digit_edge, 1, np.where(is_in, 2, np.where(is_out, 3, 0)))
    ok &= tok > 0
    sp1 = np.maximum(e - tok - 1, 0)
    ok &= a[sp1] == 0x20
    val = np.zeros(n, dtype=np.int64)
    nd = np.zeros(n, dtype=np.int64)
    alive = ok.copy()
    for k in range(1, _MAX_DIGITS + 1):
        idx = sp1 - k
        alive &= idx > starts
        c = a[np.maximum(idx, 0)].astype(np.int64) - 48
        alive &= (c >= 0) & (c <= 9)
        if not alive.any():
            break
        val += np.where(alive, c, 0) * _POW10[k - 1]
        nd += alive
    ok &= (nd >= 1) & ~alive  # a digit run longer than _MAX_DIGITS goes the slow way
    sp2 = np.maximum(sp1 - nd - 1, 0)
    ok &= (a[sp2] == 0x20) & (sp2 > starts)
    tabs = np.concatenate(([0], np.cumsum(a == 9, dtype=np.int64)))
    ok &= tabs[e] == tabs[starts]
    first = a[np.minimum(starts, len(a) - 1)]
    ok &= first != 0x40  # '@' metadata lines
    # Possible log lines ("dd:dd:dd [") are left to the exact regex of the slow path.
    s2 = np.minimum(starts + 2, len(a) - 1)
    s5 = np.minimum(starts + 5, len(a) - 1)
    s9 = np.minimum(starts + 9, len(a) - 1)
    maybe_log = (a[s2] == 0x3A) & (a[s5] == 0x3A) & (a[s9] == 0x5B) & (length >= 10)
    ok &= ~maybe_log
    begin = is_digit_edge & (last == 0x31) | is_in
    return starts, ends, ok, val, begin, starts, sp2, tok > 1


def iter_stamps(items: Iterable[StampBatch | Item]) -> Iterator[Stamp]:
    """The stamps among decoded items, expanding batches."""
    for item in items:
        if type(item) is StampBatch:
            yield from item.stamps()
        elif type(item) is Stamp:
            yield item
