"""The scanner tracker kit: laser-scanner traffic turned into scans and statistics, whatever the protocol.

Each scanner family's tracker (a :class:`ScannerTracker` subclass in its own
module, named by its instrument's ``tracker_path``) decodes its protocol; this
module keeps what they share. A tracker is fed the bytes of both directions with their times (no I/O) and
keeps: a bounded request/reply log, every finished scan's time and point
count (scan rate, points per scan), the newest scan itself (angles in the
sensor's *counter-clockwise* frame, ranges in metres, for plots), the unit's
health as the traffic says it, decoding errors and checksum failures.

Direction: a bench names the device side ``<name>-device``, ``hilbench tap``
names the sides ``app`` and ``device``; any other source is classified from
what it sends (requests or replies), once.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Entries kept in the request/reply log and the error log.
LOG_SIZE = 500
#: Scan times kept for the rate.
RATE_WINDOW = 64


@dataclass
class Scan:
    """One scan as decoded: time, angles (rad, counter-clockwise, 0 = straight ahead), ranges (m, 0 = none)."""

    t: float
    angles: np.ndarray
    ranges: np.ndarray
    quality: np.ndarray | None = None

    @property
    def points(self) -> int:
        return int(np.count_nonzero(self.ranges > 0))


@dataclass
class LogEntry:
    t: float
    direction: str  # "host" or "device"
    text: str


@dataclass
class ScannerTracker:
    """Shared state and bookkeeping; subclasses decode one protocol (:meth:`feed`)."""

    protocol: str = ""
    baud: int | None = None
    timestamps: bool = True
    t0: float | None = None
    t_last: float | None = None
    bytes: int = 0
    requests: int = 0
    replies: int = 0
    scans: int = 0
    checksum_failures: int = 0
    dropped_bytes: int = 0
    health: str = "unknown"
    device_info: dict[str, Any] = field(default_factory=dict)
    log: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LOG_SIZE))
    errors: collections.deque = field(default_factory=lambda: collections.deque(maxlen=LOG_SIZE))
    error_count: int = 0
    last_scan: Scan | None = None
    scan_times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=RATE_WINDOW))
    points: collections.deque = field(default_factory=lambda: collections.deque(maxlen=RATE_WINDOW))
    sides: dict[str, str] = field(default_factory=dict)

    # ------------------------------------------------------------------ frame duties

    def _stamp(self, t: float) -> None:
        if self.t0 is None:
            self.t0 = t
        self.t_last = t

    def side(self, source: str, data: bytes) -> str:
        """``host`` or ``device`` for a source (by its name, else from its first bytes)."""
        s = self.sides.get(source)
        if s is None:
            if source == "device" or source.endswith("-device"):
                s = "device"
                self.sides[source[:-len("-device")]] = "host"  # a bench's endpoint: its host port
            elif source == "app" or self.sides.get(f"{source}-device") == "device":
                s = "host"
            else:
                s = "device" if self.looks_like_device(data) else "host"
            self.sides[source] = s
        return s

    def looks_like_device(self, data: bytes) -> bool:
        return True

    def feed(self, t: float, source: str, data: bytes) -> None:
        self._stamp(t)
        self.bytes += len(data)
        if self.side(source, data) == "host":
            self.feed_host(t, data)
        else:
            self.feed_device(t, data)

    def feed_host(self, t: float, data: bytes) -> None:
        raise NotImplementedError

    def feed_device(self, t: float, data: bytes) -> None:
        raise NotImplementedError

    def gap(self, t: float, source: str, nbytes: int) -> None:
        self.error(t, f"{nbytes} bytes from {source} lost before the monitor")

    def flush(self, t: float | None = None) -> None:
        """Nothing to cut off: decoders keep partial items for the next bytes."""

    def tick(self, t: float) -> None:
        """No timeouts are tracked."""

    def finish(self) -> None:
        """The source ended."""

    # ------------------------------------------------------------------ bookkeeping

    def note(self, t: float, direction: str, text: str) -> None:
        self.log.append(LogEntry(t, direction, text))

    def error(self, t: float, text: str) -> None:
        self.error_count += 1
        self.errors.append(LogEntry(t, "error", text))

    def add_scan(self, scan: Scan) -> None:
        self.scans += 1
        self.last_scan = scan
        self.scan_times.append(scan.t)
        self.points.append(scan.points)

    @property
    def scan_rate(self) -> float | None:
        """Scans per second over the recent scans (None before two)."""
        if len(self.scan_times) < 2 or not self.timestamps:
            return None
        span = self.scan_times[-1] - self.scan_times[0]
        return (len(self.scan_times) - 1) / span if span > 0 else None

    @property
    def points_per_scan(self) -> float | None:
        return float(np.mean(self.points)) if self.points else None

    def summary(self, *, source: str = "", timestamps: str | None = None, errors: int = 50) -> dict[str, Any]:
        """Everything the tracker knows, as plain JSON types."""
        rate = self.scan_rate
        pps = self.points_per_scan
        return {
            "source": source,
            "protocol": self.protocol,
            "baud": self.baud,
            "timestamps": timestamps,
            "bytes": self.bytes,
            "duration_s": round(self.t_last - self.t0, 3) if self.t0 is not None and self.timestamps else None,
            "requests": self.requests,
            "replies": self.replies,
            "scans": self.scans,
            "scan_rate_hz": round(rate, 3) if rate else None,
            "points_per_scan": round(pps, 1) if pps is not None else None,
            "health": self.health,
            "device": dict(self.device_info),
            "checksum_failures": self.checksum_failures,
            "dropped_bytes": self.dropped_bytes,
            "error_count": self.error_count,
            "errors": [f"{e.t - (self.t0 or 0):.3f} {e.text}" for e in list(self.errors)[-errors:]],
        }


__all__ = ["LOG_SIZE", "RATE_WINDOW", "LogEntry", "Scan", "ScannerTracker"]
