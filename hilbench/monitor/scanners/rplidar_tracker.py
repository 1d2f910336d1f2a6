"""The RPLIDAR tracker: requests, response descriptors, node and capsule streams turned into scans.

Fed by ``hilbench monitor`` (:mod:`hilbench.monitor.scanners.rplidar`) and by
``hilbench lidar``'s RPLIDAR driver (:mod:`hilbench.clients.rplidar`), so both
count the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hilbench.monitor.scanners.tracker import Scan, ScannerTracker
from hilbench.protocols import rplidar as rp
from hilbench.protocols.problem import Problem


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


__all__ = ["RplidarTracker"]
