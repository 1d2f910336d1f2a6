"""A UDP relay between clients and a target (``hilbench tap udp LISTEN TARGET``), watching both ways.

Clients (a micro-ROS board, eProsima's client examples) send to LISTEN
instead of to the agent; the relay forwards each datagram at once from a
socket of that client's own (so the target sees one address per client, as
it would without the relay) and sends the target's answers back to the client
from LISTEN. Every datagram also goes to :attr:`UdpRelay.source` (a bounded
:class:`~hilbench.transports.sources.PushSource`) with the addresses of the
conversation it belongs to: ``(client, target)`` one way, ``(target, client)``
the other, the relay's own sockets left out. It binds 127.0.0.1 unless told
otherwise.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time

from hilbench.transports.sources.base import PushSource

Address = tuple[str, int]
#: Clients relayed at once; the least recently heard one is dropped beyond this.
MAX_CLIENTS = 64


class UdpRelay:
    """See the module docstring."""

    def __init__(self, listen: Address, target: Address, *, max_clients: int = MAX_CLIENTS) -> None:
        self.target = target
        self.max_clients = max_clients
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(listen)
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.listen: Address = self.sock.getsockname()[:2]
        self.source = PushSource(f"udp relay {self.listen[0]}:{self.listen[1]} -> {target[0]}:{target[1]}")
        self.source.protocol = "udp"
        self._up: dict[Address, socket.socket] = {}
        self._client_of: dict[int, Address] = {}
        self._seen: dict[Address, float] = {}
        self.datagrams_up = 0
        self.datagrams_down = 0
        self.bytes_up = 0
        self.bytes_down = 0
        self.send_errors = 0
        self.error: str | None = None
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def clients(self) -> list[Address]:
        return list(self._up)

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
            up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            up.bind((self.listen[0], 0))
            up.setblocking(False)
            self._up[client] = up
            self._client_of[up.fileno()] = client
        self._seen[client] = time.monotonic()
        return up

    def _drop(self, client: Address) -> None:
        up = self._up.pop(client, None)
        self._seen.pop(client, None)
        if up is not None:
            self._client_of.pop(up.fileno(), None)
            up.close()

    def _run(self) -> None:
        target = self.target
        push = self.source.push
        try:
            while not self._stop.is_set():
                fds = [self.sock, self._wake_r, *self._up.values()]
                ready = select.select(fds, [], [], 0.5)[0]
                for r in ready:
                    if r is self._wake_r:
                        with contextlib.suppress(BlockingIOError):
                            os.read(self._wake_r, 64)
                        continue
                    if r is self.sock:
                        while True:
                            try:
                                data, client = self.sock.recvfrom(65536)
                            except (BlockingIOError, InterruptedError):
                                break
                            except OSError:
                                break  # ICMP from an earlier send to a client that went away
                            client = client[:2]
                            now = time.monotonic()
                            try:
                                self._upstream(client).sendto(data, target)
                            except OSError:
                                self.send_errors += 1
                            self.datagrams_up += 1
                            self.bytes_up += len(data)
                            push(now, f"udp:{client[0]}:{client[1]}", data, (client[0], client[1], target[0], target[1]))
                        continue
                    client = self._client_of.get(r.fileno())
                    if client is None:
                        continue
                    while True:
                        try:
                            data, sender = r.recvfrom(65536)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:
                            break  # the target is not there (ICMP port unreachable): keep relaying
                        now = time.monotonic()
                        try:
                            self.sock.sendto(data, client)
                        except OSError:
                            self.send_errors += 1
                        self.datagrams_down += 1
                        self.bytes_down += len(data)
                        push(now, f"udp:{sender[0]}:{sender[1]}", data, (sender[0], sender[1], client[0], client[1]))
        except Exception as exc:  # noqa: BLE001 (reported to the verb, which exits with it)
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.source.end()

    def close(self) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=5)
        for client in list(self._up):
            self._drop(client)
        self.sock.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.source.end()


__all__ = ["MAX_CLIENTS", "UdpRelay"]
