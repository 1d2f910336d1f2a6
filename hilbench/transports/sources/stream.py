"""Live byte streams: pipes, FIFOs, stdin and a bench's TCP tap server."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Iterator
from urllib.parse import urlparse

from hilbench.transports.capture_parser import READ_SIZE, CaptureParser
from hilbench.transports.chunk import Chunk, sound_quality
from hilbench.transports.sources.base import Source, SourceError, SourceOpener, SourceUnavailable


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
        self.parser = CaptureParser(name=name, lookahead=False)  # live: hand records out as they complete
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

    def quality(self) -> dict:
        return self.parser.quality() if self.parser.info is not None else sound_quality()

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
        from hilbench.transports.readiness import Readiness  # (a source plug-in loads light: see sources)

        readiness = Readiness([self._fd])
        while not self._stop.is_set():
            try:
                if not readiness.idle(idle if idle is not None else 0.5):
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
        import socket

        from hilbench.transports.tap_server import REFUSAL_PREFIX as TAP_REFUSAL

        name = name or f"tcp://{host}:{port}"
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as exc:
            raise SourceUnavailable(f"cannot connect to {name}: {exc.strerror or exc}") from None
        super().__init__(self._sock.fileno(), name=name, own=False)
        head = b""  # the first bytes: a refusal is a line of text
        try:
            while not self.parser.decided:
                data = self._sock.recv(65536)
                if not data:
                    break
                if len(head) < 256:
                    head += data[:256]
                self._early += self.parser.feed(data)
        except TimeoutError:
            self._sock.close()
            raise SourceUnavailable(f"{self.name}: sent nothing within {timeout:g} s (a bench's traffic tap sends "
                                    "its header at once)") from None
        except OSError as exc:
            self._sock.close()
            if head.startswith(TAP_REFUSAL):  # (the reset came after the server's message)
                raise SourceUnavailable(f"{self.name}: {_line(head)}") from None
            raise SourceUnavailable(f"{self.name}: {exc.strerror or exc}") from None
        if self.parser.info is None:
            self._sock.close()
            if head.startswith(TAP_REFUSAL):
                raise SourceUnavailable(f"{self.name}: {_line(head)}")
            raise SourceError(f"{self.name} does not speak the hilbench capture format")
        self._sock.settimeout(None)

    def _recv(self) -> bytes:
        return self._sock.recv(READ_SIZE)

    def close(self) -> None:
        import socket

        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


def _line(head: bytes) -> str:
    return head.split(b"\n", 1)[0].decode("ascii", "replace").strip()


def open_fifo(spec: str, target: str, fragment: str, *, baud: int | None = None, **_: object) -> Source:
    # O_NONBLOCK so the open does not wait for a writer; reads then wait in poll.
    return StreamSource(os.open(target, os.O_RDONLY | os.O_NONBLOCK), name=target, baud=baud)


def open_tcp(spec: str, target: str, fragment: str, **_: object) -> Source:
    url = urlparse(spec)
    if not url.hostname or not url.port:
        raise SourceError(f"{spec}: expected tcp://HOST:PORT")
    return TcpSource(url.hostname, url.port)


FIFO = SourceOpener("fifo", open_fifo, kinds=("fifo",), usage="a FIFO",
                    what="a named pipe: a capture or raw bytes arriving live")
TCP = SourceOpener("tcp", open_tcp, schemes=("tcp",), usage="tcp://127.0.0.1:PORT",
                   what="a bench's traffic tap (the capture format over TCP)")

__all__ = ["FIFO", "TCP", "StreamSource", "TcpSource", "open_fifo", "open_tcp"]
