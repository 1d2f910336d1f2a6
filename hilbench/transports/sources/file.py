"""Capture files and stdin: replayed as fast as possible or at their recorded speed."""

from __future__ import annotations

import os
import stat
import sys
from collections.abc import Iterator

from hilbench.transports.capture_file import CaptureReader
from hilbench.transports.chunk import CaptureError, Chunk, sound_quality
from hilbench.transports.sources.base import (
    ReplaySource,
    Source,
    SourceError,
    SourceOpener,
    SourceUnavailable,
)


class FileSource(ReplaySource):
    """A capture file (hilbench format or raw dump), replayed fast or at recorded speed.

    ``speed`` None replays as fast as possible; 1.0 at recorded speed, 2.0
    twice as fast. A raw dump has times only with ``baud`` (byte time).
    """

    def __init__(self, target, *, baud: int | None = None, speed: float | None = None) -> None:
        try:
            self.reader = CaptureReader(target, raw_baud=baud)
        except FileNotFoundError:
            raise SourceUnavailable(f"{target}: no such file") from None
        self.name = self.reader.name
        self.baud = self.reader.baud or baud
        info = self.reader.info
        self.protocol = (info.protocol or None) if info else None
        self.timestamps = self.reader.timestamps
        if speed is not None and (speed <= 0 or self.timestamps == "none"):
            self.reader.close()
            self.check_speed(speed)
            raise SourceError(f"{self.name}: a raw capture has no times; give --baud to replay it at wire speed")
        self._start_replay(speed)

    def quality(self) -> dict:
        return self.reader.parser.quality() if not self.reader.is_raw else sound_quality()

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        stop = self._stop
        try:
            for chunk in self.reader:
                if stop.is_set():
                    return
                if self.speed is not None and (yield from self._pace(chunk.t, idle)):
                    return
                yield chunk
        except OSError as exc:
            raise CaptureError(f"{self.name}: {exc}") from None

    def close(self) -> None:
        super().close()
        self.reader.close()


def open_stdin(spec: str, target: str, fragment: str, *, baud: int | None = None, speed: float | None = None,
               **_: object) -> Source:
    """stdin redirected from a file is replayed like that file; a pipe or terminal is live."""
    fd = sys.stdin.buffer.fileno()
    if stat.S_ISREG(os.fstat(fd).st_mode):  # `< file`: replay it like a named file
        return FileSource("-", baud=baud, speed=speed)
    from hilbench.transports.sources.stream import StreamSource

    return StreamSource(fd, name="stdin", baud=baud, own=False)


def open_file(spec: str, target: str, fragment: str, *, baud: int | None = None, speed: float | None = None,
              **_: object) -> Source:
    return FileSource(target, baud=baud, speed=speed)


FILE = SourceOpener("file", open_file, kinds=("file",), usage="capture.hbcap, trace.bin, trace.txt",
                    what="a file: a hilbench capture (times and directions kept) or raw bytes (a raw dump has no "
                         "times unless --baud gives it byte time)")
STDIN = SourceOpener("stdin", open_stdin, kinds=("stdin",), usage="-",
                     what="stdin: live from a pipe, or read like a file when redirected from one")

__all__ = ["FILE", "STDIN", "FileSource", "open_file", "open_stdin"]
