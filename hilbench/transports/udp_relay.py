"""A UDP relay between clients and an upstream (``hilbench tap udp LISTEN UPSTREAM``), watching both ways.

Clients (a micro-ROS board, eProsima's client examples) send to LISTEN
instead of to the agent; the relay forwards each datagram at once from a
socket of that client's own (so the upstream sees one address per client, as
it would without the relay) and sends the upstream's answers back to the client
from LISTEN. Every datagram also goes to :attr:`UdpRelay.source` (a bounded
:class:`~hilbench.transports.sources.PushSource`) with the addresses of the
conversation it belongs to: ``(client, upstream)`` one way, ``(upstream, client)``
the other, the relay's own sockets left out. It binds 127.0.0.1 unless told
otherwise.

Bounds: at most :data:`MAX_CLIENTS` clients (the one heard least recently
makes room, ``clients_dropped``); each socket is read :data:`READ_BATCH`
datagrams at a time, so one flooding client cannot hold up the others; nothing
is queued for relaying (a datagram the kernel will not take is counted in
``send_errors``); the watching side holds :data:`WATCH_BYTES` at most and
reports what it missed. :meth:`UdpRelay.counters` has the figures.
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
import time

from hilbench.transports.medium_loop import WakePipe
from hilbench.transports.sources.base import PushSource

Address = tuple[str, int]
#: Clients relayed at once; the least recently heard one is dropped beyond this (counted).
MAX_CLIENTS = 64
#: Datagrams read from one socket per wake-up, so a flooding client cannot starve the others' replies.
READ_BATCH = 64
#: What the watching side may fall behind by (bytes); beyond, datagrams are relayed but not watched, and
#: the loss is reported to the monitor (:class:`~hilbench.transports.sources.PushSource`).
WATCH_BYTES = 16 << 20


class UdpRelay:
    """See the module docstring."""

    def __init__(self, listen: Address, upstream: Address, *, max_clients: int = MAX_CLIENTS) -> None:
        self.upstream = upstream
        self.max_clients = max_clients  #: clients relayed at once
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(listen)
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.listen: Address = self.sock.getsockname()[:2]
        #: What the relay saw, both ways, for a monitor or recorder.
        self.source = PushSource(f"udp relay {self.listen[0]}:{self.listen[1]} -> {upstream[0]}:{upstream[1]}",
                                 max_bytes=WATCH_BYTES)
        self.source.protocol = "udp"
        self._up: dict[Address, socket.socket] = {}
        self._seen: dict[Address, float] = {}
        self.datagrams_up = 0
        self.datagrams_down = 0
        self.bytes_up = 0
        self.bytes_down = 0
        self.send_errors = 0
        self.clients_dropped = 0
        self.error: str | None = None
        self._waker = WakePipe()
        # epoll: clients' sockets may have any descriptor number (select() stops at 1024).
        self._sel = selectors.DefaultSelector()
        self._sel.register(self.sock, selectors.EVENT_READ, None)
        self._sel.register(self._waker.fd, selectors.EVENT_READ, "wake")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def clients(self) -> list[Address]:
        return list(self._up)

    def counters(self) -> dict[str, int]:
        """What went through and what was lost: datagrams and bytes each way, send errors, clients dropped
        beyond :attr:`max_clients`, bytes the watching side missed."""
        return {"datagrams_up": self.datagrams_up, "datagrams_down": self.datagrams_down,
                "bytes_up": self.bytes_up, "bytes_down": self.bytes_down, "send_errors": self.send_errors,
                "clients": len(self._up), "clients_dropped": self.clients_dropped,
                "unwatched_bytes": self.source.lost_bytes}

    def start(self) -> UdpRelay:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="udp-relay", daemon=True)
            self._thread.start()
        return self

    def _upstream(self, client: Address) -> socket.socket:
        up = self._up.get(client)
        if up is None:
            if len(self._up) >= self.max_clients:
                oldest = min(self._seen, key=self._seen.get)
                self._drop(oldest)
                self.clients_dropped += 1
            up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            up.bind((self.listen[0], 0))
            up.setblocking(False)
            self._up[client] = up
            self._sel.register(up, selectors.EVENT_READ, client)
        self._seen[client] = time.monotonic()
        return up

    def _drop(self, client: Address) -> None:
        up = self._up.pop(client, None)
        self._seen.pop(client, None)
        if up is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(up)
            up.close()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                for key, _ in self._sel.select(0.5):
                    if key.data == "wake":
                        self._waker.drain()
                    elif key.data is None:
                        self._from_clients()
                    elif self._up.get(key.data) is key.fileobj:  # (not a client dropped meanwhile)
                        self._from_upstream(key.fileobj, key.data)
        except Exception as exc:  # noqa: BLE001 (reported to the verb, which exits with it)
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.source.end()

    def _from_clients(self) -> None:
        upstream = self.upstream
        for _ in range(READ_BATCH):
            try:
                data, client = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return  # ICMP from an earlier send to a client that went away
            client = client[:2]
            now = time.monotonic()
            try:
                self._upstream(client).sendto(data, upstream)
            except OSError:
                self.send_errors += 1
            self.datagrams_up += 1
            self.bytes_up += len(data)
            self.source.push(now, f"udp:{client[0]}:{client[1]}", data, (client[0], client[1], upstream[0], upstream[1]))

    def _from_upstream(self, up: socket.socket, client: Address) -> None:
        for _ in range(READ_BATCH):
            try:
                data, sender = up.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return  # the upstream is not there (ICMP port unreachable): keep relaying
            now = time.monotonic()
            try:
                self.sock.sendto(data, client)
            except OSError:
                self.send_errors += 1
            self.datagrams_down += 1
            self.bytes_down += len(data)
            self.source.push(now, f"udp:{sender[0]}:{sender[1]}", data, (sender[0], sender[1], client[0], client[1]))

    def close(self) -> None:
        self._stop.set()
        self._waker.wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for client in list(self._up):
            self._drop(client)
        self._sel.close()
        self.sock.close()
        self._waker.close()
        self.source.end()


__all__ = ["MAX_CLIENTS", "READ_BATCH", "UdpRelay"]
