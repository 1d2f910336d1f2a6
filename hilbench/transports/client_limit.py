"""Which client a full server lets go for a newcomer: one that has done nothing useful for longest.

Every multi-client server keeps at most its limit of clients
(:class:`~hilbench.transports.listener.Listener`). Refusing every newcomer
beyond it would let a few hundred idle connections lock a team out of a
bench, so a newcomer first takes the place of a kept client that is of no
use to anyone, as the control channel does: the server tells it why in its
protocol's words and closes it. Only when every kept client is doing
something is the newcomer refused.

What "of no use" means is the protocol's own (:class:`Eviction` asks the
server through ``judge``), but one measure serves every streaming server:
whether the client *reads* what it is sent. :class:`ReadWatch` follows it.
A client that has read everything sent so far, or has read something since
the server last looked, is reading; one that has left bytes unread for
seconds is not. On this machine (a client on 127.0.0.1, as benches bind by
default) the kernel tells how many bytes wait unread in the client's own
socket (``sock_diag``, as ``ss`` shows them), so a client that never reads is
seen at once, even on a quiet line; a client elsewhere is seen only once the
buffers between are full and the server's own queue for it stops shrinking.
Where the kernel does not answer (not Linux, a netlink socket refused), the
server's own queue is all there is to go by.
"""

from __future__ import annotations

import contextlib
import fcntl
import ipaddress
import socket
import struct
import termios
from collections.abc import Callable, Sequence
from typing import Generic, TypeVar

#: A decision looks at the clients' sockets again only if it last looked longer ago than this (seconds):
#: a connection flood brings a newcomer every few microseconds, and one look serves them all.
OBSERVE_EVERY = 0.1
#: How long one question to the kernel may take before the server decides on what it knows (seconds).
KERNEL_TIMEOUT = 0.05

_NETLINK_SOCK_DIAG = 4
_SOCK_DIAG_BY_FAMILY = 20
_NLM_F_REQUEST = 1
_NLMSG_ERROR = 2
_NLMSG = struct.Struct("=IHHII")  # nlmsghdr: length, type, flags, sequence, port id
_NO_COOKIE = 0xFFFFFFFF
#: Offset of ``idiag_rqueue`` in a reply: nlmsghdr (16), family/state/timer/retrans (4), the socket id (48),
#: ``idiag_expires`` (4).
_RQUEUE_AT = 16 + 4 + 48 + 4

C = TypeVar("C")


class ReadWatch:
    """How a client takes what a server sends it.

    The server adds every byte the kernel took for the client to :attr:`sent`;
    :func:`observe` works out how many of them the client has read
    (:attr:`taken`) and since when it has had bytes waiting and read none of
    them (:attr:`since`: the last time it was seen reading, or with nothing to
    read; at first the time it connected).
    """

    __slots__ = ("sent", "taken", "since")

    def __init__(self, now: float) -> None:
        self.sent = 0
        self.taken = 0
        self.since = now

    def unread_for(self, now: float) -> float:
        """Seconds the client has left what it was sent unread (0 if it was seen reading just now)."""
        return now - self.since


def peer_unread(socks: Sequence[socket.socket]) -> list[int | None]:
    """Bytes each connection's client has received and not yet read, where the client is a socket of this
    machine the kernel tells about (None otherwise: a client elsewhere, or no answer). One netlink request
    per connection, all sent at once (~1 ms for 64 of them)."""
    out: list[int | None] = [None] * len(socks)
    requests = []
    for i, sock in enumerate(socks):
        try:
            ours, theirs = sock.getsockname(), sock.getpeername()
        except OSError:
            continue
        request = _lookup(i + 1, theirs, ours)
        if request is not None:
            requests.append(request)
    if not requests:
        return out
    try:
        nl = socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, _NETLINK_SOCK_DIAG)
    except (OSError, AttributeError):  # not Linux, or netlink refused: the server's own queue is all it has
        return out
    with nl:
        nl.settimeout(KERNEL_TIMEOUT)
        try:
            nl.send(b"".join(requests))
            left = len(requests)
            while left:
                data = nl.recv(65536)
                at = 0
                while at + _NLMSG.size <= len(data):
                    length, kind, _flags, seq, _pid = _NLMSG.unpack_from(data, at)
                    if length < _NLMSG.size:
                        break
                    if 1 <= seq <= len(socks):
                        if kind == _SOCK_DIAG_BY_FAMILY and length >= _RQUEUE_AT + 4:
                            out[seq - 1] = struct.unpack_from("=I", data, at + _RQUEUE_AT)[0]
                            left -= 1
                        elif kind == _NLMSG_ERROR:  # no such socket here: the client is elsewhere
                            left -= 1
                    at += (length + 3) & ~3
        except OSError:  # (a timeout too) decide on what came
            pass
    return out


def _lookup(seq: int, theirs: tuple, ours: tuple) -> bytes | None:
    """A sock_diag request for the socket at the client's end of a connection (its address, then ours)."""
    try:
        src, dst = ipaddress.ip_address(theirs[0].split("%")[0]), ipaddress.ip_address(ours[0].split("%")[0])
    except (ValueError, IndexError, AttributeError):
        return None
    if src.version == 6 and src.ipv4_mapped is not None:  # an IPv4 client of a "::" listener: an IPv4 socket
        src, dst = src.ipv4_mapped, dst.ipv4_mapped or dst
    if src.version != dst.version:
        return None
    family = socket.AF_INET if src.version == 4 else socket.AF_INET6
    sockid = (struct.pack(">HH", theirs[1], ours[1]) + src.packed.ljust(16, b"\0") + dst.packed.ljust(16, b"\0")
              + struct.pack("=III", 0, _NO_COOKIE, _NO_COOKIE))
    body = struct.pack("=BBBBI", family, socket.IPPROTO_TCP, 0, 0, 0xFFFFFFFF) + sockid
    return _NLMSG.pack(_NLMSG.size + len(body), _SOCK_DIAG_BY_FAMILY, _NLM_F_REQUEST, seq, 0) + body


def unsent(sock: socket.socket) -> int:
    """Bytes in our kernel's send queue for ``sock`` that the client's side has not acknowledged (0 if unknown)."""
    try:
        return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
    except (OSError, AttributeError, ValueError):
        return 0


def observe(entries: Sequence[tuple[socket.socket, ReadWatch, int]], now: float) -> None:
    """Look at each connection ``(sock, watch, queued)`` (``queued``: bytes still in the server's own queue for
    it) and bring its watch up to ``now``: the client read something since the last look, or has nothing
    waiting, and it is reading now; otherwise its :attr:`~ReadWatch.since` stays."""
    unread = peer_unread([sock for sock, _, _ in entries])
    for (sock, watch, queued), theirs in zip(entries, unread, strict=True):
        mine = unsent(sock)
        taken = watch.sent - mine - (theirs or 0)
        if taken > watch.taken or queued + mine + (theirs or 0) == 0:
            watch.since = now
        watch.taken = max(watch.taken, taken)


class Eviction(Generic[C]):
    """Chooses the kept client a newcomer replaces.

    ``judge(client, now)`` is the server's word on one client: None if it keeps
    its place, else ``(rank, since)``: the lowest rank goes first (a server may
    rank kinds of uselessness), and within a rank the client useless since the
    earliest time. ``watched(client)`` gives ``(sock, watch, queued)`` for the
    clients whose reading the server judges by (:func:`observe` runs on them
    first, at most every :data:`OBSERVE_EVERY` seconds).
    """

    def __init__(self, judge: Callable[[C, float], tuple[int, float] | None],
                 watched: Callable[[C], tuple[socket.socket, ReadWatch, int]] | None = None,
                 observe_every: float = OBSERVE_EVERY) -> None:
        self.judge = judge
        self.watched = watched
        self.observe_every = observe_every
        self._looked = float("-inf")

    def victim(self, clients: Sequence[C], now: float) -> C | None:
        """The client to let go for a newcomer, or None if every one is of use."""
        if self.watched is not None and now - self._looked >= self.observe_every:
            self._looked = now
            with contextlib.suppress(OSError):
                observe([self.watched(c) for c in clients], now)
        best: tuple[tuple[int, float], C] | None = None
        for c in clients:
            rank = self.judge(c, now)
            if rank is not None and (best is None or rank < best[0]):
                best = (rank, c)
        return None if best is None else best[1]


__all__ = ["OBSERVE_EVERY", "Eviction", "ReadWatch", "observe", "peer_unread", "unsent"]
