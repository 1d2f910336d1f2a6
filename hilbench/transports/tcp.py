"""A TCP host port: a device reached over Ethernet (a laser scanner's TCP port, a bench service).

:class:`TcpPort` listens on 127.0.0.1 (unless told otherwise) and serves
one client at a time, as an embedded device's single TCP server does: a
second client while one is connected is accepted and closed at once (and
counted), and when the client leaves the port listens again (also when the
bench runs out of descriptors: :class:`~hilbench.transports.listener.Listener`). To a medium it
is a host port like a pty: bytes the client sends are read, the devices'
bytes are written to the client (or dropped and counted while nobody is
connected, as a device's output is lost without a peer).
"""

from __future__ import annotations

import contextlib
import socket
from typing import Any

from hilbench.transports.host_port import HostPort, bind_address, port_number
from hilbench.transports.listener import Listener


class TcpPort(HostPort):
    """A one-client TCP server acting as a host port; profile keys ``bind`` and ``port``."""

    kind = "tcp"
    profile_keys = {"bind": "127.0.0.1", "port": 0}
    backpressure = True  # unread, the receive window fills and the client's send() waits

    def __init__(self, name: str = "tcp", bind: str = "127.0.0.1", port: int = 0) -> None:
        self.name = name
        # a device's protocol has no refusal message: a newcomer is closed at once
        self.listener = Listener(bind, port, 4, max_clients=1, refusal=lambda reason: b"")
        self.client: socket.socket | None = None
        self.peer: tuple[str, int] | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.dropped = 0
        self.connections = 0

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        return {"bind": bind_address(raw.get("bind", "127.0.0.1")), "port": port_number(raw.get("port", 0))}

    @classmethod
    def open(cls, name: str, options: dict[str, Any], **_: Any) -> TcpPort:
        return cls(name, options["bind"], options["port"])

    @property
    def address(self) -> tuple[str, int]:
        return self.listener.getsockname()[:2]

    @property
    def url(self) -> str:
        host, port = self.address
        return f"tcp://{host}:{port}"

    @property
    def client_path(self) -> str:
        return self.url

    def describe(self) -> dict[str, Any]:
        host, port = self.address
        return {"path": self.url, "host": host, "port": port}

    def counters(self) -> dict[str, int]:
        """Traffic and losses: connections served, bytes in and out, the devices' bytes dropped (no client, or
        its buffer full), newcomers closed at once (:attr:`refused`) and the one client it serves."""
        return {"connections": self.connections, "bytes_in": self.bytes_in, "bytes_out": self.bytes_out,
                "dropped": self.dropped, "refused": self.refused, "max_clients": 1}

    def fileno(self) -> int:
        return self.client.fileno() if self.client is not None else self.listener.fileno()

    def filenos(self) -> list[int]:
        fds = self.listener.filenos()
        if self.client is not None:
            fds.append(self.client.fileno())
        return fds

    def _accept(self) -> None:
        busy = self.client is not None  # busy: a real single-connection device refuses the newcomer
        for sock, addr in self.listener.accept(1 if busy else 0):
            self.client, self.peer = sock, addr[:2]
            self.connections += 1

    @property
    def refused(self) -> int:
        """Connections closed at once (another client held the port, or no descriptor was left)."""
        return self.listener.refused + self.listener.exhausted

    def _drop_client(self) -> None:
        if self.client is not None:
            with contextlib.suppress(OSError):
                self.client.close()
        self.client = self.peer = None

    def read(self, size: int = 65536) -> bytes:
        """What the client sent (at most ``size`` bytes; b'' if nothing); accepts a waiting client first."""
        self._accept()
        if self.client is None:
            return b""
        try:
            data = self.client.recv(size)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            self._drop_client()
            return b""
        if not data:  # the client closed: listen for the next one
            self._drop_client()
            return b""
        self.bytes_in += len(data)
        return data

    def write(self, data: bytes) -> int:
        """Send to the client; without one, or what its buffer refuses, is dropped and counted."""
        if self.client is None:
            self.dropped += len(data)
            return 0
        view = memoryview(data)
        sent = 0
        while sent < len(view):
            try:
                sent += self.client.send(view[sent:])
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._drop_client()
                break
        self.bytes_out += sent
        self.dropped += len(view) - sent
        return sent

    def close(self) -> None:
        self._drop_client()
        with contextlib.suppress(OSError):
            self.listener.close()

    def __repr__(self) -> str:
        return f"TcpPort({self.name!r}, {self.url})"


__all__ = ["TcpPort"]
