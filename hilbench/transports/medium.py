"""Media: the shared wire behind an endpoint (a serial line, a CAN bus, a datagram net).

Every medium has the same shape, so pacing, taps and capture work for all of
them: host ports (what host programs open) and in-process devices are added,
taps see every transmission with its time and sender, :meth:`Medium.start`
runs it in a thread of its own, :meth:`Medium.close` ends it. How a device
hears traffic depends on the medium (``on_bytes`` on a serial line,
``on_frame`` on a CAN bus, ``on_datagram`` on a datagram net); what it sends
goes through the :class:`DevicePort` the medium returned when it was added.

Media register by kind in the ``hilbench.media`` entry-point group; a bus kind
names the kind its endpoints need (:attr:`BusKind.medium <hilbench.bench.bus.BusKind.medium>`).

Besides traffic, a serial host port has modem lines and BREAK
(:mod:`hilbench.transports.port_state`): the medium hands the host's changes to each
device that has ``on_port_event(event, t)``, in the medium's own thread, and a
device drives CTS/DSR/RI/CD through :meth:`DevicePort.set_lines`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, ClassVar

from hilbench.transports.clock import WALL, WallClock
from hilbench.transports.port_state import PortEvent

log = logging.getLogger(__name__)

#: A tap sees ``(t, source, data)`` for every transmission on a medium.
Tap = Callable[[float, str, bytes], None]


class Medium:
    """Base class of media: host ports, devices, taps and port events. Subclasses move the traffic."""

    #: The medium's kind, as families name it (``"serial"``).
    kind: ClassVar[str] = ""
    #: What the traffic is (an endpoint's protocol, set by the bench), for taps and monitors.
    protocol: str | None = None

    def __init__(self, name: str, baud: int | None = None, *, paced: bool = False, clock: WallClock = WALL) -> None:
        self.name = name
        self.baud = baud
        self.paced = paced
        #: The bench's clock: every time this medium, its ports and its devices read is ``clock.now()``.
        self.clock = clock
        self._now = clock.now  # (the builtin time.monotonic itself on a wall clock: the hot path's read)
        self._taps: list[Tap] = []
        self._hosts: list[tuple[Any, bool]] = []
        self._devices: list[Any] = []
        self._lock = threading.Lock()
        self.callback_errors = 0

    # ------------------------------------------------------------------ wiring

    def add_host(self, port: Any, *, listen_only: bool = False) -> None:
        """Attach a host port; ``listen_only`` ignores what it sends. Its port events reach the devices."""
        with self._lock:
            self._hosts.append((port, listen_only))
        book = self.clock.channels
        if book is not None and hasattr(port, "vt_channels"):  # (virtual time: a socket door counts its traffic)
            port.vt_channels(book)
        lines = getattr(port, "port_state", None)
        if lines is not None:
            lines.set_listener(lambda event, _name=port.name: self.port_event(_name, event))

    def add_device(self, device: Any) -> DevicePort:
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
    def hosts(self) -> list[Any]:
        return [port for port, _ in self._hosts]

    @property
    def devices(self) -> list[Any]:
        return list(self._devices)

    # ------------------------------------------------------------------ port events

    def port_event(self, source: str, event: PortEvent) -> None:
        """A host port's modem lines, BREAK or settings changed: tell the devices in the medium's thread.

        Called in the medium's own thread (a settings change found while reading the
        port, a change ``hilbench run``'s port-state server applies there) the devices hear it
        at once, so it comes before anything the medium delivers afterwards; from any
        other thread it is queued.
        """
        if self.in_medium_thread():
            self._deliver_port_event(source, event)
        else:
            self.call_at(None, lambda: self._deliver_port_event(source, event))

    def _deliver_port_event(self, source: str, event: PortEvent) -> None:
        t = self._now()
        for device in self._devices:
            handler = getattr(device, "on_port_event", None)
            if handler is None or device.name == source:
                continue
            try:
                handler(event, t)
            except Exception:  # one faulty device must not stop the medium
                self.callback_errors += 1
                log.exception("device %s failed on line event %r", device.name, event)

    def set_device_lines(self, **lines: bool) -> None:
        """A device drives CTS/DSR/RI/CD: every host port with lines reads the new levels."""
        for port in self.hosts:
            state = getattr(port, "port_state", None)
            if state is not None:
                state.device_sets(**lines)

    def in_medium_thread(self) -> bool:
        """Whether the caller runs in the medium's own thread (device callbacks, ``call_at`` functions)."""
        thread = getattr(self, "_thread", None)
        return thread is not None and thread is threading.current_thread()

    # ------------------------------------------------------------------ subclass duties

    def drain_host(self, port: Any) -> tuple[int, float]:
        """Take at once everything host ``port`` already sent (call in the medium's thread).

        Returns how many bytes were taken and when the last of them is delivered.
        ``hilbench run`` uses it so an output flush or a modem-line change never
        overtakes the bytes a client wrote before it.
        """
        raise NotImplementedError

    def watch_quiet(self, port: Any, watcher: Callable[[int], None] | None) -> bool:
        """Call ``watcher(ns)`` whenever everything host ``port`` wrote before ``CLOCK_MONOTONIC`` ``ns``
        is delivered; False: this medium cannot tell (``hilbench run`` clients then always ask)."""
        return False

    def check_quiet(self, port: Any) -> bool:
        """Check now, in the medium's thread, what :meth:`watch_quiet` watches; False if not quiet."""
        return False

    def call_at(self, t: float | None, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the medium's thread at time ``t`` (None: as soon as possible)."""
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class DevicePort:
    """What a device holds to transmit on its medium (and to drive the host's modem inputs)."""

    def __init__(self, medium: Medium, name: str) -> None:
        self._medium = medium
        self.name = name

    @property
    def medium(self) -> Medium:
        return self._medium

    @property
    def paced(self) -> bool:
        return self._medium.paced

    @property
    def clock(self) -> WallClock:
        """The bench's clock (what :meth:`now` reads; ``clock.wall(t)`` for Unix time stamps)."""
        return self._medium.clock

    def now(self) -> float:
        """The medium's current time (the ``t`` devices schedule and stamp with)."""
        return self._medium.clock.now()

    def transmit(self, data: bytes, t: float | None = None, gap: float = 0.0, baud: int | None = None) -> float:
        """Send ``data`` ``gap`` seconds after the medium is free (and not before ``t``); returns its end time."""
        return self._medium.transmit(self.name, data, t=t, gap=gap, baud=baud)

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the medium's thread at time ``t``."""
        self._medium.call_at(t, fn)

    def set_lines(self, **lines: bool) -> None:
        """Drive the host's modem inputs: ``set_lines(dsr=True, cts=False)``."""
        self._medium.set_device_lines(**lines)


def medium_timing(medium: Any) -> dict[str, str]:
    """What a medium's thread runs under, as the manifest and ``media`` say it: ``scheduling`` (SCHED_FIFO
    where allowed) and a paced medium's ``cpu_latency`` (idle CPUs kept awake: "0 us", or why not), each
    only where the medium has it."""
    return {key: value for key in ("scheduling", "cpu_latency") if (value := getattr(medium, key, None))}


__all__ = ["DevicePort", "Medium", "Tap", "medium_timing"]
