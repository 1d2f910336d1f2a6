"""Recording CAN traffic to python-can's log formats (``hilbench record SOURCE run.asc``, ``--record run.blf``).

A :class:`CanLogRecorder` takes the same chunks as the hilbench capture
writer (16-byte SocketCAN frame records with their time) and writes them with
python-can's own writers, chosen by suffix: ``.log`` (candump ``-L``, the
format the spec sheet recommends for hilbench's own recordings), ``.asc``,
``.blf``, ``.trc``, ``.csv`` (and ``.gz`` variants of the text formats).
Times are written as Unix time. Registered as the ``can`` recorder
(``hilbench.recorders`` entry point): it takes CAN sources whose file name
has one of those suffixes.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from hilbench.protocols import can_frame as cf

SUFFIXES = (".log", ".asc", ".blf", ".trc", ".csv")


def log_suffix(path: str) -> str:
    """A log's format suffix, lower case: ``.log`` for ``run.log`` and ``run.log.gz``."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return suffixes[-1] if suffixes else ""


def _logger(path: str) -> Any:
    """python-can's writer for ``path``'s format; a ``.gz`` name with more dots than ``run.log.gz`` (such as a
    running recording's ``run.partial.log.gz``) too, which ``can.Logger`` refuses."""
    import gzip

    import can

    writer = can.io.MESSAGE_WRITERS.get(log_suffix(path))
    if not path.lower().endswith(".gz") or writer is None or log_suffix(path) in (".blf", ".db"):
        return can.Logger(path)  # (python-can's own message for what it cannot write)
    binary = issubclass(writer, can.io.generic.BinaryIOMessageWriter)
    return writer(file=gzip.open(path, "wb" if binary else "wt"))


class CanLogRecorder:
    """Writes chunks of CAN frame records through python-can's ``can.Logger``."""

    def __init__(self, path: str, *, wall_offset: float = 0.0) -> None:

        self.path = path
        self.wall_offset = wall_offset
        self.logger = _logger(path)
        self.bytes = 0
        self.records = 0
        self.frames = 0
        self.lost = 0

    def chunk(self, chunk: Any) -> None:
        from hilbench.transports.can_messages import to_message

        if chunk.lost:
            self.lost += chunk.lost
            return
        frames, _rest = cf.split(chunk.data)
        self.records += 1
        self.bytes += len(chunk.data)
        t = chunk.t + self.wall_offset
        for frame in frames:
            self.logger.on_message_received(to_message(frame, timestamp=t, channel=0,
                                                       is_rx=not chunk.source.endswith(" tx")))
            self.frames += 1

    def flush(self) -> None:
        file = getattr(self.logger, "file", None)
        if file is not None and hasattr(file, "flush") and not getattr(file, "closed", False):
            file.flush()

    def close(self) -> None:
        self.logger.stop()


class CanLogFormat:
    """The recorder plug-in: python-can log formats for CAN sources."""

    name = "can"
    suffixes = SUFFIXES

    def accepts(self, path: str, protocol: str | None) -> bool:
        return protocol == "can" and log_suffix(path) in self.suffixes

    def open(self, path: str, *, source: Any, description: str = "") -> CanLogRecorder:
        offset = getattr(source, "wall_offset", None)
        if offset is None:
            info = getattr(getattr(source, "reader", None), "info", None) or \
                getattr(getattr(source, "parser", None), "info", None)
            if info is not None and info.measured and info.t0_wall:
                offset = info.t0_wall - info.t0_monotonic  # a hilbench capture or tap: its clock's Unix time
            elif source.live:
                offset = time.time() - time.monotonic()  # live sources stamp with the monotonic clock
            else:
                offset = 0.0
        return CanLogRecorder(path, wall_offset=offset)


RECORDER = CanLogFormat()

__all__ = ["RECORDER", "SUFFIXES", "CanLogFormat", "CanLogRecorder", "log_suffix"]
