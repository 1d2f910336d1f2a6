"""Datagrams arriving on a UDP port, receive-only (bound to 127.0.0.1 unless told otherwise)."""

from __future__ import annotations

import contextlib
import selectors
import threading
import time
from collections.abc import Iterator
from urllib.parse import parse_qs, urlparse

from hilbench.transports.chunk import Chunk
from hilbench.transports.sources.base import Source, SourceError, SourceOpener, SourceUnavailable


class UdpSource(Source):
    """Datagrams arriving on a UDP port, receive-only; binds 127.0.0.1 unless told otherwise.

    Each wake-up yields the datagrams that arrived, one chunk each with its
    addresses (``Chunk.addr``), stamped with their arrival time and named
    ``udp:HOST:PORT`` after the sender. With
    ``peer``, an empty datagram announces this socket to a sender that streams
    to whoever registers (hilbench's emulated board does), repeated every
    ``announce_s`` seconds until data arrives.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, peer: tuple[str, int] | None = None,
                 announce_s: float = 0.5) -> None:
        import socket

        from hilbench.transports.medium_loop import WakePipe  # (a source plug-in loads light: see sources)

        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # Room for bursts while the consumer is busy: the kernel drops what does not fit.
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        try:
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise SourceUnavailable(f"cannot bind udp://{host}:{port}: {exc.strerror or exc}") from None
        self._sock.setblocking(False)
        self._sel = selectors.DefaultSelector()  # (epoll: any descriptor number, unlike select())
        self._sel.register(self._sock, selectors.EVENT_READ)
        self._waker = WakePipe()  # close() ends a wait at once
        self._sel.register(self._waker.fd, selectors.EVENT_READ)
        self._iterating = False
        self._released = threading.Lock()  # held once the selector and wake-up pipe are closed
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
        out: list[Chunk] = []
        now = time.monotonic()
        host, port = self.address
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
            out.append(Chunk(now, f"udp:{sender[0]}:{sender[1]}", data, 0, (sender[0], sender[1], host, port)))
        if out:
            self._heard = True
        return out

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        sel = self._sel
        self._iterating = True
        try:
            yield from self._chunks(sel, idle)
        finally:
            self._iterating = False
            self._release()

    def _chunks(self, sel: selectors.BaseSelector, idle: float | None) -> Iterator[Chunk | None]:
        while not self._stop.is_set():
            self._announce()
            try:
                ready = sel.select(min(idle if idle is not None else 0.5, self.announce_s))
            except (OSError, ValueError, KeyError):  # (closed under us)
                if self._stop.is_set():
                    return
                raise
            if self._stop.is_set():
                break
            if not ready:
                if idle is not None:
                    yield None
                continue
            yield from self._drain()

    def _release(self) -> None:
        if self._stop.is_set() and self._released.acquire(blocking=False):
            self._sel.close()
            self._waker.close()

    def close(self) -> None:
        self._stop.set()
        self._waker.wake()
        with contextlib.suppress(OSError):
            self._sock.close()
        if not self._iterating:
            self._release()  # (else the iteration does, once its wait has ended)


def _host_port(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise SourceError(f"{what}: expected HOST:PORT, got {text!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def open_udp(spec: str, target: str, fragment: str, **_: object) -> Source:
    url = urlparse(spec)
    host, port = _host_port(url.netloc, spec)
    query = parse_qs(url.query)
    peer = _host_port(query["peer"][0], f"{spec}: peer") if "peer" in query else None
    return UdpSource(host, port, peer=peer)


UDP = SourceOpener("udp", open_udp, schemes=("udp",), usage="udp://127.0.0.1:PORT[?peer=HOST:PORT]",
                   what="datagrams arriving on a UDP port (udp://:PORT binds 127.0.0.1); peer announces the "
                        "socket to a sender that streams to whoever registers")

__all__ = ["UDP", "UdpSource", "open_udp"]
