"""Byte sources for instruments: where bus traffic comes from, as timestamped chunks.

Every source yields :class:`~hilbench.transports.capture_file.Chunk` s
``(t, source, data)``: the bytes one party put on the bus, complete at time
``t`` (seconds, ``time.monotonic()`` for live data, the recording's own clock
for captures). The monitor, the recorder and the trace profiler consume
sources the same way:

=================================  ==================================================
source string                      what it opens
=================================  ==================================================
``capture.hbcap``, ``trace.bin``   a capture file: hilbench format, or a raw dump
``-``                              the same, read from stdin
``/dev/ttyUSB0``                   a serial port, receive-only (sniffing a bus)
``serial:///dev/ttyUSB0?baud=N``   the same with its baud rate in the URL
``tcp://127.0.0.1:PORT``           a bench's tap server (capture format over TCP)
``manifest.json[#endpoint]``       the tap server of a running ``hilbench emulate``
=================================  ==================================================

In-process benches are tapped with :class:`MediumSource`, and
:class:`PushSource` turns any callback (a pty proxy, a test) into a source.

``Source.chunks(idle)`` yields ``None`` after ``idle`` seconds without data
(live sources only), so a consumer can advance its clock (``Source.clock()``)
while the bus is quiet. ``close()`` ends the iteration from another thread.
"""

from __future__ import annotations

import collections
import json
import os
import select
import socket
import stat
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from hilbench.transports.capture_file import CaptureError, CaptureParser, CaptureReader, Chunk

__all__ = [
    "Chunk",
    "FileSource",
    "MediumSource",
    "PushSource",
    "SerialSource",
    "Source",
    "SourceError",
    "TcpSource",
    "open_source",
]


class SourceError(ValueError):
    """A source string that cannot be opened; the message is one line."""


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

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        raise NotImplementedError

    def __iter__(self) -> Iterator[Chunk]:
        return (c for c in self.chunks() if c is not None)

    def clock(self) -> float | None:
        """The source's current time, or None if it has no clock (fast replay)."""
        return time.monotonic() if self.live else None

    def close(self) -> None:
        """Stop the iteration (thread-safe) and release the source."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class FileSource(Source):
    """A capture file (hilbench format or raw dump), replayed fast or at recorded speed.

    ``speed`` None replays as fast as possible; 1.0 at recorded speed, 2.0
    twice as fast. A raw dump has times only with ``baud`` (byte time).
    """

    live = False

    def __init__(self, target, *, baud: int | None = None, speed: float | None = None) -> None:
        try:
            self.reader = CaptureReader(target, raw_baud=baud)
        except FileNotFoundError:
            raise SourceError(f"{target}: no such file") from None
        self.name = self.reader.name
        self.baud = self.reader.baud or baud
        info = self.reader.info
        self.protocol = (info.protocol or None) if info else None
        self.timestamps = self.reader.timestamps
        if speed is not None and (speed <= 0 or self.timestamps == "none"):
            self.reader.close()
            if speed <= 0:
                raise SourceError(f"replay speed must be positive, got {speed}")
            raise SourceError(f"{self.name}: a raw capture has no times; give --baud to replay it at wire speed")
        self.speed = speed
        self._stop = threading.Event()
        self._origin: tuple[float, float] | None = None  # (capture time, monotonic) at the start

    def clock(self) -> float | None:
        if self.speed is None or self._origin is None:
            return None
        t_cap, t_mono = self._origin
        return t_cap + (time.monotonic() - t_mono) * self.speed

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        stop = self._stop
        try:
            for chunk in self.reader:
                if stop.is_set():
                    return
                if self.speed is not None:
                    if self._origin is None:
                        self._origin = (chunk.t, time.monotonic())
                    t_cap, t_mono = self._origin
                    due = t_mono + (chunk.t - t_cap) / self.speed
                    while True:
                        wait = due - time.monotonic()
                        if wait <= 0:
                            break
                        if idle is not None and wait > idle:
                            if stop.wait(idle):
                                return
                            yield None
                        elif stop.wait(wait):
                            return
                yield chunk
        except OSError as exc:
            raise CaptureError(f"{self.name}: {exc}") from None

    def close(self) -> None:
        self._stop.set()
        self.reader.close()


class SerialSource(Source):
    """A serial port opened receive-only with pyserial: a sniffer on a bus (never writes)."""

    def __init__(self, port: str, baud: int | None = None, *, read_timeout: float = 0.02) -> None:
        import serial  # pyserial; imported here so captures can be read without it

        self.name = port
        self.baud = baud or 57_600
        try:
            self._ser = serial.serial_for_url(port, baudrate=self.baud, timeout=read_timeout)
        except (serial.SerialException, ValueError) as exc:
            raise SourceError(f"cannot open {port}: {exc}") from None
        self._stop = threading.Event()

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        ser = self._ser
        last = time.monotonic()
        while not self._stop.is_set():
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (OSError, TypeError, AttributeError):
                if self._stop.is_set():
                    return  # closed under us
                raise
            now = time.monotonic()
            if data:
                last = now
                yield Chunk(now, "bus", data)
            elif idle is not None and now - last >= idle:
                last = now
                yield None

    def close(self) -> None:
        self._stop.set()
        try:
            self._ser.close()
        except Exception:  # noqa: BLE001 (closing is best effort)
            pass


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
        self._cond = threading.Condition()
        self._closed = False

    def push(self, t: float, source: str, data: bytes) -> None:
        """Queue one chunk (a :data:`~hilbench.transports.serial_medium.Tap` signature)."""
        with self._cond:
            if self._closed:
                return
            if self._bytes + len(data) > self.max_bytes:
                self._lost[source] = self._lost.get(source, 0) + len(data)
                return
            if self._lost:
                for src, n in self._lost.items():
                    self._q.append(Chunk(t, src, b"", n))
                self._lost.clear()
            self._q.append(Chunk(t, source, bytes(data)))
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
    """Taps an in-process :class:`~hilbench.transports.serial_medium.SerialMedium` (a bench's line)."""

    def __init__(self, medium, **kwargs) -> None:
        super().__init__(kwargs.pop("name", f"bench line {medium.name}"), baud=medium.baud, **kwargs)
        self.protocol = "dynamixel"
        self._medium = medium
        medium.add_tap(self.push)

    def close(self) -> None:
        self._medium.remove_tap(self.push)
        super().close()


class TcpSource(Source):
    """A bench's tap server (``tcp://127.0.0.1:PORT``): a live capture stream over TCP."""

    def __init__(self, host: str, port: int, *, name: str | None = None, timeout: float = 5.0) -> None:
        self.name = name or f"tcp://{host}:{port}"
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as exc:
            raise SourceError(f"cannot connect to {self.name}: {exc.strerror or exc}") from None
        self._stop = threading.Event()
        self.parser = CaptureParser(name=self.name)
        self._early: list[Chunk] = []
        try:
            while not self.parser.decided:
                data = self._sock.recv(65536)
                if not data:
                    break
                self._early += self.parser.feed(data)
        except OSError as exc:
            self._sock.close()
            raise SourceError(f"{self.name}: {exc}") from None
        if self.parser.info is None:
            self._sock.close()
            raise SourceError(f"{self.name} does not speak the hilbench capture format")
        self._sock.settimeout(None)
        self.baud = self.parser.info.baud
        self.protocol = self.parser.info.protocol or None

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        early, self._early = self._early, []
        yield from early
        sock = self._sock
        parser = self.parser
        while not self._stop.is_set():
            try:
                ready = select.select([sock], [], [], idle if idle is not None else 0.5)[0]
                if not ready:
                    if idle is not None:
                        yield None
                    continue
                data = sock.recv(65536)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                raise
            if not data:
                yield from parser.finish()
                return
            yield from parser.feed(data)

    def close(self) -> None:
        self._stop.set()
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()


def _manifest_tap(path: Path, endpoint: str | None) -> tuple[str, str]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SourceError(f"{path}: not a bench manifest ({exc})") from None
    eps = data.get("endpoints") if isinstance(data, dict) else None
    if not isinstance(eps, list):
        raise SourceError(f"{path}: not a bench manifest (no endpoints)")
    if endpoint is not None:
        eps = [e for e in eps if e.get("name") == endpoint]
        if not eps:
            raise SourceError(f"{path}: no endpoint named {endpoint!r}")
    for ep in eps:
        if ep.get("tap"):
            return ep["tap"], f"{path}#{ep.get('name')}"
    raise SourceError(f"{path}: the bench offers no tap (started with --no-tap?)")


def open_source(spec: str, *, baud: int | None = None, speed: float | None = None) -> Source:
    """Open a source string (see the module docstring); raises :class:`SourceError` with one line."""
    if spec == "-":
        return FileSource("-", baud=baud, speed=speed)
    url = urlparse(spec)
    if url.scheme == "tcp":
        if not url.hostname or not url.port:
            raise SourceError(f"{spec}: expected tcp://HOST:PORT")
        return TcpSource(url.hostname, url.port)
    if url.scheme == "serial":
        query = parse_qs(url.query)
        if "baud" in query:
            try:
                baud = int(query["baud"][0])
            except ValueError:
                raise SourceError(f"{spec}: baud must be an integer") from None
        return SerialSource(url.path or url.netloc, baud)
    path_text, _, fragment = spec.partition("#")
    path = Path(path_text)
    if not path.exists():
        raise SourceError(f"{spec}: no such file, port or source")
    mode = os.stat(path).st_mode
    if stat.S_ISCHR(mode):
        return SerialSource(str(path), baud)
    if path.suffix == ".json":
        tap, name = _manifest_tap(path, fragment or None)
        tap_url = urlparse(tap)
        return TcpSource(tap_url.hostname or "127.0.0.1", tap_url.port or 0, name=name)
    return FileSource(path, baud=baud, speed=speed)
