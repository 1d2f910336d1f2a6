"""The SICK LMS 200 tracker: telegrams both ways, ACK/NAK, B0 scans and CRC failures.

Fed by ``hilbench monitor`` (:mod:`hilbench.monitor.scanners.sick_lms200`) and
by ``hilbench lidar``'s LMS 200 driver (:mod:`hilbench.clients.sick_lms200`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hilbench.monitor.scanners.tracker import Scan, ScannerTracker
from hilbench.protocols import sick_lms200 as lms
from hilbench.protocols.problem import Problem


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


__all__ = ["SickTracker"]
