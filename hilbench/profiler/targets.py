"""The trace profiler as a fuzz target (:mod:`hilbench.fuzzing`): decode, store and analyse."""

from __future__ import annotations

from hilbench.fuzzing import FuzzTarget
from hilbench.profiler.ingest import Profiler
from hilbench.protocols.tracestamp_targets import BOARD_LINE, stream_traffic


class _ProfilerReader:
    def __init__(self) -> None:
        self.profiler = Profiler()
        self.analysis = None

    def feed(self, data: bytes) -> None:
        self.profiler.feed(data)

    def finish(self) -> None:
        self.profiler.finish()
        self.analysis = self.profiler.analyse()  # the statistics must survive whatever was decoded

    def good(self) -> int:
        d = self.profiler.decoder
        return d.text.stamp_lines + d.words.stamps

    def dropped(self) -> int:
        d = self.profiler.decoder
        return d.text.parse_errors + d.words.broken_words


PROFILER = FuzzTarget("profiler", "trace profiler (hilbench trace: decode, pair, analyse)", _ProfilerReader,
                         BOARD_LINE, "12.5 Mbit/s UART", stream_traffic, kind="instrument")

__all__ = ["PROFILER"]
