"""A datagram net: UDP sockets on 127.0.0.1 shared by host programs, in-process devices and taps.

The serial line's shape (:class:`~hilbench.transports.medium.Medium`: add_host,
add_device, add_tap, start, close) for datagrams, which keep their boundaries
and their addresses:

- **host ports** are bound UDP sockets (:class:`~hilbench.transports.udp.UdpPort`):
  the endpoint's own port (an agent's 8888), and sockets a device asks for with
  :meth:`DatagramDevicePort.open_socket` (a FreeRTPS node's metatraffic and user ports).
  A datagram arriving on a socket a device owns reaches that device; one on a
  shared socket (the endpoint's) reaches every device.
- **devices** hear ``on_datagram(data, src, dst, t)`` and send with
  :meth:`DatagramDevicePort.send` (from a socket they name, by default the endpoint's),
  so replies leave from the port the host wrote to, as from a real agent.
- **taps** see every datagram once, in and out, as ``tap(t, source, data, addr)``
  with ``addr = (source host, source port, destination host, destination port)``;
  three-argument taps (``tap(t, source, data)``) get the payload alone. The source
  is the sending device's name, or ``udp:HOST:PORT`` for a datagram from outside.
  A datagram one device sends to another socket of the same net is tapped when sent.

One thread runs the net: it reads the sockets, runs timers (:meth:`~DatagramMedium.call_at`) and
every device callback, so device logic needs no locks. Loopback is not paced: a
datagram leaves when it is sent (``t`` delays it).
"""

from __future__ import annotations

import inspect
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hilbench.transports.clock import WALL, WallClock, wait
from hilbench.transports.medium import DevicePort
from hilbench.transports.medium_loop import LoopMedium
from hilbench.transports.udp import UdpPort

log = logging.getLogger(__name__)

Address = tuple[str, int]
#: Datagrams read from one socket per wake-up, so one busy socket cannot starve the others.
READ_BATCH = 64


@dataclass
class DatagramMediumStats:
    """Counters of the net."""

    datagrams_in: int = 0
    datagrams_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    send_errors: int = 0
    callback_errors: int = 0
    by_source: dict[str, int] = field(default_factory=dict)


class DatagramMedium(LoopMedium):
    """A datagram net; see the module docstring. ``baud`` and ``paced`` are accepted and ignored."""

    kind = "datagram"
    thread_prefix = "net"

    def __init__(self, name: str, baud: int | None = None, *, paced: bool = False, clock: WallClock = WALL) -> None:
        super().__init__(name, baud, paced=False, clock=clock)
        self.stats = DatagramMediumStats()
        self._owner: dict[int, str | None] = {}  # id(socket) -> device name owning it (None: shared)
        self._sockets: list[UdpPort] = []
        self._own_addresses: set[Address] = set()
        self._tap_kinds: dict[int, bool] = {}  # id(tap) -> takes addresses
        self._opened: list[UdpPort] = []
        # In-process peers of a virtual bench (:meth:`vt_connect`): address -> deliver(data, src)
        self._peers: dict[Address, Callable[[bytes, Address], None]] = {}

    # ------------------------------------------------------------------ wiring

    def add_host(self, port: Any, *, listen_only: bool = False, owner: str | None = None) -> None:
        """Attach a bound UDP socket (a host port); ``owner`` names the only device that hears it."""
        super().add_host(port, listen_only=listen_only)
        with self._lock:
            self._sockets.append(port)
            self._owner[id(port)] = owner
            self._own_addresses.add(tuple(port.address))
        self._wake()

    def add_device(self, device: Any) -> DatagramDevicePort:
        """Attach a device (``on_datagram(data, src, dst, t)``); it sends through the returned port."""
        with self._lock:
            self._devices.append(device)
        return DatagramDevicePort(self, device.name)

    def add_tap(self, tap: Callable[..., None]) -> None:
        """Attach a tap: ``tap(t, source, data, addr)``, or ``tap(t, source, data)`` if it takes three."""
        super().add_tap(tap)
        self._tap_kinds[id(tap)] = _takes_four(tap)

    def open_socket(self, owner: str | None, host: str = "127.0.0.1", port: int = 0, *,
                    name: str | None = None) -> UdpPort:
        """Bind a socket for device ``owner`` (None: shared); closed with the net. Raises OSError if taken."""
        sock = UdpPort(name or f"{owner or self.name}:{port}", host, port)
        self._opened.append(sock)
        self.add_host(sock, owner=owner)
        return sock

    @property
    def sockets(self) -> list[UdpPort]:
        return list(self._sockets)

    def socket_of(self, owner: str | None) -> UdpPort | None:
        """The first socket ``owner`` owns (None: the first shared one, the endpoint's)."""
        for s in self._sockets:
            if self._owner.get(id(s)) == owner:
                return s
        return None

    # ------------------------------------------------------------------ sending

    def send(self, source: str, data: bytes, dst: Address, *, via: UdpPort | None = None,
             t: float | None = None) -> None:
        """Send ``data`` from device ``source`` to ``dst`` (from ``via``, by default its own socket or the
        endpoint's) now or at time ``t``; thread-safe."""
        data = bytes(data)
        if via is None:
            via = self.socket_of(source) or self.socket_of(None)
        if via is None:
            raise RuntimeError(f"datagram net {self.name!r} has no socket to send from")
        if t is None and threading.get_ident() == self._ident:
            self._send_now(source, data, dst, via)
        else:
            self.call_at(t, lambda: self._send_now(source, data, dst, via))

    def _send_now(self, source: str, data: bytes, dst: Address, via: UdpPort) -> None:
        stats = self.stats
        peer = self._peers.get(dst) if self._peers else None
        if peer is not None:
            peer(data, via.address)  # an in-process participant: it hears it now (virtual time)
        elif not via.send_to(data, dst):
            stats.send_errors += 1
            return
        stats.datagrams_out += 1
        stats.bytes_out += len(data)
        stats.by_source[source] = stats.by_source.get(source, 0) + len(data)
        src = via.address
        self._tap(self._now(), source, data, (src[0], src[1], dst[0], dst[1]))

    def transmit(self, source: str, data: bytes, *, t: float | None = None, gap: float = 0.0,
                 baud: int | None = None) -> float:
        """The serial line's call, for devices written for one: to every recent sender of the endpoint."""
        sock = self.socket_of(None)
        when = (self._now() if t is None else t) + gap
        if sock is not None:
            for peer in sock.targets():
                self.send(source, data, peer, via=sock, t=when)
        return when

    def _tap(self, t: float, source: str, data: bytes, addr: tuple[str, int, str, int]) -> None:
        for tap in self._taps:
            try:
                if self._tap_kinds.get(id(tap), False):
                    tap(t, source, data, addr)
                else:
                    tap(t, source, data)
            except Exception:
                self.stats.callback_errors += 1
                log.exception("tap failed")

    # ------------------------------------------------------------------ receiving

    def _receive(self, sock: UdpPort, listen_only: bool) -> None:
        owner = self._owner.get(id(sock))
        for _ in range(READ_BATCH):
            got = sock.recv_from()
            if got is None:
                return
            self._heard(sock, owner, listen_only, *got)

    def _heard(self, sock: UdpPort, owner: str | None, listen_only: bool, data: bytes, src: Address) -> None:
        """One datagram from ``src`` arrived on ``sock``: tap it, hand it to the devices that hear that socket."""
        dst = sock.address
        t = self._now()
        self.stats.datagrams_in += 1
        self.stats.bytes_in += len(data)
        if tuple(src) not in self._own_addresses:  # from inside the net: tapped when it was sent
            self._tap(t, f"udp:{src[0]}:{src[1]}", data, (src[0], src[1], dst[0], dst[1]))
        if listen_only:
            return
        for device in self._devices:
            if owner is not None and device.name != owner:
                continue
            try:
                device.on_datagram(data, src, dst, t)
            except Exception:  # one faulty device must not stop the net
                self.stats.callback_errors += 1
                log.exception("device %s failed on a %d-byte datagram", device.name, len(data))

    # ------------------------------------------------------------------ thread (timers: LoopMedium)

    def _run(self) -> None:
        waker = self._waker
        while not self._stop.is_set():
            with self._lock:
                deadline = self._events[0][0] if self._events else None
                hosts = list(self._hosts)
            fds = [p.fileno() for p, _ in hosts] + [waker.fd]
            try:
                ready = wait(fds, deadline)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                raise
            if ready:
                for port, listen_only in hosts:
                    if port.fileno() in ready:
                        self._receive(port, listen_only)
                if waker.fd in ready:
                    waker.drain()
            self._run_due()

    # ------------------------------------------------------------------ virtual time (a VirtualLoop runs it)

    def vt_fds(self) -> list[int]:
        return [p.fileno() for p, _ in list(self._hosts)] + [self._waker.fd]

    def vt_read(self, ready: list[int], now: float) -> bool:
        """Datagrams keep their boundaries: each is heard at ``now`` as it is read."""
        got = super().vt_read(ready, now)
        for port, listen_only in list(self._hosts):
            if port.fileno() in ready:
                self._receive(port, listen_only)
                got = True
        return got

    def vt_connect(self, address: Address, deliver: Callable[[bytes, Address], None]) -> None:
        """An in-process peer at ``address`` (a bench participant, such as the rover board's XRCE client):
        what the net sends there is handed to ``deliver(data, src)`` in the loop's thread at the instant it
        is sent (tapped as sent), not written to a socket, so its time does not depend on the kernel."""
        self._peers[(address[0], address[1])] = deliver

    def vt_disconnect(self, address: Address) -> None:
        self._peers.pop((address[0], address[1]), None)

    def vt_inject(self, data: bytes, src: Address, dst: Address) -> bool:
        """A datagram from the in-process peer at ``src`` to the net's socket at ``dst``: it arrives at the
        clock's ``now``, as an event in the loop's sequence (any thread). False if no socket of the net is
        at ``dst``."""
        dst = (dst[0], dst[1])
        for sock, listen_only in list(self._hosts):
            if tuple(sock.address) == dst:
                owner = self._owner.get(id(sock))
                args = (sock, owner, listen_only, bytes(data), (src[0], src[1]))
                self.call_at(None, lambda a=args: self._heard(*a))
                return True
        return False

    def close(self) -> None:
        """Stop the net, release its wake-up pipe, close the sockets it opened for devices."""
        super().close()
        for sock in self._opened:
            sock.close()


class DatagramDevicePort(DevicePort):
    """What a device on a datagram net holds: send, timers, sockets of its own."""

    @property
    def net(self) -> DatagramMedium:
        return self._medium  # type: ignore[return-value]

    def send(self, data: bytes, dst: Address, *, via: UdpPort | None = None, t: float | None = None) -> None:
        """Send one datagram to ``dst`` (from ``via``, else the device's own socket or the endpoint's)."""
        self.net.send(self.name, data, dst, via=via, t=t)

    def open_socket(self, host: str = "127.0.0.1", port: int = 0) -> UdpPort:
        """A socket only this device hears (raises OSError if the port is taken)."""
        return self.net.open_socket(self.name, host, port, name=f"{self.name}:{port}")

    def call_at(self, t: float | None, fn: Callable[[], None]) -> None:  # type: ignore[override]
        self.net.call_at(t, fn)


def _takes_four(fn: Callable[..., Any]) -> bool:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return False
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(positional) >= 4 or any(p.kind == p.VAR_POSITIONAL for p in params)


__all__ = ["Address", "DatagramMedium", "DatagramDevicePort", "DatagramMediumStats"]
