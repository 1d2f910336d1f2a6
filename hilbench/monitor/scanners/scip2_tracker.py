"""The SCIP 2.0 tracker: request and reply lines (status, sums), GD/MD scans, the unit's parameters.

Fed by ``hilbench monitor`` (:mod:`hilbench.monitor.scanners.scip2`) and by
``hilbench lidar``'s SCIP driver (:mod:`hilbench.clients.scip2`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hilbench.monitor.scanners.tracker import Scan, ScannerTracker
from hilbench.protocols import scip
from hilbench.protocols.problem import Problem


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


__all__ = ["ScipTracker"]
