"""Scanner trackers: laser-scanner traffic (RPLIDAR, SICK LMS 200, SCIP 2.0) turned into scans and statistics.

A tracker is fed the bytes of both directions with their times (no I/O) and
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
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hilbench.protocols import rplidar as rp
from hilbench.protocols import scip
from hilbench.protocols import sick_lms200 as lms
from hilbench.protocols.problem import Problem

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


# ----------------------------------------------------------------------------- RPLIDAR


@dataclass
class RplidarTracker(ScannerTracker):
    """RPLIDAR traffic: requests, descriptors and single responses, node and capsule streams."""

    protocol: str = "rplidar"

    def __post_init__(self) -> None:
        self.req_dec = rp.RequestDecoder()
        self.resp_dec = rp.ResponseDecoder()
        self.asm = rp.ScanAssembler(min_points=5)
        self._last_req_t: float | None = None

    def looks_like_device(self, data: bytes) -> bool:
        return b"\xa5\x5a" in data or not data.startswith(b"\xa5")

    def feed_host(self, t: float, data: bytes) -> None:
        for item in self.req_dec.feed(data):
            if isinstance(item, rp.Request):
                self.requests += 1
                self.note(t, "host", f"{item.name} {item.payload.hex(' ')}".rstrip())
                if item.cmd in (rp.Cmd.STOP, rp.Cmd.RESET):
                    self.resp_dec.expect_stream(None)
            else:
                self.dropped_bytes += len(item.raw)
                if item.kind == "checksum":
                    self.checksum_failures += 1
                self.error(t, f"host: {item.kind} {item.raw[:16].hex(' ')}")

    def feed_device(self, t: float, data: bytes) -> None:
        for item in self.resp_dec.feed(data):
            if isinstance(item, rp.Node):
                for rev in self.asm.add_node(item):
                    self._scan(t, rev)
            elif isinstance(item, rp.CapsuleItem):
                for rev in self.asm.add_capsule(item):
                    self._scan(t, rev)
            elif isinstance(item, rp.Response):
                self.replies += 1
                text = item.name
                if item.fields:
                    f = item.fields
                    text += " " + ", ".join(f"{k}={v}" for k, v in f.items() if k != "value")
                    if item.ans_type == rp.AnsType.DEVHEALTH:
                        self.health = f"{rp.HEALTH_STATUS.get(f['status'], f['status'])} " \
                                      f"(code 0x{f['error_code']:04X})"
                    elif item.ans_type == rp.AnsType.DEVINFO:
                        self.device_info = {"model": f["model"], "firmware": ".".join(map(str, f["firmware"])),
                                            "hardware": f["hardware"], "serial": f["serial"]}
                if item.mode == rp.MULTIPLE:
                    text += " (stream)"
                    self.asm = rp.ScanAssembler(min_points=5)
                self.note(t, "device", text)
            elif isinstance(item, Problem):
                self.dropped_bytes += len(item.raw)
                if item.kind == "checksum":
                    self.checksum_failures += 1
                if item.kind != "banner":
                    self.error(t, f"device: {item.kind} {item.raw[:16].hex(' ')}")
                else:
                    self.note(t, "device", f"banner {item.raw.decode('ascii', 'replace').strip()}")

    def _scan(self, t: float, rev: list[tuple[float, float, int]]) -> None:
        a = np.array([p[0] for p in rev])
        d = np.array([p[1] for p in rev]) / 1000.0
        q = np.array([p[2] for p in rev])
        # RPLIDAR angles grow clockwise: the shared frame is counter-clockwise.
        self.add_scan(Scan(t, -np.radians(a), d, q))


# ----------------------------------------------------------------------------- SICK LMS 200


@dataclass
class SickTracker(ScannerTracker):
    """LMS 200 telegrams: requests and replies, ACK/NAK, B0 scans, CRC failures."""

    protocol: str = "sick-lms200"

    def __post_init__(self) -> None:
        self.host_dec = lms.Decoder(handshakes=False)
        self.dev_dec = lms.Decoder(handshakes=True)
        self.naks = 0

    def looks_like_device(self, data: bytes) -> bool:
        return data[:1] in (b"\x06", b"\x15") or data[:2] == b"\x02\x80"

    def feed_host(self, t: float, data: bytes) -> None:
        for item in self.host_dec.feed(data):
            if isinstance(item, lms.Frame):
                self.requests += 1
                self.note(t, "host", f"{item.name} {item.data.hex(' ')}".rstrip())
            else:
                self._problem(t, "host", item)

    def feed_device(self, t: float, data: bytes) -> None:
        for item in self.dev_dec.feed(data):
            if isinstance(item, lms.Handshake):
                if not item.ack:
                    self.naks += 1
                    self.error(t, "device: NAK")
            elif isinstance(item, lms.Frame):
                self.replies += 1
                f = item.fields()
                if item.cmd == 0xB0 and "values" in f:
                    self._scan(t, f)
                    self.note(t, "device", f"SCAN {f['count']} values ({lms.UNITS.get(f['units'], '?')})")
                else:
                    self.note(t, "device", f"{item.name} reply {item.data[:24].hex(' ')}".rstrip())
                if item.status is not None:
                    self.health = "ok" if item.status & 0x07 == 0 else f"status 0x{item.status:02X}"
            else:
                self._problem(t, "device", item)

    def _problem(self, t: float, side: str, item: Problem) -> None:
        self.dropped_bytes += len(item.raw) if item.kind == "garbage" else 1
        if item.kind == "crc":
            self.checksum_failures += 1
        self.error(t, f"{side}: {item.kind} {item.detail}".rstrip())

    def _scan(self, t: float, f: dict) -> None:
        n = f["count"]
        if not f["complete"] or n == 0:
            self.error(t, "device: truncated scan")
            return
        res = {101: 1.0, 181: 1.0, 201: 0.5, 361: 0.5, 401: 0.25}.get(n, 180.0 / max(n - 1, 1))
        start = 0.0 if n in (181, 361) else 40.0 if n in (101, 201, 401) else 0.0
        angles = np.radians(start + np.arange(n) * res - 90.0)
        scale = 1000.0 if f["units"] == 1 else 100.0
        vals = np.asarray(f["values"], dtype=float)
        ranges = np.where(vals < 8183, vals / scale, 0.0)
        self.add_scan(Scan(t, angles, ranges))


# ----------------------------------------------------------------------------- SCIP 2.0


@dataclass
class ScipTracker(ScannerTracker):
    """SCIP 2.0 lines: requests, replies (status and sums), GD/MD scans, the unit's parameters."""

    protocol: str = "scip2"

    def __post_init__(self) -> None:
        self.req_dec = scip.RequestDecoder()
        self.rep_dec = scip.ReplyDecoder()
        self.params = {"AMIN": 0, "AMAX": 1080, "AFRT": 540, "ARES": 1440}

    def looks_like_device(self, data: bytes) -> bool:
        reps = scip.ReplyDecoder().feed(data)
        return any(isinstance(r, scip.Reply) and r.status is not None for r in reps)

    def feed_host(self, t: float, data: bytes) -> None:
        for item in self.req_dec.feed(data):
            if isinstance(item, scip.Request):
                self.requests += 1
                self.note(t, "host", item.line.decode("ascii", "replace"))
            else:
                self.dropped_bytes += len(item.raw)
                self.error(t, f"host: {item.kind}")

    def feed_device(self, t: float, data: bytes) -> None:
        for item in self.rep_dec.feed(data):
            if isinstance(item, Problem):
                self.dropped_bytes += len(item.raw)
                self.error(t, f"device: {item.kind} {item.detail}")
                continue
            self.replies += 1
            if item.bad_sums:
                self.checksum_failures += item.bad_sums
                self.error(t, f"device: {item.bad_sums} bad sums in reply to {item.echo}")
            status = item.status or "??"
            self.note(t, "device", f"{item.echo} -> {status} ({scip.STATUS_TEXT.get(status, '?')})")
            cmd = item.cmd
            if cmd == "PP":
                for k, v in item.info().items():
                    if v.isdigit():
                        self.params[k] = int(v)
                    if k == "MODL":
                        self.device_info["model"] = v
            elif cmd == "VV":
                self.device_info.update({k.lower(): v for k, v in item.info().items()})
            elif cmd == "II":
                info = item.info()
                if "STAT" in info:
                    self.health = info["STAT"]
            elif cmd in scip.ENCODING and status in ("00", "99") and item.lines:
                self._scan(t, item)
            elif status not in ("00", "99"):
                if status == "0M":
                    self.health = "unstable"
                self.error(t, f"device: {item.echo} status {status} ({scip.STATUS_TEXT.get(status, '?')})")

    def _scan(self, t: float, item: scip.Reply) -> None:
        req = scip.parse_request(item.echo.encode("ascii", "replace"))
        f = req.fields() if req else None
        _ts, dist, _inten = item.scan()
        if not f or not dist:
            return
        cluster = max(1, f["cluster"])
        steps = f["start"] + np.arange(len(dist)) * cluster
        p = self.params
        angles = (steps - p.get("AFRT", 0)) * 2 * math.pi / p.get("ARES", 1440)
        d = np.asarray(dist, dtype=float)
        ranges = np.where(d >= p.get("DMIN", 20), d / 1000.0, 0.0)
        self.add_scan(Scan(t, angles, ranges))
        self.health = "ok" if self.health in ("unknown", "unstable") else self.health


TRACKERS = {"rplidar": RplidarTracker, "sick-lms200": SickTracker, "scip2": ScipTracker}

__all__ = ["TRACKERS", "LogEntry", "RplidarTracker", "Scan", "ScannerTracker", "ScipTracker", "SickTracker"]
