"""Byte sources for instruments: where bus traffic comes from, as timestamped chunks.

Every source yields :class:`~hilbench.transports.capture_file.Chunk` s
``(t, source, data)``: the bytes one party put on the bus, complete at time
``t`` (seconds, ``time.monotonic()`` for live data, the recording's own clock
for captures). The monitor, the recorder and the trace profiler consume
sources the same way:

=====================================  ==================================================
source string                          what it opens
=====================================  ==================================================
``capture.hbcap``, ``trace.bin``       a capture file: hilbench format, or a raw dump
``-``, a FIFO                          the same, arriving live on stdin or a named pipe
``/dev/ttyUSB0``, a pty                a serial port, receive-only (sniffing a bus)
``serial:///dev/ttyUSB0?baud=N``       the same with its baud rate in the URL
``udp://127.0.0.1:PORT[?peer=H:P]``    datagrams arriving on a UDP port (bound to
                                       127.0.0.1 when the host is empty); ``peer``
                                       announces this socket to a sender that streams
                                       to whoever registers (hilbench's emulated board)
``tcp://127.0.0.1:PORT``               a bench's tap server (capture format over TCP)
``manifest.json[#endpoint]``           the tap server of a running ``hilbench emulate``
=====================================  ==================================================

In-process benches are tapped with :class:`MediumSource`, and
:class:`PushSource` turns any callback (a pty proxy, a test) into a source.
Live raw bytes (a serial port, a pipe, UDP) are stamped with their arrival
time; raw files have no times unless a baud rate gives them byte time.

``Source.chunks(idle)`` yields ``None`` after ``idle`` seconds without data
(live sources only), so a consumer can advance its clock (``Source.clock()``)
while the bus is quiet. ``close()`` ends the iteration from another thread.
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import select
import socket
import stat
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from hilbench.transports.capture_file import READ_SIZE, CaptureError, CaptureParser, CaptureReader, Chunk

__all__ = [
    "Chunk",
    "FileSource",
    "MediumSource",
    "PushSource",
    "SerialSource",
    "Source",
    "SourceError",
    "StreamSource",
    "TcpSource",
    "UdpSource",
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

    def __init__(self, medium, *, protocol: str | None = "dynamixel", **kwargs) -> None:
        super().__init__(kwargs.pop("name", f"bench line {medium.name}"), baud=medium.baud, **kwargs)
        self.protocol = protocol
        self._medium = medium
        medium.add_tap(self.push)

    def close(self) -> None:
        self._medium.remove_tap(self.push)
        super().close()


class StreamSource(Source):
    """Bytes arriving live on a descriptor (a pipe, a FIFO, stdin, a socket), decoded as they come.

    The input is a hilbench capture stream (its header decides, as in a file)
    or raw bytes; raw bytes are stamped with their arrival time. ``chunks(idle)``
    yields None while the input is quiet and ends when the writer closes it.
    """

    def __init__(self, fd: int, *, name: str, baud: int | None = None, own: bool = True) -> None:
        self.name = name
        self._fd = fd
        self._own = own
        self._baud = baud
        self._baud_set: int | None = None
        self._stop = threading.Event()
        self.parser = CaptureParser(name=name)
        self._early: list[Chunk] = []

    @property
    def baud(self) -> int | None:  # type: ignore[override]
        """The line rate: as set, else the capture header's, else the one given at opening."""
        if self._baud_set is not None:
            return self._baud_set
        info = self.parser.info
        return info.baud if info is not None and info.baud else self._baud

    @baud.setter
    def baud(self, value: int | None) -> None:
        self._baud_set = value

    @property
    def protocol(self) -> str | None:  # type: ignore[override]
        info = self.parser.info
        return (info.protocol or None) if info is not None else None

    def _parse(self, data: bytes, now: float) -> list[Chunk]:
        chunks = self.parser.feed(data)
        if self.parser.mode == "raw":
            # Raw live bytes have no clock of their own: their arrival time is the truth we have.
            return [Chunk(now, c.source, c.data) for c in chunks]
        return chunks

    def _recv(self) -> bytes:
        return os.read(self._fd, READ_SIZE)

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        early, self._early = self._early, []
        yield from early
        fd = self._fd
        while not self._stop.is_set():
            try:
                if not select.select([fd], [], [], idle if idle is not None else 0.5)[0]:
                    if idle is not None:
                        yield None
                    continue
                data = self._recv()
            except (OSError, ValueError):
                if self._stop.is_set():
                    return  # closed under us
                raise
            if not data:  # the writer closed: what a raw input still holds is complete now
                now = time.monotonic()
                raw = self.parser.info is None
                yield from (Chunk(now, c.source, c.data) if raw else c for c in self.parser.finish())
                return
            yield from self._parse(data, time.monotonic())

    def close(self) -> None:
        self._stop.set()
        if self._own:
            self._own = False
            with contextlib.suppress(OSError):
                os.close(self._fd)


class TcpSource(StreamSource):
    """A bench's tap server (``tcp://127.0.0.1:PORT``): a live capture stream over TCP."""

    def __init__(self, host: str, port: int, *, name: str | None = None, timeout: float = 5.0) -> None:
        name = name or f"tcp://{host}:{port}"
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as exc:
            raise SourceError(f"cannot connect to {name}: {exc.strerror or exc}") from None
        super().__init__(self._sock.fileno(), name=name, own=False)
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

    def _recv(self) -> bytes:
        return self._sock.recv(READ_SIZE)

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


class UdpSource(Source):
    """Datagrams arriving on a UDP port, receive-only; binds 127.0.0.1 unless told otherwise.

    Each wake-up yields the datagrams that arrived, joined per sender, stamped
    with their arrival time and named ``udp:HOST:PORT`` after the sender. With
    ``peer``, an empty datagram announces this socket to a sender that streams
    to whoever registers (hilbench's emulated board does), repeated every
    ``announce_s`` seconds until data arrives.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, peer: tuple[str, int] | None = None,
                 announce_s: float = 0.5) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # Room for bursts while the consumer is busy: the kernel drops what does not fit.
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        try:
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise SourceError(f"cannot bind udp://{host}:{port}: {exc.strerror or exc}") from None
        self._sock.setblocking(False)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self.name = f"udp://{self.address[0]}:{self.address[1]}"
        self.peer = peer
        self.announce_s = announce_s
        self.datagrams = 0
        self._announced = 0.0
        self._heard = False
        self._stop = threading.Event()
        self._announce()

    def _announce(self) -> None:
        if self.peer is not None and not self._heard:
            now = time.monotonic()
            if now - self._announced >= self.announce_s:
                self._announced = now
                with contextlib.suppress(OSError):
                    self._sock.sendto(b"", self.peer)

    #: Datagrams taken per wake-up, so one burst cannot hold the consumer (or memory) for long.
    MAX_DATAGRAMS = 256

    def _drain(self) -> list[Chunk]:
        parts: list[tuple[str, list[bytes]]] = []
        now = time.monotonic()
        for _ in range(self.MAX_DATAGRAMS):
            try:
                data, sender = self._sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # ICMP for an announcement nobody heard yet
                break
            except OSError:
                if self._stop.is_set():
                    break  # closed under us
                raise
            self.datagrams += 1
            src = f"udp:{sender[0]}:{sender[1]}"
            if parts and parts[-1][0] == src:
                parts[-1][1].append(data)
            else:
                parts.append((src, [data]))
        if parts:
            self._heard = True
        return [Chunk(now, src, b"".join(datas)) for src, datas in parts]

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        sock = self._sock
        while not self._stop.is_set():
            self._announce()
            try:
                ready = select.select([sock], [], [], min(idle if idle is not None else 0.5, self.announce_s))[0]
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                raise
            if not ready:
                if idle is not None:
                    yield None
                continue
            yield from self._drain()

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
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


def _host_port(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise SourceError(f"{what}: expected HOST:PORT, got {text!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def _stdin(*, baud: int | None, speed: float | None) -> Source:
    """stdin redirected from a file is replayed like that file; a pipe or terminal is live."""
    fd = sys.stdin.buffer.fileno()
    if stat.S_ISREG(os.fstat(fd).st_mode):  # `< file`: replay it like a named file
        return FileSource("-", baud=baud, speed=speed)
    return StreamSource(fd, name="stdin", baud=baud, own=False)


def open_source(spec: str, *, baud: int | None = None, speed: float | None = None,
                default_baud: int = 57_600) -> Source:
    """Open a source string (see the module docstring); raises :class:`SourceError` with one line.

    ``baud`` is the line rate of a serial port (``default_baud`` if not given)
    and the byte time of a raw file; ``speed`` replays a file in its recorded
    time (1.0) instead of as fast as possible.
    """
    if spec == "-":
        return _stdin(baud=baud, speed=speed)
    url = urlparse(spec)
    if url.scheme == "tcp":
        if not url.hostname or not url.port:
            raise SourceError(f"{spec}: expected tcp://HOST:PORT")
        return TcpSource(url.hostname, url.port)
    if url.scheme == "udp":
        host, port = _host_port(url.netloc, spec)
        query = parse_qs(url.query)
        peer = _host_port(query["peer"][0], f"{spec}: peer") if "peer" in query else None
        return UdpSource(host, port, peer=peer)
    if url.scheme == "serial":
        query = parse_qs(url.query)
        if "baud" in query:
            try:
                baud = int(query["baud"][0])
            except ValueError:
                raise SourceError(f"{spec}: baud must be an integer") from None
        return SerialSource(url.path or url.netloc, baud or default_baud)
    if len(url.scheme) > 1:  # one letter would be a Windows drive
        raise SourceError(f"{spec}: unknown source scheme {url.scheme!r} "
                          "(use a path, -, serial://, udp:// or tcp://)")
    path_text, _, fragment = spec.partition("#")
    path = Path(path_text)
    if not path.exists():
        raise SourceError(f"{spec}: no such file, port or source")
    mode = os.stat(path).st_mode
    if stat.S_ISCHR(mode):
        return SerialSource(str(path), baud or default_baud)
    if stat.S_ISFIFO(mode):
        # O_NONBLOCK so the open does not wait for a writer; reads then wait in select.
        return StreamSource(os.open(path, os.O_RDONLY | os.O_NONBLOCK), name=str(path), baud=baud)
    if path.suffix == ".json":
        tap, name = _manifest_tap(path, fragment or None)
        tap_url = urlparse(tap)
        return TcpSource(tap_url.hostname or "127.0.0.1", tap_url.port or 0, name=name)
    return FileSource(path, baud=baud, speed=speed)
