"""What a serial adapter carries besides bytes: modem lines, BREAK and line settings.

A real USB-serial adapter has modem lines. The host drives DTR and RTS (an
RPLIDAR A1's adapter runs the motor while DTR is low; boards reset on
DTR/RTS) and reads CTS, DSR, RI and CD, which the device drives; the host can
hold the line in BREAK and changes baud rate and framing. A pseudo-terminal
has none of that, so a host port keeps a :class:`PortState` that whoever
learns of a change feeds: ``hilbench run``'s shim (modem-line ioctls of an
unmodified client on the bench's pty), an RFC 2217 server, a test. Changes
become events a medium hands to its devices (``device.on_port_event(event, t)``);
what the device drives goes the other way (:meth:`PortState.device_sets`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class ModemSignals:
    """The host-driven modem outputs after a change: DTR and RTS (True: asserted)."""

    dtr: bool
    rts: bool


@dataclass(frozen=True)
class BreakCondition:
    """The host started (``active``) or ended a BREAK; ``duration`` is set for a timed break (tcsendbreak)."""

    active: bool
    duration: float | None = None


@dataclass(frozen=True)
class SerialSettings:
    """The host set the line: baud rate (None if unknown), data bits, parity (N/E/O/M/S), stop bits."""

    baud: int | None
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1.0


@dataclass(frozen=True)
class OutputFlushed:
    """The host flushed its output (TCOFLUSH); under ``hilbench run`` the bytes were delivered first."""


PortEvent = ModemSignals | BreakCondition | SerialSettings | OutputFlushed

#: Device-driven lines a host can read, as in pyserial (``cts``, ``dsr``, ``ri``, ``cd``).
DEVICE_LINES = ("cts", "dsr", "ri", "cd")


class PortState:
    """The modem lines, BREAK and settings of one host port; thread-safe.

    ``dtr``/``rts`` start asserted, as a host's open() leaves them on a real
    adapter (pyserial and termios with HUPCL assert both). A listener
    (``set_listener``) receives every host-side change as an event.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.dtr = True
        self.rts = True
        self.break_active = False
        self.settings = SerialSettings(None)
        self.cts = False
        self.dsr = False
        self.ri = False
        self.cd = False
        self.events = 0
        self._listener: Callable[[PortEvent], None] | None = None
        self._watchers: list[Callable[[dict[str, bool]], None]] = []

    def set_listener(self, listener: Callable[[PortEvent], None] | None) -> None:
        """Who hears the host's changes (a medium, which passes them to its devices)."""
        self._listener = listener

    def add_watcher(self, watcher: Callable[[dict[str, bool]], None]) -> None:
        """Also tell ``watcher`` the device-driven lines after each :meth:`device_sets` (an RFC 2217
        server reports them to its client as a real adapter's driver does)."""
        self._watchers.append(watcher)

    def remove_watcher(self, watcher: Callable[[dict[str, bool]], None]) -> None:
        if watcher in self._watchers:
            self._watchers.remove(watcher)

    def _emit(self, event: PortEvent) -> None:
        self.events += 1
        listener = self._listener
        if listener is not None:
            listener(event)

    # ------------------------------------------------------------------ host side

    def host_sets(self, *, dtr: bool | None = None, rts: bool | None = None) -> ModemSignals:
        """The host changed DTR and/or RTS; emits :class:`ModemSignals` if anything changed."""
        with self._lock:
            new_dtr = self.dtr if dtr is None else bool(dtr)
            new_rts = self.rts if rts is None else bool(rts)
            changed = (new_dtr, new_rts) != (self.dtr, self.rts)
            self.dtr, self.rts = new_dtr, new_rts
            event = ModemSignals(new_dtr, new_rts)
        if changed:
            self._emit(event)
        return event

    def host_break(self, active: bool, duration: float | None = None) -> None:
        """The host set or cleared BREAK (a timed break is one event with its duration)."""
        with self._lock:
            self.break_active = active and duration is None
        self._emit(BreakCondition(active, duration))

    def host_settings(self, settings: SerialSettings) -> None:
        """The host changed baud rate or framing; emits :class:`SerialSettings` if anything changed."""
        with self._lock:
            changed = settings != self.settings
            self.settings = settings
        if changed:
            self._emit(settings)

    def host_flushed_output(self) -> None:
        self._emit(OutputFlushed())

    # ------------------------------------------------------------------ device side

    def device_sets(self, **lines: bool) -> None:
        """The device drives CTS, DSR, RI and/or CD (``device_sets(dsr=True)``)."""
        for key in lines:
            if key not in DEVICE_LINES:
                raise ValueError(f"a device drives {', '.join(DEVICE_LINES)}, not {key!r}")
        with self._lock:
            for key, value in lines.items():
                setattr(self, key, bool(value))
            now = {k: getattr(self, k) for k in DEVICE_LINES}
        for watcher in list(self._watchers):
            watcher(now)

    def device_lines(self) -> dict[str, bool]:
        """CTS, DSR, RI, CD as the host reads them."""
        with self._lock:
            return {k: getattr(self, k) for k in DEVICE_LINES}

    def snapshot(self) -> dict[str, object]:
        """Everything, for status reports and the manifest."""
        with self._lock:
            return {"dtr": self.dtr, "rts": self.rts, "break": self.break_active,
                    **{k: getattr(self, k) for k in DEVICE_LINES}}


__all__ = ["DEVICE_LINES", "BreakCondition", "PortEvent", "SerialSettings", "PortState", "ModemSignals",
           "OutputFlushed"]
