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
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from hilbench.transports.clock import SPIN_AFTER_ACTIVITY, reduce_timer_slack, wait
from hilbench.transports.pty import PtyEndpoint

log = logging.getLogger(__name__)

#: A tap sees ``(t, source, data)`` for every transmission on the line.
Tap = Callable[[float, str, bytes], None]


class Device(Protocol):
    """An in-process party on the line, e.g. a group of emulated servos."""

    name: str

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        """Bytes another party sent, as received at time ``t``; ``baud`` is the sender's line rate."""


@dataclass
class LineStats:
    """Counters of the line, by sender."""

    transmissions: int = 0
    bytes: int = 0
    by_source: dict[str, int] = field(default_factory=dict)
    callback_errors: int = 0


class DevicePort:
    """What a device holds to transmit on the line."""

    def __init__(self, medium: SerialMedium, name: str) -> None:
        self._medium = medium
        self.name = name

    @property
    def paced(self) -> bool:
        return self._medium.paced

    def transmit(self, data: bytes, t: float | None = None, gap: float = 0.0, baud: int | None = None) -> float:
        """Send ``data`` ``gap`` seconds after the line is free (and not before ``t``); returns its end time."""
        return self._medium.transmit(self.name, data, t=t, gap=gap, baud=baud)

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the line's thread at time ``t``."""
        self._medium.call_at(t, fn)


class SerialMedium:
    """One shared serial line. Add hosts, devices and taps, then :meth:`start` it."""

    def __init__(self, name: str, baud: int, *, paced: bool = False) -> None:
        self.name = name
        self.baud = baud
        self.paced = paced
        self.stats = LineStats()
        self._hosts: list[tuple[PtyEndpoint, bool]] = []
        self._devices: list[Device] = []
        self._taps: list[Tap] = []
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._lock = threading.Lock()
        self._busy_until = 0.0
        self._last_activity = 0.0
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ wiring

    def add_host(self, endpoint: PtyEndpoint, *, listen_only: bool = False) -> None:
        """Attach a pty whose client is a host program; ``listen_only`` ignores what it sends."""
        with self._lock:
            self._hosts.append((endpoint, listen_only))
        self._wake()

    def add_device(self, device: Device) -> DevicePort:
        """Attach an in-process device; it transmits through the returned port."""
        with self._lock:
            self._devices.append(device)
        return DevicePort(self, device.name)

    def add_tap(self, tap: Tap) -> None:
        """Attach a tap that sees every transmission."""
        with self._lock:
            self._taps.append(tap)

    def remove_tap(self, tap: Tap) -> None:
        with self._lock:
            if tap in self._taps:
                self._taps.remove(tap)

    @property
    def hosts(self) -> list[PtyEndpoint]:
        return [ep for ep, _ in self._hosts]

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
            now = time.monotonic()
            t = now if t is None else t
            if self.paced:
                start = max(t, self._busy_until) + gap
                end = start + len(data) * self.byte_time(baud)
                self._busy_until = end
            else:
                end = t + gap
            self._push(end, lambda: self._deliver(source, data, end, baud))
        if threading.current_thread() is not self._thread:
            self._wake()
        return end

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the line's thread at time ``t`` (thread-safe)."""
        with self._lock:
            self._push(t, fn)
        if threading.current_thread() is not self._thread:
            self._wake()

    def _push(self, t: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self._events, (t, next(self._seq), fn))

    def _deliver(self, source: str, data: bytes, t: float, baud: int | None) -> None:
        stats = self.stats
        stats.transmissions += 1
        stats.bytes += len(data)
        stats.by_source[source] = stats.by_source.get(source, 0) + len(data)
        for endpoint, _ in self._hosts:
            if endpoint.name != source:
                endpoint.write(data)
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

    # ------------------------------------------------------------------ running

    def start(self) -> None:
        """Run the line in a background thread."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"line-{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the line's thread (host ports stay open; close them separately)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except BlockingIOError:
            pass  # already pending

    def _run(self) -> None:
        if self.paced:
            reduce_timer_slack()
        while not self._stop.is_set():
            with self._lock:
                deadline = self._events[0][0] if self._events else None
                hosts = list(self._hosts)
            fds = [ep.fileno() for ep, _ in hosts] + [self._wake_r]
            ready = wait(fds, deadline, precise=self.paced, spin_until=self._last_activity + SPIN_AFTER_ACTIVITY)
            if ready:
                now = self._last_activity = time.monotonic()
                for endpoint, listen_only in hosts:
                    if endpoint.fileno() in ready:
                        data = endpoint.read()
                        if data and not listen_only:
                            self.transmit(endpoint.name, data, t=now, baud=endpoint.client_baud())
                if self._wake_r in ready:
                    with contextlib.suppress(BlockingIOError):
                        os.read(self._wake_r, 4096)
            self._run_due()

    def _run_due(self) -> None:
        while True:
            with self._lock:
                if not self._events or self._events[0][0] > time.monotonic():
                    return
                _, _, fn = heapq.heappop(self._events)
            fn()

    def close(self) -> None:
        """Stop the line and release its wake-up pipe."""
        self.stop()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
