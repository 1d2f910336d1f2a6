"""Non-blocking TCP listeners for the bench's servers (TCP host ports, RFC 2217, socketcand), and binding.

A server thread waits on the listener's descriptor with everything else it
serves, then takes every waiting connection (:func:`accepted`) without ever
blocking. ``socket.create_server`` is not used: it turns IPV6_V6ONLY on (a
``::`` bind would stop hearing IPv4 clients) and rewrites bind errors.

Every bench socket binds through :func:`bind`: an address that is taken or
not this machine's raises :class:`BindError`, which says the address; the
bench adds the endpoint and the profile key that chose it.
"""

from __future__ import annotations

import errno
import socket
from collections.abc import Iterator

from hilbench.errors import UnavailableError


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


def accepted(listener: socket.socket) -> Iterator[tuple[socket.socket, tuple]]:
    """``(socket, peer address)`` of every connection waiting on ``listener``; ends when none waits (or the
    listener fails, e.g. closed under us)."""
    while True:
        try:
            conn = listener.accept()
        except OSError:  # BlockingIOError / InterruptedError: nobody waits; anything else: nothing to accept
            return
        yield conn


def serve(sock: socket.socket) -> socket.socket:
    """An accepted client made ready for a server thread: non-blocking, small writes sent at once (no Nagle)."""
    sock.setblocking(False)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


_bind = bind  # (listen's parameter is called bind)

__all__ = ["BindError", "accepted", "bind", "listen", "serve"]
