"""What every byte source is: a stream of timestamped chunks from one medium, and the in-process ones.

:class:`Source` is the interface the monitor, the recorder and the profiler
read; :class:`PushSource` turns callbacks into a source (bounded: overflow is
reported as a ``lost`` chunk); :class:`MediumSource` taps an in-process bench
medium; :class:`PeekedSource` replays chunks read ahead (to tell a protocol)
before the rest of its source. :class:`SourceOpener` is what a source plug-in
registers (``hilbench.sources`` entry points), see :func:`open_source
<hilbench.transports.sources.open_source>`.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import Any

from hilbench.errors import HilbenchError, UnavailableError
from hilbench.transports.chunk import Chunk, sound_quality


class SourceError(HilbenchError, ValueError):
    """A source string that cannot be opened; the message is one line. Exit status 2 (a malformed source, a
    file that is not a capture); :class:`SourceUnavailable` is what is not there or did not answer (1)."""

    exit_code = 2


class SourceUnavailable(SourceError, UnavailableError):
    """A source that is not there, is taken or did not answer: no such file or port, a refused connection,
    an address in use, a timeout (exit status 1)."""

    exit_code = 1


class Source:
    """Base class: a stream of chunks from one bus.

    Attributes: ``name`` (what was opened), ``baud`` (line rate if known),
    ``protocol`` (if known), ``timestamps`` (``measured``, ``synthetic`` or
    ``none``), ``live`` (data arrives as it happens).
    """

    name = "source"
    baud: int | None = None
    protocol: str | None = None
    timestamps = "measured"
    live = True
    #: ``(HOST:PORT, endpoint)``: the control channel of the bench whose endpoint this source watches (a
    #: manifest's tap sets it; the command line makes :attr:`bench_overflow` of it).
    bench_control: tuple[str, str] | None = None
    #: For a source that watches a bench's endpoint (a manifest's tap, ``bench:PROFILE``): asks that endpoint's
    #: overflow counters now (:mod:`hilbench.bench.overflow`; None: the bench no longer answers). None for any
    #: other source.
    bench_overflow: Callable[[], dict[str, Any] | None] | None = None

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        raise NotImplementedError

    def __iter__(self) -> Iterator[Chunk]:
        return (c for c in self.chunks() if c is not None)

    def clock(self) -> float | None:
        """The source's current time, or None if it has no clock (fast replay)."""
        return time.monotonic() if self.live else None

    def quality(self) -> dict[str, Any]:
        """Damage found in the input so far: counters and one-line ``findings`` (truncation, corruption,
        times out of order; see :class:`~hilbench.transports.capture_parser.CaptureParser`). Sources that
        carry no capture format have nothing to report."""
        return sound_quality()

    def close(self) -> None:
        """Stop the iteration (thread-safe) and release the source."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class ReplaySource(Source):
    """A recording replayed as fast as possible (``speed`` None) or at ``speed`` times its recorded pace.

    Subclasses call :meth:`_start_replay` in ``__init__`` and, in ``chunks()``, wait for each record with
    ``stopped = yield from self._pace(t, idle)`` (only when ``self.speed`` is set); :meth:`close` ends a wait.
    """

    live = False

    def _start_replay(self, speed: float | None) -> None:
        self.speed = speed
        self._stop = threading.Event()
        self._origin: tuple[float, float] | None = None  # (recording time, monotonic) at the first record

    @staticmethod
    def check_speed(speed: float | None) -> None:
        """Raise :class:`SourceError` unless ``speed`` is None or positive."""
        if speed is not None and speed <= 0:
            raise SourceError(f"replay speed must be positive, got {speed}")

    def clock(self) -> float | None:
        if self.speed is None or self._origin is None:
            return None
        t_rec, t_mono = self._origin
        return t_rec + (time.monotonic() - t_mono) * self.speed

    def _pace(self, t: float, idle: float | None) -> Generator[None, None, bool]:
        """Wait until recording time ``t`` is due, yielding None every ``idle`` s meanwhile; returns whether
        the source was closed during the wait."""
        if self._origin is None:
            self._origin = (t, time.monotonic())
        t_rec, t_mono = self._origin
        due = t_mono + (t - t_rec) / self.speed
        stop = self._stop
        while (wait := due - time.monotonic()) > 0:
            if idle is not None and wait > idle:
                if stop.wait(idle):
                    return True
                yield None
            elif stop.wait(wait):
                return True
        return False

    def close(self) -> None:
        self._stop.set()


class PushSource(Source):
    """A source fed by callbacks (:meth:`push`) from other threads, bounded in memory.

    Beyond ``max_bytes`` waiting, new data is dropped and reported as a loss
    chunk (``lost`` > 0) once the consumer catches up, so nothing is lost
    silently and a slow consumer cannot exhaust memory.
    """

    def __init__(self, name: str = "push", *, baud: int | None = None, max_bytes: int = 16 << 20) -> None:
        self.name = name
        self.baud = baud
        self.max_bytes = max_bytes
        self._q: collections.deque[Chunk] = collections.deque()
        self._bytes = 0
        self._lost: dict[str, int] = {}
        #: Bytes dropped beyond ``max_bytes`` so far (reported in the stream as loss chunks too).
        self.lost_bytes = 0
        self._cond = threading.Condition()
        self._closed = False

    def push(self, t: float, source: str, data: bytes, addr: tuple[str, int, str, int] | None = None) -> None:
        """Queue one chunk (a :data:`~hilbench.transports.serial_medium.Tap` signature; a datagram
        medium also passes the datagram's addresses)."""
        with self._cond:
            if self._closed:
                return
            if self._bytes + len(data) > self.max_bytes:
                self._lost[source] = self._lost.get(source, 0) + len(data)
                self.lost_bytes += len(data)
                return
            if self._lost:
                for src, n in self._lost.items():
                    self._q.append(Chunk(t, src, b"", n))
                self._lost.clear()
            self._q.append(Chunk(t, source, bytes(data), 0, addr))
            self._bytes += len(data)
            self._cond.notify()

    def end(self) -> None:
        """No more data will come: the iteration ends after what is queued."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        q = self._q
        while True:
            with self._cond:
                if not q and not self._closed:
                    self._cond.wait(idle if idle is not None else 0.5)
                if not q:
                    if self._closed:
                        return
                    if idle is not None:
                        batch = None
                    else:
                        continue
                else:
                    batch = list(q)
                    q.clear()
                    self._bytes = 0
            if batch is None:
                yield None
            else:
                yield from batch

    def close(self) -> None:
        self.end()


class MediumSource(PushSource):
    """Taps an in-process medium (a bench endpoint's line); ``protocol`` is what it carries, if known."""

    def __init__(self, medium, *, protocol: str | None = None, **kwargs) -> None:
        super().__init__(kwargs.pop("name", f"bench line {medium.name}"), baud=medium.baud, **kwargs)
        self.protocol = protocol if protocol is not None else getattr(medium, "protocol", None)
        self._medium = medium
        medium.add_tap(self.push)

    def clock(self) -> float | None:
        """The medium's time (its bench's clock), so monitors judge silence in the time its stamps are in."""
        clock = getattr(self._medium, "clock", None)
        return clock.now() if clock is not None else super().clock()

    @property
    def wall_offset(self) -> float | None:
        """Unix time minus the medium's time (recorders stamp Unix time with it)."""
        clock = getattr(self._medium, "clock", None)
        return clock.wall(0.0) if clock is not None else None

    def close(self) -> None:
        self._medium.remove_tap(self.push)
        super().close()


class PeekedSource(Source):
    """A source whose first chunks were read ahead (to tell its protocol); they come again first.

    Everything else (name, baud, times, clock, close) is the wrapped source's.
    """

    def __init__(self, source: Source, early: list[Chunk | None], rest: Iterator[Chunk | None],
                 protocol: str | None = None) -> None:
        self.source = source
        self._early = early
        self._rest = rest
        self._protocol = protocol

    def __getattr__(self, key: str) -> Any:
        return getattr(self.__dict__["source"], key)

    @property
    def name(self) -> str:  # type: ignore[override]
        return self.source.name

    @property
    def baud(self) -> int | None:  # type: ignore[override]
        return self.source.baud

    @baud.setter
    def baud(self, value: int | None) -> None:
        self.source.baud = value

    @property
    def protocol(self) -> str | None:  # type: ignore[override]
        return self._protocol or self.source.protocol

    @property
    def timestamps(self) -> str:  # type: ignore[override]
        return self.source.timestamps

    @property
    def live(self) -> bool:  # type: ignore[override]
        return self.source.live

    def clock(self) -> float | None:
        return self.source.clock()

    def quality(self) -> dict[str, Any]:
        return self.source.quality()

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        early, self._early = self._early, []
        yield from (c for c in early if c is not None or idle is not None)
        for chunk in self._rest:
            if chunk is None and idle is None:
                continue
            yield chunk

    def close(self) -> None:
        self.source.close()


def peek(source: Source, *, min_bytes: int = 256, max_bytes: int = 8192, timeout: float | None = 2.0,
         idle: float = 0.05) -> tuple[bytes, PeekedSource]:
    """Read ahead: the first bytes of ``source`` and a source that yields them again first.

    Reading stops at ``min_bytes``, when a live source goes quiet after some
    traffic, when it ends, or after ``timeout`` s (None: no limit; closing the
    source also ends the wait). At most ``max_bytes`` are returned.
    """
    it = source.chunks(idle)
    early: list[Chunk | None] = []
    got = bytearray()
    deadline = None if timeout is None else time.monotonic() + timeout
    for chunk in it:
        early.append(chunk)
        if chunk is None:
            if got:
                break  # quiet after some traffic: that is what there is for now
        elif chunk.data:
            got += chunk.data
        if len(got) >= min_bytes:
            break
        if deadline is not None and time.monotonic() >= deadline:
            break
    return bytes(got[:max_bytes]), PeekedSource(source, early, it)


@dataclass(frozen=True)
class SourceOpener:
    """A kind of source, as a plug-in registers it (``hilbench.sources`` entry point).

    ``open(spec, target, fragment, **options)`` makes the source: ``spec`` is the
    whole string, ``target`` the part an opener reads (a path, or the URL),
    ``fragment`` what followed ``#``; ``options`` are ``baud``, ``speed`` and
    ``default_baud`` (an opener ignores what it does not use). An opener is
    found by URL scheme (``schemes``), by file suffix (``suffixes``), by the
    first bytes of a regular file whose suffix no opener claims (``sniff``:
    given up to :data:`SNIFF_SIZE` bytes, whether the opener reads that file)
    or by the kind of file (``kinds``: ``"stdin"`` for ``-``, ``"char"`` for a
    character device, ``"fifo"``, ``"file"`` for any other regular file).
    ``usage`` and ``what`` make its row of the table in ``hilbench monitor --help``.
    """

    name: str
    open: Callable[..., Source]
    schemes: tuple[str, ...] = ()
    suffixes: tuple[str, ...] = ()
    kinds: tuple[str, ...] = ()
    usage: str = ""
    what: str = ""
    sniff: Callable[[bytes], bool] | None = None


#: Bytes of a file an opener's ``sniff`` sees.
SNIFF_SIZE = 4096

__all__ = ["SNIFF_SIZE", "Chunk", "MediumSource", "PeekedSource", "PushSource", "ReplaySource", "Source", "SourceError",
           "SourceOpener", "SourceUnavailable", "peek"]
