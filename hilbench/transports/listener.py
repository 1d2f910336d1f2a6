"""Non-blocking TCP listeners for the bench's servers (TCP host ports, RFC 2217, socketcand, taps).

A server thread waits on the listener's descriptor with everything else it
serves, then takes every waiting connection without ever blocking. ``socket.create_server``
is not used: it turns IPV6_V6ONLY on (a ``::`` bind would stop hearing IPv4
clients) and rewrites bind errors.

A client must never take a bench's thread down, so :class:`Listener` also
keeps each server to its limit of clients: a connection beyond it first asks
the server to let go of a kept client that is of no use (``evict``; the
policy: :mod:`hilbench.transports.client_limit`) and takes its place; if
none is, it gets the server's own refusal (its protocol's error message) and
is closed, and the clients already served go on. When the process has no descriptor left
(``accept`` fails with EMFILE), the connection would stay pending and the
listener readable, and a thread waiting on it would spin: the listener then
spends a spare descriptor kept for the purpose to take that connection and
refuse it, and if even that fails (another thread took the spare first) it
stops listening for :data:`PAUSE` seconds (the connections wait in the backlog).

Every bench socket binds through :func:`bind`: an address that is taken or
not this machine's raises :class:`BindError`, which says the address; the
bench adds the endpoint and the profile key that chose it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator

from hilbench.errors import UnavailableError

#: accept() errors that mean "no descriptor or memory left": the connection stays pending.
_EXHAUSTED = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
#: Connections the kernel completes and holds for a server before it accepts them: a burst of clients
#: (a team's test runs starting together) beyond it has its connection attempts dropped and retried a
#: second later. Holding them takes no descriptor.
BACKLOG = 128
#: Seconds a listener stops listening when the process has no descriptor left even for a refusal.
PAUSE = 0.25
#: What a client refused for lack of descriptors is told (with the server's own refusal around it).
NO_DESCRIPTORS = "the bench has no descriptors left (too many connections)"


class BindError(UnavailableError, OSError):
    """A socket could not bind ``address`` (taken, not an address of this machine, privileged): exit status 1.

    ``what`` says which socket ("TCP port", "UDP port"); ``key`` is the profile key (relative to its
    endpoint's table) that chose the port, where the code that opened it knows it; ``port_taken`` tells a
    taken or forbidden port (change the port) from an address this machine does not have (change the bind).
    """

    def __init__(self, address: tuple, reason: str, code: int | None = None, what: str = "socket",
                 key: str | None = None) -> None:
        super().__init__(f"cannot listen on {what} {address[0]}:{address[1]}: {reason}")
        self.errno = code
        self.address = (address[0], address[1])
        self.reason = reason
        self.what = what
        self.key = key

    def with_message(self, text: str) -> BindError:
        """This error with ``text`` as its whole one-line message (the bench adds where and what to change)."""
        self.args = (text,)
        return self

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""

    @property
    def port_taken(self) -> bool:
        return self.errno in (errno.EADDRINUSE, errno.EACCES)


def bind(sock: socket.socket, address: tuple, what: str) -> None:
    """``sock.bind(address)``; on failure the socket is closed and :class:`BindError` raised."""
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise BindError(address, exc.strerror or str(exc), exc.errno, what) from None


def listen(bind: str, port: int, backlog: int, family: socket.AddressFamily = socket.AF_INET) -> socket.socket:
    """A non-blocking socket listening on ``(bind, port)`` (SO_REUSEADDR, so a restarted bench gets its port
    back at once); raises :class:`BindError` (the socket closed) if the address is taken or invalid."""
    listener = socket.socket(family, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    _bind(listener, (bind, port), "TCP port")
    listener.listen(backlog)
    listener.setblocking(False)
    return listener


def serve(sock: socket.socket) -> socket.socket:
    """An accepted client made ready for a server thread: non-blocking, small writes sent at once (no Nagle)."""
    sock.setblocking(False)
    with contextlib.suppress(OSError):  # (not on a Unix socket)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def refuse(sock: socket.socket, message: bytes) -> None:
    """Send ``message`` (a few bytes: a fresh socket's buffer takes them at once) and close ``sock``, never
    blocking: whatever the client already sent is read and dropped first, so the close is a FIN and the
    client reads the message before the end (an unread byte would turn it into a reset)."""
    with contextlib.suppress(OSError):
        sock.setblocking(False)
        if message:
            sock.send(message)
        sock.shutdown(socket.SHUT_WR)
        for _ in range(4):
            if not sock.recv(65536):
                break
    with contextlib.suppress(OSError):
        sock.close()


class _Spare:
    """One descriptor the process keeps for taking (and refusing) a connection when it has none left."""

    lock = threading.Lock()
    fd: int | None = None

    @classmethod
    def ensure(cls) -> None:
        with cls.lock:
            if cls.fd is None:
                with contextlib.suppress(OSError):
                    cls.fd = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)

    @classmethod
    def shed(cls, listener: socket.socket, message: Callable[[str], bytes]) -> bool:
        """Free the spare, take one pending connection with it and refuse it; False if that failed."""
        with cls.lock:
            if cls.fd is None:
                return False
            os.close(cls.fd)
            cls.fd = None
            try:
                conn, _ = listener.accept()
            except OSError:
                conn = None
            if conn is not None:
                refuse(conn, message(NO_DESCRIPTORS))
            with contextlib.suppress(OSError):
                cls.fd = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
            return conn is not None


class Listener:
    """A listening socket serving at most ``max_clients`` at once (see the module docstring).

    ``refusal(reason)`` is what a refused client is sent (the protocol's own
    error: ``< error ... >`` for socketcand, a line of text for RFC 2217);
    ``reason`` says why, in words. ``send_buffer`` fixes each client's kernel
    send buffer (SO_SNDBUF): autotuned, the kernel holds up to megabytes for a
    client that reads nothing (2.8 MB measured on loopback), on top of what the
    server queues itself. Counters: :attr:`accepted`, :attr:`refused` (beyond
    the limit), :attr:`evicted` (kept clients let go for a newcomer),
    :attr:`exhausted` (accept found no descriptor left).
    """

    def __init__(self, bind: str, port: int, backlog: int, *, max_clients: int,
                 refusal: Callable[[str], bytes], family: socket.AddressFamily | None = None,
                 sock: socket.socket | None = None, send_buffer: int | None = None) -> None:
        if sock is not None:  # a listening socket made elsewhere (a Unix socket)
            sock.setblocking(False)
            self.sock = sock
        else:
            if family is None:
                family = socket.AF_INET6 if ":" in bind else socket.AF_INET
            self.sock = listen(bind, port, backlog, family)
        self.max_clients = max_clients
        self.refusal = refusal
        self.send_buffer = send_buffer
        self.accepted = 0  #: connections accepted
        self.refused = 0  #: connections refused beyond the limit
        self.evicted = 0  #: connections closed to make room for a newcomer
        self.exhausted = 0  #: accepts that found no descriptor left
        #: While ``time.monotonic()`` is below this, the listener is not waited on (see the module docstring).
        self.paused_until = 0.0
        _Spare.ensure()

    def fileno(self) -> int:
        return self.sock.fileno()

    def getsockname(self) -> tuple:
        return self.sock.getsockname()

    def filenos(self) -> list[int]:
        """The listener's descriptor to wait on, or none while it pauses."""
        if self.paused_until and time.monotonic() < self.paused_until:
            return []
        return [self.sock.fileno()]

    def deadline(self) -> float | None:
        """When a pause ends (wait no longer than that), or None."""
        return self.paused_until if self.paused_until > time.monotonic() else None

    def accept(self, clients: int, evict: Callable[[], bool] | None = None) -> Iterator[tuple[socket.socket, tuple]]:
        """Every connection waiting, made ready by :func:`serve`, while the server holds fewer than
        ``max_clients`` (``clients`` now, plus those yielded). Beyond, ``evict()`` may let a kept client go
        (it returns True if it did: the newcomer takes its place); otherwise the newcomer is refused. Never
        blocks or raises."""
        if self.paused_until:
            if time.monotonic() < self.paused_until:
                return
            self.paused_until = 0.0
        while True:
            try:
                sock, addr = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno in (errno.ECONNABORTED, errno.EPROTO, errno.EPERM):
                    continue  # that one left before we took it: the next may be there
                if exc.errno in _EXHAUSTED:
                    self.exhausted += 1
                    if not _Spare.shed(self.sock, self.refusal):
                        self.paused_until = time.monotonic() + PAUSE
                return  # closed under us (EBADF, EINVAL) or out of descriptors: nothing more now
            if clients >= self.max_clients and evict is not None and evict():
                self.evicted += 1
                clients -= 1
            if clients >= self.max_clients:
                self.refused += 1
                refuse(sock, self.refusal(f"{self.max_clients} clients at most"))
                continue
            try:
                serve(sock)
                if self.send_buffer:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.send_buffer)
            except OSError:
                sock.close()
                continue
            clients += 1
            self.accepted += 1
            yield sock, addr

    def status(self) -> dict[str, int]:
        """The limit and the counters, for status reports."""
        return {"max_clients": self.max_clients, "accepted": self.accepted, "refused": self.refused,
                "evicted": self.evicted, "out_of_descriptors": self.exhausted}

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


_bind = bind  # (listen's and Listener's parameter is called bind)

__all__ = ["BACKLOG", "NO_DESCRIPTORS", "PAUSE", "BindError", "Listener", "bind", "listen", "refuse", "serve"]
