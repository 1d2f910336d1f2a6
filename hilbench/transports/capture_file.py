"""Reading and writing bus captures: the hilbench format, and raw byte dumps.

:class:`CaptureWriter` stores every chunk with its time and source in the
format of :mod:`hilbench.protocols.capture`; :class:`CaptureReader` reads it
back, or, when the file does not start with the format's magic, reads it as a
raw headerless dump (like the Wolfgang trace in tests/data): one source named
``bus``, no times, unless a baud rate is given, in which case each chunk is
stamped with the time its last byte would have taken on the wire ("byte
time", starting at 0).

Both work on paths and on binary file objects (``-`` is stdin or stdout), and
the reader on sockets too: it never asks for more bytes than are available, so
a live stream is decoded as it arrives. The reader feeds a
:class:`~hilbench.transports.capture_parser.CaptureParser`, which finds,
counts and survives damage.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from hilbench.protocols import capture as cap
from hilbench.protocols.capture import MAX_PAYLOAD, CaptureInfo, Flags, RecordKind
from hilbench.transports.capture_parser import READ_SIZE, CaptureParser
from hilbench.transports.chunk import CaptureError, Chunk


def _open_in(target: str | os.PathLike[str] | BinaryIO) -> tuple[BinaryIO, bool]:
    if isinstance(target, str | os.PathLike):
        if str(target) == "-":
            return sys.stdin.buffer, False
        return open(target, "rb"), True  # noqa: SIM115 (closed by the reader)
    return target, False


def _read_some(f: BinaryIO, n: int) -> bytes:
    """At most ``n`` bytes, without waiting for more than one read's worth (sockets, pipes)."""
    read1 = getattr(f, "read1", None)
    return read1(n) if read1 is not None else f.read(n)


def _timestamps(info: CaptureInfo | None, raw_baud: int | None) -> str:
    if info is None:
        return "synthetic" if raw_baud else "none"
    if info.measured:
        return "measured"
    return "synthetic" if info.synthetic else "none"


class CaptureReader:
    """Chunks of a hilbench capture or a raw dump, in order, from a path or a binary file.

    ``raw_baud`` gives raw dumps a byte-time clock. The header is read on
    construction (:attr:`info`, None for a raw dump). A record cut off by the
    end of the input (a recording that was killed) is counted in
    :attr:`truncated_bytes` instead of raising.
    """

    def __init__(self, target: str | os.PathLike[str] | BinaryIO, *, raw_baud: int | None = None) -> None:
        self.name = str(target) if isinstance(target, str | os.PathLike) else getattr(target, "name", "stream")
        self._f, self._owned = _open_in(target)
        self.parser = CaptureParser(raw_baud=raw_baud, name=self.name)
        self._early: list[Chunk] = []
        self._eof = False
        try:
            while not self.parser.decided:
                data = _read_some(self._f, READ_SIZE)
                if not data:
                    self._eof = True
                    if self.parser.mode == "header":
                        raise CaptureError(f"{self.name}: capture header cut short")
                    self._early += self.parser.finish()
                    break
                self._early += self.parser.feed(data)
        except BaseException:
            self.close()
            raise

    @property
    def info(self) -> CaptureInfo | None:
        return self.parser.info

    @property
    def is_raw(self) -> bool:
        """True for a headerless dump."""
        return self.parser.info is None

    @property
    def timestamps(self) -> str:
        """``measured``, ``synthetic`` (byte time) or ``none``."""
        return _timestamps(self.parser.info, self.parser.raw_baud)

    @property
    def baud(self) -> int | None:
        info = self.parser.info
        return info.baud if info is not None else self.parser.raw_baud

    @property
    def truncated_bytes(self) -> int:
        return self.parser.truncated_bytes

    def quality(self) -> dict:
        """Damage found so far (see :meth:`CaptureParser.quality`)."""
        return self.parser.quality()

    def __iter__(self) -> Iterator[Chunk]:
        early, self._early = self._early, []
        yield from early
        if self._eof:
            return
        parser = self.parser
        while True:
            data = _read_some(self._f, READ_SIZE)
            if not data:
                yield from parser.finish()
                return
            yield from parser.feed(data)

    def close(self) -> None:
        if self._owned:
            self._f.close()

    def __enter__(self) -> CaptureReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class CaptureWriter:
    """Writes chunks to a hilbench capture.

    Stored times count from ``t0`` (a ``time.monotonic()`` value; default: the
    time of the first chunk), so a recording of a live source replays with the
    original times. ``timestamps`` is ``measured``, ``synthetic`` or ``none``
    (then every time is stored as 0). ``t0_wall`` is the Unix time of ``t0``
    (default: ``t0 + wall_offset`` when the source says how its times map to
    Unix time, e.g. 0 for a CAN bus stamped in Unix time; else derived from
    the clocks now, right for sources stamped with ``time.monotonic()``). Sources
    get ids in order of appearance (at most 256).
    """

    def __init__(
        self,
        target: str | os.PathLike[str] | BinaryIO,
        *,
        baud: int | None = None,
        protocol: str | None = None,
        description: str = "",
        t0: float | None = None,
        t0_wall: float | None = None,
        timestamps: str = "measured",
        wall_offset: float | None = None,
    ) -> None:
        if timestamps not in ("measured", "synthetic", "none"):
            raise ValueError(f"timestamps must be measured, synthetic or none, not {timestamps!r}")
        if isinstance(target, str | os.PathLike):
            if str(target) == "-":
                self._f, self._owned = sys.stdout.buffer, False
            else:
                self._f, self._owned = open(Path(target), "wb"), True  # noqa: SIM115
        else:
            self._f, self._owned = target, False
        self.t0 = t0
        self.timed = timestamps != "none"
        self._flags = {"measured": Flags.MEASURED, "synthetic": Flags.SYNTHETIC, "none": 0}[timestamps]
        self._head = {"baud": baud, "protocol": protocol, "description": description, "t0_wall": t0_wall,
                      "wall_offset": wall_offset}
        self._ids: dict[str, int] = {}
        self.bytes = 0
        self.records = 0
        self._started = False

    def _start(self, t: float | None) -> None:
        """Write the header, fixing t0 (the first chunk's time unless given)."""
        self._started = True
        now_mono, now_wall = time.monotonic(), time.time()
        if self.t0 is None:
            self.t0 = t if (t is not None and self.timed) else now_mono
        wall = self._head["t0_wall"]
        if wall is None and self._head["wall_offset"] is not None:
            wall = self.t0 + self._head["wall_offset"]
        if wall is None:
            wall = now_wall - (now_mono - self.t0)
        self._f.write(
            cap.build_header(
                flags=self._flags,
                baud=self._head["baud"],
                t0_wall=wall,
                t0_monotonic=self.t0 if self.timed else 0.0,
                protocol=self._head["protocol"],
                description=self._head["description"],
            )
        )

    def _source_id(self, source: str) -> int:
        sid = self._ids.get(source)
        if sid is None:
            if len(self._ids) >= 256:
                raise CaptureError("a capture holds at most 256 sources")
            sid = self._ids[source] = len(self._ids)
            self._f.write(cap.pack_record(RecordKind.SOURCE, sid, 0, source.encode()[:MAX_PAYLOAD]))
        return sid

    def _t_ns(self, t: float) -> int:
        return round((t - self.t0) * 1e9) if self.timed else 0

    def write(self, t: float, source: str, data: bytes, addr: tuple[str, int, str, int] | None = None) -> None:
        """Store ``data`` from ``source`` at time ``t`` (split into records of at most 65535 bytes).

        ``addr`` (a datagram's source and destination) is stored in an ADDRESS record before the data.
        """
        if not self._started:
            self._start(t)
        sid = self._source_id(source)
        t_ns = self._t_ns(t)
        write = self._f.write
        if addr is not None:
            write(cap.address_record(sid, t_ns, addr))
        for i in range(0, len(data), MAX_PAYLOAD):
            write(cap.pack_record(RecordKind.DATA, sid, t_ns, data[i : i + MAX_PAYLOAD]))
            self.records += 1
        self.bytes += len(data)

    def gap(self, t: float, source: str, nbytes: int) -> None:
        """Note that ``nbytes`` of ``source`` were lost before reaching the recorder."""
        if not self._started:
            self._start(t)
        sid = self._source_id(source)
        self._f.write(cap.gap_record(sid, self._t_ns(t), nbytes))

    def chunk(self, chunk: Chunk) -> None:
        """Store a :class:`Chunk` (data or loss)."""
        if chunk.lost:
            self.gap(chunk.t, chunk.source, chunk.lost)
        else:
            self.write(chunk.t, chunk.source, chunk.data, chunk.addr)

    def flush(self) -> None:
        """Hand what was written to the system; a failed write (disk full) raises :class:`OSError`."""
        with contextlib.suppress(ValueError):  # closed already
            self._f.flush()

    def close(self) -> None:
        """Finish the file (a capture of nothing still gets its header)."""
        if self._f.closed:
            return
        if not self._started:
            self._start(None)
        self.flush()
        if self._owned:
            self._f.close()

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["CaptureReader", "CaptureWriter"]
