"""The profiler's front end: bytes or decoded items in, a :class:`~hilbench.profiler.timeline.Timeline` and counters out.

:class:`Profiler` owns one :class:`~hilbench.protocols.tracestamp_stream.StreamDecoder`
(text and binary stamps mixed with logs and run-time reports on one port) and
keeps everything the analysis needs: the stamps (unwrapped, per window), the
reports, binary markers and the decoders' counters. :meth:`Profiler.analyse`
runs the statistics on what has arrived so far, so a live view calls it as
often as it likes.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from hilbench.profiler.settings import ProfilerSettings
from hilbench.profiler.timeline import Timeline
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp import UNREADABLE, LogMessage, RuntimeReport, Stamp, StampBatch
from hilbench.protocols.tracestamp_binary import Marker
from hilbench.protocols.tracestamp_stream import StreamDecoder

#: Unreadable lines the quality report quotes (the first ones; the count is exact).
FIRST_BAD_LINES = 5


class Profiler:
    """Feed it a board's output; ask it for an :class:`~hilbench.profiler.analysis.Analysis`.

    >>> p = Profiler()
    >>> p.feed(b"IDLE 0 out\\nwheel_ctrl 0 in\\nwheel_ctrl 10 out\\nIDLE 10 in\\n")
    >>> p.finish()
    >>> p.analyse().tasks["wheel_ctrl"]["total_us"]
    10
    """

    def __init__(self, settings: ProfilerSettings | None = None) -> None:
        self.settings = settings or ProfilerSettings()
        self.decoder = StreamDecoder()
        self.timeline = Timeline(self.settings.reorder_us, self.settings.max_stamps)
        self.reports: list[tuple[int, RuntimeReport]] = []  # (window index, report)
        self.log_lines: deque[LogMessage] = deque(maxlen=50)
        self.bad_lines: deque[Problem] = deque(maxlen=20)  # the latest unreadable lines
        self.first_bad_lines: list[Problem] = []  # the first ones (what a damaged start looked like)
        self.word_problems: dict[str, int] = {}
        self.windows_started = 0
        self.windows_stopped = 0
        self.finished = False
        #: Bytes of a line, word or report cut in two where the reading stopped (see :meth:`finish`), and of
        #: the unreadable first line of a stream joined mid-line (see :meth:`feed_items`).
        self.cut_bytes = 0
        self._joining = self.settings.joined_mid_stream  # the first line may be the tail of one

    @property
    def names(self) -> list[str]:
        """Name table the stamp ids index (shared by text and binary)."""
        return self.decoder.names

    # ------------------------------------------------------------------ input

    def feed(self, data: bytes) -> None:
        """Decode a chunk of the stream (any size, any split) and take in what it holds."""
        self.feed_items(self.decoder.feed_batch(data))

    def finish(self, *, cut: bool = False) -> None:
        """End of the stream: decode what the decoders still hold.

        ``cut``: the reader stopped (``--duration``, ``--reports``, Ctrl-C) rather than the stream ending, so
        a line, word or report it cut in two is dropped (:attr:`cut_bytes`), not counted as damage.
        """
        if not self.finished:
            if cut:
                self.cut_bytes += self.decoder.cut()
            self.feed_items(self.decoder.flush())
            self.finished = True

    def feed_items(self, items: Iterable) -> None:
        """Take in decoded items (as :meth:`StreamDecoder.feed_batch` returns them).

        Stamps reach the timeline in arrival order; runs of them separated only by items that do not
        touch the timeline (damaged lines and words, logs, name-table lines) are joined into one call
        (noise makes thousands of tiny runs per chunk).

        A stream joined mid-line (``settings.joined_mid_stream``: a live port or a bench's tap) begins with
        the tail of a line the board wrote before the reading started: an unreadable first line is that cut,
        counted in :attr:`cut_bytes`, not damage (as the line :meth:`finish` cuts at the other end).
        """
        tl = self.timeline
        registry = self.decoder.registry
        stamps: list[Stamp] = []
        batches: list[StampBatch] = []
        for item in items:
            kind = type(item)
            if self._joining:
                self._joining = False
                if kind is Problem and item.kind == UNREADABLE and self._joined_mid_line(item):
                    continue
            if kind is Stamp:
                if batches:
                    self._add_batches(batches)
                    batches = []
                stamps.append(item)
                continue
            if kind is StampBatch:
                if stamps:
                    self._add_stamps(stamps, registry)
                    stamps = []
                batches.append(item)
                continue
            if kind is LogMessage:
                self.log_lines.append(item)
                continue
            if kind is Problem:
                if item.kind == UNREADABLE:
                    self.bad_lines.append(item)
                    if len(self.first_bad_lines) < FIRST_BAD_LINES:
                        self.first_bad_lines.append(item)
                else:  # damaged binary words
                    self.word_problems[item.kind] = self.word_problems.get(item.kind, 0) + item.count
                continue
            if stamps:
                self._add_stamps(stamps, registry)
                stamps = []
            if batches:
                self._add_batches(batches)
                batches = []
            if kind is RuntimeReport:
                self.reports.append((tl.segment.index, item))
                tl.attach_report(item)
            elif kind is Marker:
                if item.kind == "drops":
                    tl.add_drops(item.value, item.t_us)
                elif item.kind == "window_start":
                    self.windows_started += 1
                    tl.new_window("window_start")
                elif item.kind == "window_stop":
                    self.windows_stopped += 1
        if stamps:
            self._add_stamps(stamps, registry)
        if batches:
            self._add_batches(batches)

    def _joined_mid_line(self, problem: Problem) -> bool:
        """Count the unreadable first line of a stream joined mid-line as cut; False if it is no such line."""
        text = self.decoder.text
        if text.parse_errors < 1 or text.lines < 1:
            return False
        text.parse_errors -= 1
        text.lines -= 1
        self.cut_bytes += len(problem.raw) + 1  # (and its LF)
        return True

    def _add_batches(self, batches: list[StampBatch]) -> None:
        if len(batches) == 1:
            b = batches[0]
            self.timeline.add(b.ids, b.t_us, b.begin)
        else:
            self.timeline.add(np.concatenate([b.ids for b in batches]), np.concatenate([b.t_us for b in batches]),
                              np.concatenate([b.begin for b in batches]))

    def _add_stamps(self, stamps: list[Stamp], registry) -> None:
        ids = np.fromiter((registry.id_of_str(s.name) for s in stamps), np.int32, len(stamps))
        t = np.fromiter((s.t_us for s in stamps), np.int64, len(stamps))
        b = np.fromiter((s.begin for s in stamps), bool, len(stamps))
        self.timeline.add(ids, t, b)

    # ------------------------------------------------------------------ output

    def analyse(self, settings: ProfilerSettings | None = None, *, last_us: float | None = None):
        """Statistics of everything so far (``settings`` overrides the profiler's own).

        ``last_us`` restricts the analysis to the last that many µs of the
        timeline (the live view's window).
        """
        from hilbench.profiler.analysis import analyse

        return analyse(self, settings or self.settings, last_us=last_us)


def analyse_bytes(data: bytes, settings: ProfilerSettings | None = None, chunk: int = 1 << 20):
    """Analyse a complete capture held in memory."""
    p = Profiler(settings)
    for i in range(0, len(data), chunk):
        p.feed(data[i : i + chunk])
    p.finish()
    return p.analyse()
