"""What a virtual-time bench's sockets sent to and took from each client address (its socket *channels*).

A bench in virtual time keeps one :class:`ChannelBook` on its clock
(:attr:`~hilbench.transports.clock.VirtualClock.channels`). Its socket doors (a socketcand server's listener,
a UDP endpoint) register their addresses with :meth:`ChannelBook.door` and count, per client address, the
bytes (TCP) or datagrams (UDP) they send and take. The lockstep controller
(:mod:`hilbench.bench.lockstep`) publishes the doors on the clock page and stores these totals beside the
counts a client's preload shim keeps for the same address, so it knows when bytes to the bench are in flight
and which waiting client thread the bench just sent to (PLAN26 §4.8, phase 2). Wall-clock benches have no book.

Everything here runs in the bench loop's thread (the doors' I/O and the lockstep's reads), so no lock.
"""

from __future__ import annotations

import contextlib
import socket
import sys
from typing import Any

TCP, UDP = 6, 17
#: Client addresses kept at most (the oldest go first: a client that connects and leaves for ever).
MAX_ADDRESSES = 4096


class ChannelBook:
    """Per (protocol, client host, client port): [sent, taken] by the bench; the doors the bench counts on."""

    def __init__(self) -> None:
        self.totals: dict[tuple[int, str, int], list[int]] = {}
        self.doors: list[tuple[int, str, int]] = []
        self.door_ports: list[Any] = []  # the host port behind each door (a serial line may hold it back)
        self.changes = 0  #: bumped on every count (the lockstep looks at the totals only when it moved)

    def door(self, proto: int, address: tuple[str, int], port: Any = None) -> None:
        """Count the traffic of the socket bound at ``address`` (a listener's, for TCP); ``port``: the host port
        it belongs to (a line that leaves it unread on purpose does not leave its clients' bytes in flight)."""
        entry = (proto, address[0], int(address[1]))
        if entry not in self.doors:
            self.doors.append(entry)
            self.door_ports.append(port)
            self.changes += 1

    def forget(self, proto: int, addr: tuple[str, int]) -> None:
        """A client's connection ended: its address may come back for another one."""
        self.totals.pop((proto, addr[0], int(addr[1])), None)

    def _entry(self, proto: int, addr: tuple[str, int]) -> list[int]:
        key = (proto, addr[0], int(addr[1]))
        entry = self.totals.get(key)
        if entry is None:
            if len(self.totals) >= MAX_ADDRESSES:
                with contextlib.suppress(StopIteration, KeyError):
                    del self.totals[next(iter(self.totals))]
            entry = self.totals[key] = [0, 0]
        return entry

    def sent(self, proto: int, addr: tuple[str, int], n: int) -> None:
        """The bench sent ``n`` bytes (TCP) or datagrams (UDP) to ``addr``."""
        self._entry(proto, addr)[0] += n
        self.changes += 1

    def took(self, proto: int, addr: tuple[str, int], n: int) -> None:
        """The bench read ``n`` bytes (TCP) or datagrams (UDP) from ``addr``."""
        self._entry(proto, addr)[1] += n
        self.changes += 1

    def get(self, proto: int, host: str, port: int) -> list[int] | None:
        return self.totals.get((proto, host, port))


def packed_ipv4(host: str) -> int:
    """``host`` as the clock page stores an IPv4 address (``sin_addr`` read as a native u32); 0 if not one."""
    try:
        return int.from_bytes(socket.inet_aton(host), sys.byteorder)
    except OSError:
        return 0


def unpacked_ipv4(value: int) -> str:
    """The dotted address of an IPv4 address as the clock page stores it (the inverse of :func:`packed_ipv4`)."""
    return socket.inet_ntoa(value.to_bytes(4, sys.byteorder))


__all__ = ["MAX_ADDRESSES", "TCP", "UDP", "ChannelBook", "packed_ipv4", "unpacked_ipv4"]
