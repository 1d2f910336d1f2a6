"""Stamps on one timeline: unwrapping, sampling windows, arrival order, bounded storage.

Text stamp times are raw: t_us = floor(cycles / 216) with a 32-bit cycle
counter, so they return to 0 after 2^32 / 216 = 19,884,107.85 µs (spec sheet
§3.3). :class:`Timeline` extends them by the nearest-value rule (a step back
of more than half the range is a wrap, a step forward of more than half is a
late stamp from before the last wrap), with at most 1 µs of truncation error.
Binary stamps arrive already extended by their decoder; the same rule leaves
them unchanged.

**Windows.** A board samples in windows (a button press, §3.6), and each
window starts its clock again. A new window (a *segment* here) begins at the
first stamp after a run-time report or a binary WINDOW_START, or where time
jumps back by more than the reorder window to near zero without either (a
*backward jump*, counted). Windows are laid end to end on one timeline
(``t`` is the window's own time plus the end of the previous window), and no
interval or period ever spans two of them.

**Order.** Stamps are kept in arrival order; the analysis sorts them by
(t, arrival). Stamps earlier than one already seen are counted as out of
order; those later than the reorder window are counted as late (a live
reorder buffer of that size would have misplaced them).

Storage is columnar numpy arrays grown by doubling, bounded by
``max_stamps``: beyond it, the oldest quarter is discarded and counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: DWT CYCCNT at 216 MHz: 2^32 cycles wrap after 2^32 / 216 µs (§3.3).
CYCLES_WRAP = 1 << 32
CYCLES_PER_US = 216
WRAP_US = CYCLES_WRAP / CYCLES_PER_US
HALF_WRAP_US = WRAP_US / 2


@dataclass
class Segment:
    """One sampling window: where it lies on the timeline and what closed it."""

    index: int
    reason: str  # "start", "report", "window_start" or "time_reset"
    offset: int = 0  # added to the window's own times
    first_local: int | None = None
    t_first: int | None = None  # global
    t_last: int | None = None
    stamps: int = 0
    wraps: int = 0
    drops: int = 0  # binary DROPS in this window
    report: object = None  # the RuntimeReport printed after it, if any
    drop_marks: list[tuple[int, int]] = field(default_factory=list)  # (global t, count)


class _Columns:
    """Growable columns: t (int64), id (int32), begin (bool), seg (int32)."""

    def __init__(self, capacity: int = 1 << 14) -> None:
        self.n = 0
        self.t = np.empty(capacity, np.int64)
        self.id = np.empty(capacity, np.int32)
        self.begin = np.empty(capacity, bool)
        self.seg = np.empty(capacity, np.int32)

    def append(self, t, ids, begin, seg: int) -> None:
        m = len(t)
        need = self.n + m
        if need > len(self.t):
            cap = max(need, 2 * len(self.t))
            for name in ("t", "id", "begin", "seg"):
                old = getattr(self, name)
                new = np.empty(cap, old.dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
        s = slice(self.n, need)
        self.t[s] = t
        self.id[s] = ids
        self.begin[s] = begin
        self.seg[s] = seg
        self.n = need

    def drop_front(self, k: int) -> None:
        n = self.n - k
        for name in ("t", "id", "begin", "seg"):
            a = getattr(self, name)
            a[:n] = a[k : self.n]
        self.n = n


class Timeline:
    """Stamps of one stream, unwrapped, split into windows, in arrival order."""

    def __init__(self, reorder_us: float = 500_000, max_stamps: int = 20_000_000) -> None:
        self.reorder_us = reorder_us
        self.max_stamps = max_stamps
        self.cols = _Columns()
        self.segments: list[Segment] = [Segment(0, "start")]
        self.discarded = 0  # stamps dropped from the front (memory bound)
        self.out_of_order = 0
        self.late = 0  # later than the reorder window
        self.backward_jumps = 0  # unannounced time resets (new windows)
        self.global_end = 0  # max global t so far
        self._pending: str | None = None  # reason of the next window, once stamps come
        # Unwrap state of the current window.
        self._prev_raw: int | None = None
        self._epoch = 0
        self._run_max: int | None = None  # local

    # ------------------------------------------------------------------ window boundaries

    @property
    def segment(self) -> Segment:
        return self.segments[-1]

    def new_window(self, reason: str) -> None:
        """The next stamps start a new window (a report was printed, or WINDOW_START)."""
        if self.segment.stamps:
            self._pending = reason

    def attach_report(self, report) -> None:
        self.segment.report = report
        self.new_window("report")

    def add_drops(self, count: int, t_local: int | None = None) -> None:
        """Stamps the board reported lost (binary DROPS), at the stream time ``t_local`` if known."""
        seg = self.segment
        seg.drops += count
        if t_local is not None and seg.first_local is not None:
            t = int(t_local) + seg.offset
        else:
            t = seg.t_last if seg.t_last is not None else self.global_end
        seg.drop_marks.append((t, count))

    def _open(self, reason: str, first_local: int) -> None:
        offset = self.global_end - min(0, first_local)
        if self.segment.stamps == 0 and self.segment.report is None:
            seg = self.segment  # reuse the empty window
            seg.reason = reason if seg.index else seg.reason
            seg.offset = offset if seg.index else seg.offset
        else:
            seg = Segment(len(self.segments), reason, offset=offset)
            self.segments.append(seg)
        self._prev_raw = None
        self._epoch = 0
        self._run_max = None
        self._pending = None

    # ------------------------------------------------------------------ stamps

    @property
    def count(self) -> int:
        return self.cols.n

    def add(self, ids: np.ndarray, raw_t: np.ndarray, begin: np.ndarray) -> None:
        """Append stamps in arrival order (``raw_t`` as decoded)."""
        raw = np.asarray(raw_t, dtype=np.int64)
        ids = np.asarray(ids)
        begin = np.asarray(begin)
        while len(raw):
            if self._pending is not None:
                self._open(self._pending, int(raw[0]))
            cut = self._add_run(ids, raw, begin)
            if cut >= len(raw):
                break
            # A backward jump to near zero with no announcement: a new window.
            self.backward_jumps += 1
            self._open("time_reset", int(raw[cut]))
            ids, raw, begin = ids[cut:], raw[cut:], begin[cut:]
        if self.cols.n > self.max_stamps:
            k = self.cols.n - (self.max_stamps * 3) // 4
            self.cols.drop_front(k)
            self.discarded += k

    def _add_run(self, ids, raw, begin) -> int:
        """Add stamps up to (not including) the first time reset; return how many were taken."""
        n = len(raw)
        prev = np.empty(n, dtype=np.int64)
        prev[0] = raw[0] if self._prev_raw is None else self._prev_raw
        prev[1:] = raw[:-1]
        d = raw - prev
        step = (d < -HALF_WRAP_US).astype(np.int64) - (d > HALF_WRAP_US)
        epoch = self._epoch + np.cumsum(step)
        local = raw + (epoch * CYCLES_WRAP) // CYCLES_PER_US if (epoch.any()) else raw.copy()
        run0 = local[0] if self._run_max is None else self._run_max
        runmax = np.maximum.accumulate(np.concatenate(([run0], local)))
        back = runmax[:-1] - local
        resets = np.flatnonzero((back > self.reorder_us) & (local < self.reorder_us))
        cut = int(resets[0]) if len(resets) else n
        if cut == 0:
            return 0
        if cut < n:
            local, epoch, back = local[:cut], epoch[:cut], back[:cut]
            ids, begin = ids[:cut], begin[:cut]
        seg = self.segment
        self.out_of_order += int(np.count_nonzero(back > 0))
        self.late += int(np.count_nonzero(back > self.reorder_us))
        if seg.first_local is None:
            seg.first_local = int(local[0])
        g = local + seg.offset
        self.cols.append(g, ids, begin, seg.index)
        gmin = int(g.min())
        gmax = int(g.max())
        seg.t_first = gmin if seg.t_first is None else min(seg.t_first, gmin)
        seg.t_last = gmax if seg.t_last is None else max(seg.t_last, gmax)
        seg.stamps += cut
        seg.wraps = max(seg.wraps, int(epoch.max()))
        self.global_end = max(self.global_end, gmax)
        self._prev_raw = int(raw[cut - 1])
        self._epoch = int(epoch[-1])
        self._run_max = int(runmax[cut])
        return cut

    # ------------------------------------------------------------------ reading

    def columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Views of (t, id, begin, seg) in arrival order (valid until the next :meth:`add`)."""
        c = self.cols
        n = c.n
        return c.t[:n], c.id[:n], c.begin[:n], c.seg[:n]

    @property
    def wraps(self) -> int:
        return sum(s.wraps for s in self.segments)
