"""Non-blocking TCP listeners for the bench's servers (TCP host ports, RFC 2217, socketcand).

A server thread waits on the listener's descriptor with everything else it
serves, then takes every waiting connection (:func:`accepted`) without ever
blocking. ``socket.create_server`` is not used: it turns IPV6_V6ONLY on (a
``::`` bind would stop hearing IPv4 clients) and rewrites bind errors.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator


def listen(bind: str, port: int, backlog: int, family: socket.AddressFamily = socket.AF_INET) -> socket.socket:
    """A non-blocking socket listening on ``(bind, port)`` (SO_REUSEADDR, so a restarted bench gets its port
    back at once); raises OSError (the socket closed) if the address is taken or invalid."""
    listener = socket.socket(family, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        listener.bind((bind, port))
    except OSError:
        listener.close()
        raise
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


__all__ = ["accepted", "listen", "serve"]
