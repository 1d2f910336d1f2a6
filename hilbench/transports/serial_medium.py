"""A multi-drop half-duplex serial line (RS-485) shared by host ports, in-process devices and taps.

Everything one party transmits reaches every other party, as on a real bus:
host programs on pseudo-terminals, emulated devices in this process, and taps
(monitor, recorder) that see every byte with its time and sender. One thread
runs the line: it reads the host ports, delivers transmissions, and runs the
devices' callbacks, so device logic never needs locks.

Timing has two modes. Unpaced (default), bytes arrive as soon as they are
sent, the fastest way to run tests. Paced, the line models wire time: a
transmission of n bytes occupies the bus for 10 n / baud seconds, starts no
earlier than the end of the previous one, and reaches the other parties when
its last byte would have; devices add their reply delays (Return Delay Time)
on top. Clients then see the timing of the real bus.

How a paced line keeps that timing on a busy machine (:mod:`hilbench.transports.clock`):
every delivery time is computed when the transmission is queued (from the
previous one's end, so a late wake-up never shifts the ones after it); the
thread sleeps until input or the next delivery, asking for the wake-up as much
earlier as this machine's wake-ups are late and polling only the microseconds
left (:class:`~hilbench.transports.clock.Waiter`); deliveries
due within :data:`DELIVERY_GRANULE` of each other share one wake-up and one
write to each host (late by at most that, never early; taps still get each
transmission's exact time); and it asks for SCHED_FIFO where the OS allows it
(``realtime``; :attr:`SerialMedium.scheduling` says what it got), so its
wake-ups preempt CPU-bound neighbours, and that idle CPUs stay awake while it
runs (:attr:`SerialMedium.cpu_latency`). ``HILBENCH_REALTIME=0`` in the
environment keeps every line under the normal scheduler. :attr:`SerialMedium.stats`
counts how late deliveries were against the model.

A host that writes faster than the wire is held back as a USB adapter holds
it: the adapter's driver takes :data:`HOST_FIFO` bytes (Linux's usb-serial
write FIFO is one page) and then its writer waits. A paced line reads a host
port with :attr:`~hilbench.transports.host_port.HostPort.backpressure` (a pty,
a TCP port) only while its bytes not yet on the wire need less than half of
that (in the host's own byte time), and then at most the rest; otherwise it
stops watching the port until they do (:attr:`SerialMediumStats.held_back`), so the
kernel's buffer fills and the client's write() blocks (or a non-blocking one
returns EAGAIN). An unpaced line delivers at once; it holds a host back only
for a device that paces its own receiver (``input_backlog``: the rover
board's UART). What a pty itself buffers in the kernel (18 KiB on a Linux 6
VM) comes on top, as on any pty; ``hilbench run``'s drain and flush still
take everything the client wrote (:meth:`SerialMedium.drain_host`).
"""

from __future__ import annotations

import heapq
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from hilbench.transports.clock import WALL, Waiter, WallClock, reduce_timer_slack, wait
from hilbench.transports.host_port import HostPort
from hilbench.transports.medium import DevicePort, Tap
from hilbench.transports.medium_loop import LoopMedium

log = logging.getLogger(__name__)

#: check_quiet looks again after 10 us, 20 us, ... while a client is inside write(), 10 times (~10 ms):
#: soon enough to beat the client's next drain when this thread had preempted it.
QUIET_RETRY = 10e-6
QUIET_RETRIES = 10
#: A paced line joins deliveries due within this many seconds into one wake-up (see _next_wake): a
#: high-speed USB adapter hands the host its bytes in 125 us microframes, so no client of real hardware
#: sees finer timing. HILBENCH_GRANULE_US overrides it (0: a wake-up for every transmission).
DELIVERY_GRANULE = float(os.environ.get("HILBENCH_GRANULE_US", "125")) * 1e-6
#: A paced line hands the last deliveries of a burst due within this many seconds of its very last one over
#: with it: writing, leaving the CPU for the kernel's tty worker and the client, and being woken again take
#: a line thread about this long on a VM (see _next_wake), so an earlier wake-up of its own would only add
#: one more preemption of the client while it parses the burst's tail.
TAIL_JOIN = 45e-6
#: A host port (with backpressure) is read while its bytes not yet on the wire are fewer than half of this,
#: and then up to this many (see the module docstring): what a USB-serial adapter takes before its writer
#: waits. Linux's usb-serial drivers (FTDI, CH340, CP210x, PL2303) queue a write in a FIFO of one page,
#: 4096 bytes; the chip's own buffer adds 32 (CH340) to 1024 (FT232H) bytes.
HOST_FIFO = 4096


class Device(Protocol):
    """An in-process party on the line, e.g. a group of emulated servos.

    It may also have ``on_port_event(event, t)`` to hear the host's modem lines, BREAK and
    settings (:mod:`hilbench.transports.port_state`).
    """

    name: str

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        """Bytes another party sent, as received at time ``t``; ``baud`` is the sender's line rate."""

    # A device that paces its own receiver on an unpaced line (a UART in virtual time) may also have
    # ``input_backlog(now) -> float``: seconds until it has taken in the bytes handed to it. Hosts are then
    # held back while that exceeds their share of HOST_FIFO, as on a paced line (module docstring).


@dataclass
class SerialMediumStats:
    """Counters of the line, by sender."""

    transmissions: int = 0
    bytes: int = 0
    by_source: dict[str, int] = field(default_factory=dict)
    callback_errors: int = 0
    #: How late the line handed transmissions over against its own wire model (paced lines): their
    #: number, the sum and the largest lateness in seconds, and how many were over a millisecond late.
    late_count: int = 0
    late_total: float = 0.0
    late_max: float = 0.0
    late_over_1ms: int = 0
    #: Times a host port was left unread because its bytes ahead of the wire had reached HOST_FIFO (its
    #: writer then waits, as on a USB adapter), and the seconds it was left so, in all.
    held_back: int = 0
    held_back_s: float = 0.0


class SerialMedium(LoopMedium):
    """One shared serial line. Add hosts, devices and taps, then :meth:`start` it.

    Its thread, timers and wake-ups are :class:`~hilbench.transports.medium_loop.LoopMedium`'s; a
    delivery is a joinable event (see :meth:`_next_wake`), and :meth:`_run_due` holds back the host
    writes of deliveries due together (see there).
    """

    kind = "serial"
    thread_prefix = "line"

    def __init__(self, name: str, baud: int, *, paced: bool = False, realtime: bool | None = None,
                 clock: WallClock = WALL) -> None:
        super().__init__(name, baud, paced=paced, clock=clock)
        self.stats = SerialMediumStats()  #: transmissions, bytes and lateness against the wire-time model
        #: Run the line's thread under SCHED_FIFO if the OS allows it (None: when paced, unless
        #: HILBENCH_REALTIME=0). Unpaced lines gain nothing from it.
        self.realtime = (paced and os.environ.get("HILBENCH_REALTIME", "1") != "0") if realtime is None \
            else realtime
        self._busy_until = 0.0
        self._last_end: dict[str, float] = {}  # by sender: when its latest transmission is delivered
        self._pending: dict[str, int] = {}  # by sender: transmissions not delivered yet
        self._quiet: dict[str, tuple] = {}  # host name -> (port, watcher, ready, keen): see watch_quiet
        self._quiet_retrying: set[str] = set()
        # Bumped (under the lock) when hosts change or one is held back or let go: the thread rebuilds its
        # descriptor table.
        self._hosts_version = 0
        self._out: dict[int, tuple] | None = None  # host writes held back while due deliveries run
        self._receivers: list = []  # devices pacing their own receiver (input_backlog)
        self._sent_baud: dict[str, int | None] = {}  # by bounded host: the baud of its latest transmission
        self._held: dict[int, float] = {}  # id(host port) -> since when it is left unread (line thread)

    # ------------------------------------------------------------------ wiring

    def add_host(self, endpoint, *, listen_only: bool = False) -> None:
        """Attach a host port (pty, UDP, TCP, ...); ``listen_only`` ignores what it sends."""
        super().add_host(endpoint, listen_only=listen_only)
        with self._lock:
            self._hosts_version += 1
        self._wake()

    def add_device(self, device) -> DevicePort:
        """Attach an in-process device (see :class:`Device`)."""
        port = super().add_device(device)
        if callable(getattr(device, "input_backlog", None)):
            with self._lock:
                self._receivers.append(device)
                self._hosts_version += 1  # (which hosts are held back changes)
            self._wake()
        return port

    # ------------------------------------------------------------------ sending

    def byte_time(self, baud: int | None = None) -> float:
        """Seconds per byte at 8N1 (10 bit times)."""
        return 10.0 / (baud or self.baud)

    def transmit(
        self, source: str, data: bytes, *, t: float | None = None, gap: float = 0.0, baud: int | None = None
    ) -> float:
        """Put ``data`` from ``source`` on the line; returns the time it is delivered.

        Paced: it starts ``gap`` seconds after both ``t`` and the end of the
        previous transmission, and is delivered when its last byte is on the
        wire. Unpaced: it is delivered at ``t + gap``. Thread-safe.
        """
        data = bytes(data)
        with self._lock:
            t = self._now() if t is None else t
            if self.paced:
                start = max(t, self._busy_until) + gap
                end = start + len(data) * self.byte_time(baud)
                self._busy_until = end
            else:
                end = t + gap
            self._last_end[source] = end
            self._pending[source] = self._pending.get(source, 0) + 1
            self._push(end, lambda: self._deliver(source, data, end, baud), True)
        if threading.get_ident() != self._ident:
            self._wake()
        return end

    def backlog(self, source: str) -> float:
        """Seconds until everything ``source`` transmitted is delivered, and taken in by a device that paces
        its own receiver (0 when it is; on an unpaced line without such a device always 0): a host port that
        reads its client only while this is small bounds what waits for the wire."""
        return max(0.0, self._ahead(source, self._now()))

    def _ahead(self, source: str, now: float) -> float:
        ahead = self._last_end.get(source, 0.0) - now
        for device in self._receivers:
            try:
                taking = device.input_backlog(now)
            except Exception:  # one faulty device must not stop the line
                self.stats.callback_errors += 1
                log.exception("device %s failed to tell its input backlog", device.name)
                continue
            if taking > ahead:
                ahead = taking
        return ahead

    def _deliver(self, source: str, data: bytes, t: float, baud: int | None) -> None:
        stats = self.stats
        stats.transmissions += 1
        stats.bytes += len(data)
        stats.by_source[source] = stats.by_source.get(source, 0) + len(data)
        out = self._out
        for endpoint, _ in self._hosts:
            if endpoint.name != source:
                if out is None:
                    endpoint.write(data)
                elif (buf := out.get(id(endpoint))) is not None:
                    buf[1].extend(data)
                else:
                    out[id(endpoint)] = (endpoint, bytearray(data))
        for device in self._devices:
            if device.name != source:
                try:
                    device.on_bytes(data, t, baud)
                except Exception:  # one faulty device must not stop the line
                    stats.callback_errors += 1
                    log.exception("device %s failed on %d bytes", device.name, len(data))
        for tap in self._taps:
            try:
                tap(t, source, data)
            except Exception:
                stats.callback_errors += 1
                log.exception("tap failed")
        with self._lock:
            left = self._pending[source] = self._pending[source] - 1
            watched = self._quiet.get(source) if not left else None
        if watched is not None:  # after the devices heard it, before anything they answer reaches the host
            self.check_quiet(watched[0])

    # ------------------------------------------------------------------ running (timers, thread: LoopMedium)

    def _run(self) -> None:
        events, lock, stop, waker, paced, clock = self._events, self._lock, self._stop, self._waker, self.paced, \
            self._now
        wake_r = waker.fd
        version = -1
        waiter = Waiter() if paced else wait  # a paced line keeps its deliveries' times
        fds: list[int] = []
        by_fd: dict[int, tuple] = {}
        hosts: list[tuple] = []
        held = self._held
        fixed = True  # every host's descriptors stay the same (a pty's do; a TCP port's follow its client)
        while not stop.is_set():
            if version != self._hosts_version or not fixed:
                with lock:
                    version = self._hosts_version
                    hosts = list(self._hosts)
                    bounded = paced or bool(self._receivers)  # (else what is read is delivered at once)
                # A host held back is not watched (its writer waits, see HOST_FIFO) until its timer ends it.
                by_fd = {fd: (ep, listen_only, bounded and not listen_only and getattr(ep, "backpressure", False))
                         for ep, listen_only in hosts if id(ep) not in held for fd in ep.filenos()}
                fds = [*by_fd, wake_r]
                fixed = all(type(ep).filenos is HostPort.filenos for ep, _ in hosts)
            # (stale is fine: pushes from other threads wake us)
            deadline, last = self._next_wake() if events else (None, False)
            # The host writes the due deliveries held back go out only now, just before the wait: bytes
            # written to a pty reach the client once the kernel's tty worker has run, usually on this CPU
            # as soon as this thread sleeps, so everything this thread had to do first is already done.
            wrote = self._flush_out()
            self._out = None
            # After a write, only the burst's last delivery, whose timing ends the client's wait, is worth
            # keeping the worker waiting (see Waiter). With nothing due and fixed descriptors the wait has
            # no timeout (input and _wake end it): a timed sleep arms a timer first, which on a VM takes
            # ~10 us, between the burst's last write and the worker that hands it to the client.
            ready = waiter(fds, deadline, None if fixed else 0.5, leave_cpu=wrote and not last)
            if ready:
                now = clock()
                taken: set[int] = set()
                for fd in ready:
                    if fd == wake_r:
                        waker.drain()
                        continue
                    host = by_fd.get(fd)
                    if host is not None and id(host[0]) not in taken:  # (a port may have several descriptors)
                        taken.add(id(host[0]))
                        self._take(host[0], host[1], now, host[2])
            self._run_due()

    def _next_wake(self) -> tuple[float, bool]:
        """When to wake for the pending events: the first one's time, or on a paced line the last delivery
        due within :data:`DELIVERY_GRANULE` of it, so that a burst (a Sync Read's twenty replies, 33-75 us
        apart) costs a few wake-ups instead of one each (a timed sleep costs 15-20 us of CPU on a VM).
        Deliveries are then up to a granule late, never early; nothing else waits. When only deliveries
        are pending (a burst), its tail, the deliveries due within :data:`TAIL_JOIN` of its last one, has
        a wake-up of its own at that last one's time, so the client has no more than the tail left to
        take in when the wire model says the burst is over.
        On a paced line it also says whether no delivery is due after that wake-up (the burst's last)."""
        with self._lock:
            events = self._events
            first = events[0]
            granule = DELIVERY_GRANULE
            if not self.paced:
                return first[0], False  # (an unpaced line's waits never poll: nothing to tell)
            grouped = granule and first[3]
            limit = first[0] + granule if grouped else first[0]
            end = 0.0  # the last delivery pending
            timers = False
            for t, _, _, joinable in events:
                if not joinable:
                    timers = True
                    if t < limit:
                        limit = t  # a timer or line event is never kept waiting
                elif t > end:
                    end = t
            if not grouped:
                wake = first[0]
            else:
                if not timers:
                    limit = min(limit, end - TAIL_JOIN)
                joined = [t for t, _, _, joinable in events if t <= limit and joinable]
                wake = max(joined) if joined else end
            return wake, wake >= end

    def _take(self, endpoint, listen_only: bool, now: float, bounded: bool = False) -> tuple[int, float]:
        """Read what a host port has and put it on the line; returns (bytes, delivery time). ``bounded``: read
        only while its bytes ahead of the wire are under half of :data:`HOST_FIFO`, and at most the rest of
        it; else hold the port back (unwatched) until they are. With clients in lockstep (:meth:`vt_defer_input`)
        :meth:`_vt_take` replaces it."""
        if not bounded:
            data = endpoint.read()
            if data and not listen_only:
                return len(data), self.transmit(endpoint.name, data, t=now, baud=endpoint.client_baud())
            return len(data), now
        name = endpoint.name
        ahead = self._last_end.get(name, 0.0) - now  # (_ahead, inlined: the paced line's hot path)
        if self._receivers:
            ahead = self._ahead(name, now)
        size = HOST_FIFO
        if ahead > 0.0:  # in the byte time its bytes ahead were sent at
            byte_time = self.byte_time(self._sent_baud.get(name))
            size = HOST_FIFO - int(ahead / byte_time)
            if size < HOST_FIFO // 2:
                self._hold(endpoint, now + ahead - (HOST_FIFO // 2) * byte_time)
                return 0, now
        data = endpoint.read(size)
        if not data:
            return 0, now
        baud = self._sent_baud[name] = endpoint.client_baud()
        return len(data), self.transmit(name, data, t=now, baud=baud)

    def _hold(self, endpoint, until: float) -> None:
        """Leave ``endpoint`` unread until ``until`` (line thread): its writer waits meanwhile."""
        key = id(endpoint)
        if key in self._held:
            return
        self._held[key] = self._now()
        self.stats.held_back += 1
        with self._lock:
            self._hosts_version += 1
            self._push(until, lambda: self._release(key))

    def _release(self, key: int) -> None:
        since = self._held.pop(key, None)
        if since is not None:
            with self._lock:
                self._hosts_version += 1
            self.stats.held_back_s += self._now() - since

    def drain_host(self, port) -> tuple[int, float]:
        """Take everything ``port`` already sent, in the line's thread; returns (bytes taken, when the
        last byte it ever sent is delivered: later than now on a paced line still sending them).

        A pty master's non-blocking read first runs the tty layer's pending buffer
        work, so "nothing to read" means every byte a client's write() returned for
        has been taken.
        """
        with self._lock:
            end = max(self._now(), self._last_end.get(port.name, 0.0))  # bytes taken before, on the wire
        taken = 0
        for endpoint, listen_only in list(self._hosts):
            if endpoint is not port:
                continue
            while True:  # (everything: a drain waits for all the client wrote, however much is ahead)
                n, t = self._take(endpoint, listen_only, self._now())
                if not n:
                    break
                taken += n
                end = max(end, t)
        if self.vt_defer:  # (in program order: what the client wrote before it asked goes first)
            end = max(end, self.vt_commit(self._now(), port))
        return taken, end

    def watch_quiet(self, port, watcher: Callable[[int], None] | None, ready: Callable[[], bool] | None = None,
                    keen: Callable[[], bool] | None = None) -> bool:
        """Tell ``watcher(ns)``, in the line's thread, each time everything host ``port`` wrote before
        ``CLOCK_MONOTONIC`` ``ns`` has been delivered (checked after each of its transmissions is
        delivered, and once now); None stops watching. ``ready()``, read after the clock, says whether
        no write to the port is under way; if one is and ``keen()`` (someone waits for the news), the
        check is repeated a little later. ``hilbench run``'s delivery ledger uses it.
        """
        with self._lock:
            if watcher is None:
                self._quiet.pop(port.name, None)
                return True
            self._quiet[port.name] = (port, watcher, ready, keen)
        if not self.paced:  # paced lines already wake precisely; the retries need it too
            self.call_at(None, reduce_timer_slack)
        self.call_at(None, lambda: self.check_quiet(port))
        return True

    def check_quiet(self, port, _retry: int = 0) -> bool:
        """In the line's thread: if nothing ``port`` sent awaits delivery, no write to it is under way
        and a non-blocking read finds nothing more, tell its watcher (see :meth:`watch_quiet`). What the
        read finds goes on the line."""
        with self._lock:
            if _retry:
                self._quiet_retrying.discard(port.name)
            watched = self._quiet.get(port.name)
            if watched is None or self._pending.get(port.name, 0):
                return False
            hosts = [(ep, listen_only) for ep, listen_only in self._hosts if ep is port]
        _, watcher, ready, keen = watched
        # The clock before the rest: a write stamped earlier is counted in ready() or has returned, and then
        # its bytes are there for the read to find (a pty master's read first runs the tty layer's work).
        t0 = self._board_ns()
        if ready is not None and not ready():
            # A client is inside write() (often preempted by this very thread on return): look again soon,
            # less and less often, and give up (every drain then asks) if it never ends.
            if keen is not None and not keen():
                return False
            with self._lock:
                if _retry < QUIET_RETRIES and port.name not in self._quiet_retrying:  # one series at a time
                    self._quiet_retrying.add(port.name)
                    self._push(self._now() + QUIET_RETRY * 2 ** _retry,
                               lambda: self.check_quiet(port, _retry + 1))
            return False
        for endpoint, listen_only in hosts:
            if listen_only or id(endpoint) in self._held:
                return False  # a port whose bytes are never delivered, or one held back with bytes waiting
            bounded = getattr(endpoint, "backpressure", False) and (self.paced or bool(self._receivers))
            if self._take(endpoint, listen_only, self._now(), bounded)[0] or id(endpoint) in self._held:
                return False  # new bytes (or some left unread, held back): not quiet yet
        try:
            watcher(t0)
        except Exception:
            self.stats.callback_errors += 1
            log.exception("quiet watcher of %s failed", port.name)
        return True

    @staticmethod
    def _board_ns() -> int:
        # The delivery ledger's stamps are in the real CLOCK_MONOTONIC domain of the shim's writes (a
        # client's write stamped before this read is counted), whatever the bench's clock: wall-clock.
        return time.monotonic_ns()  # wall-clock: the delivery ledger's domain

    def _run_due(self) -> None:
        """Run what is due. Deliveries due together reach each host port in one write (a pty write costs
        about as much as a reply's emulation), held back in ``_out`` for the loop to make just before it
        waits; anything else first flushes what is pending, so the order the host sees stays the order of
        the line. A paced line also counts how late each delivery is against its wire model."""
        # LoopMedium's loop, with this line's bookkeeping inline: a hook called per event (tried) costs
        # ~55 ns of the ~480 ns each due event takes here (+12 %; 20-40 events per 20-servo cycle).
        events, lock, paced, clock = self._events, self._lock, self.paced, self._now
        if self._out is None:
            self._out = {}
        try:
            while True:
                with lock:
                    if not events or events[0][0] > (now := clock()):
                        break
                    t, _, fn, joinable = heapq.heappop(events)
                if not joinable:
                    self._flush_out()
                elif paced:
                    stats = self.stats
                    late = now - t
                    stats.late_count += 1
                    stats.late_total += late
                    if late > stats.late_max:
                        stats.late_max = late
                    if late > 1e-3:
                        stats.late_over_1ms += 1
                try:
                    fn()
                except Exception:  # one faulty callback must not stop the line (as on every LoopMedium)
                    self.stats.callback_errors += 1
                    log.exception("timed callback failed on line %s", self.name)
        except BaseException:  # (the thread is ending: what was due still reaches the hosts)
            self._flush_out()
            self._out = None
            raise

    def _flush_out(self) -> bool:
        out = self._out
        if not out:
            return False
        for endpoint, data in out.values():
            endpoint.write(bytes(data))
        out.clear()
        return True

    # ------------------------------------------------------------------ virtual time (a VirtualLoop runs it)
    # (vt_thread, vt_head, vt_deadline and vt_poll are LoopMedium's)

    def vt_attach(self, loop) -> None:
        """Run in ``loop`` (a :class:`~hilbench.transports.virtual_loop.VirtualLoop`) instead of a thread of
        its own: its events join the loop's one sequence; deliveries happen at their exact model times."""
        super().vt_attach(loop)
        self._vt_version = -1
        self._vt_fds: dict[int, tuple] = {}
        self._vt_in: dict[int, tuple[Any, bytearray]] = {}  # id(host port) -> (port, bytes read, not yet sent)

    def vt_run_one(self) -> None:
        """Run the next event (the loop chose it); host writes of deliveries wait for :meth:`vt_flush`."""
        if self._out is None:
            self._out = {}
        with self._lock:
            _, _, fn, joinable = heapq.heappop(self._events)
        if not joinable:
            self._flush_out()  # (what the host sees stays in the line's order)
        try:
            fn()
        except Exception:  # one faulty callback must not stop the bench
            self.stats.callback_errors += 1
            log.exception("timed callback failed on line %s", self.name)

    def vt_flush(self) -> None:
        """End of the bench phase: each host port gets what was delivered to it, in one write."""
        self._flush_out()
        self._out = None

    def vt_fds(self) -> list[int]:
        """The descriptors the loop looks at for this line: its hosts not held back, and its wake-up pipe."""
        if self._vt_version != self._hosts_version or not all(
                type(ep).filenos is HostPort.filenos for ep, _ in self._hosts):
            with self._lock:
                self._vt_version = self._hosts_version
                hosts = list(self._hosts)
            self._vt_fds = {fd: (ep, listen_only, not listen_only and getattr(ep, "backpressure", False))
                            for ep, listen_only in hosts if id(ep) not in self._held for fd in ep.filenos()}
        return [*self._vt_fds, self._waker.fd]

    vt_defer = False

    def vt_defer_input(self) -> None:
        """Clients run in lockstep with the loop: what they write is read as it comes and sent when they all
        wait (:meth:`vt_commit`), one transmission per port per instant. Read and sent at once, a client's
        writes at one instant made one transmission or two depending on whether the loop read between them
        (the official SDK writes its Sync Write and the next Sync Read back to back), so the devices' and
        the taps' records differed from run to run. (An instance attribute replaces :meth:`_take`: the
        wall-clock line's hot path has no branch for it.)"""
        self.vt_defer = True
        self._take = self._vt_take  # type: ignore[method-assign]

    def _vt_take(self, endpoint, listen_only: bool, now: float, bounded: bool = False) -> tuple[int, float]:
        """:meth:`_take` with clients in lockstep: what is read waits for :meth:`vt_commit`. ``bounded``: the
        wall clock's rule in virtual time: the bytes ahead of the wire and those read but not yet sent stay
        within :data:`HOST_FIFO`, and with half of it still to go out the port is held back; either way its
        writer waits in the kernel, and :meth:`vt_refuses` tells the lockstep that time may move meanwhile."""
        size = self._vt_room(endpoint, now) if bounded else 65536
        if size <= 0:
            return 0, now
        data = endpoint.read(size)
        if not data or listen_only:
            return len(data), now
        held = self._vt_in.get(id(endpoint))
        if held is None:
            held = self._vt_in[id(endpoint)] = (endpoint, bytearray())
        held[1].extend(data)
        self._sent_baud[endpoint.name] = endpoint.client_baud()
        return len(data), now

    def _vt_room(self, endpoint, now: float) -> int:
        """How many bytes the line may read from ``endpoint`` now (0: none; held back if the wire has more
        than half of :data:`HOST_FIFO` still to send)."""
        waiting, on_wire, byte_time = self._vt_backlog(endpoint, now)
        if on_wire > HOST_FIFO // 2:
            self._hold(endpoint, now + (on_wire - HOST_FIFO // 2) * byte_time)
            return 0
        return HOST_FIFO - waiting - on_wire

    def _vt_backlog(self, endpoint, now: float) -> tuple[int, int, float]:
        """(bytes read and waiting for :meth:`vt_commit`, bytes ahead of the wire or of a receiver pacing
        itself, in the sender's byte time; that byte time)."""
        held = self._vt_in.get(id(endpoint))
        name = endpoint.name
        ahead = self._ahead(name, now) if self._receivers else self._last_end.get(name, 0.0) - now
        byte_time = self.byte_time(self._sent_baud.get(name))
        # (rounded: virtual time lands exactly on a release, where a floor of 2048.0000001 byte times would
        # hold the port again for a femtosecond, and again)
        on_wire = round(ahead / byte_time) if ahead > 0.0 else 0
        return (len(held[1]) if held is not None else 0), on_wire, byte_time

    def vt_refuses(self, port: Any) -> bool:
        """Whether the line leaves ``port``'s bytes unread on purpose (held back, or its share of
        :data:`HOST_FIFO` full): its writer waits for the wire, so the lockstep does not count them in flight."""
        if id(port) in self._held:
            return True
        if not any(ep is port for ep, _ in self._hosts):
            return False
        waiting, on_wire, _ = self._vt_backlog(port, self._now())
        return waiting + on_wire >= HOST_FIFO

    def vt_held(self) -> bool:
        """Whether client bytes were read and wait for :meth:`vt_commit`."""
        return bool(self._vt_in)

    def vt_commit(self, now: float, port: Any = None) -> float:
        """Send what was read from the host ports (or from ``port`` alone) at ``now``, one transmission
        per port, in the order the ports joined; returns the last one's delivery time."""
        end = now
        if not self._vt_in:
            return end
        for endpoint, _listen_only in list(self._hosts):
            if port is not None and endpoint is not port:
                continue
            held = self._vt_in.pop(id(endpoint), None)
            if held:
                end = max(end, self.transmit(endpoint.name, bytes(held[1]), t=now, baud=endpoint.client_baud()))
        return end

    def vt_read(self, ready: list[int], now: float) -> bool:
        """Read each ready host port once, at ``now``: everything one read returns is one transmission (a
        program's writes at one instant are one burst). True if any descriptor of the line was ready."""
        got = super().vt_read(ready, now)  # (the wake-up pipe)
        taken: set[int] = set()
        for fd in ready:
            host = self._vt_fds.get(fd)
            if host is not None and id(host[0]) not in taken:
                taken.add(id(host[0]))
                self._take(host[0], host[1], now, host[2])
                got = got or not self.vt_defer  # (deferred: the loop sends it when its clients wait)
        return got


__all__ = ["Device", "DevicePort", "SerialMediumStats", "SerialMedium", "Tap"]
