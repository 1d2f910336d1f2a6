"""RPLIDAR traffic for ``hilbench monitor``: the instrument (``hilbench.instruments`` entry point ``rplidar``).

Its tracker is :class:`~hilbench.monitor.scanners.rplidar_tracker.RplidarTracker`.
"""

from __future__ import annotations

from hilbench.monitor.scanners import ScannerInstrument


class RplidarInstrument(ScannerInstrument):
    """The Slamtec RPLIDAR serial protocol: requests, descriptors, node and capsule streams."""

    protocol = "rplidar"
    title = "Slamtec RPLIDAR serial protocol"
    tracker_path = "hilbench.monitor.scanners.rplidar_tracker:RplidarTracker"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols import rplidar as rp

        dec = rp.ResponseDecoder()
        items = dec.feed(data[:8192])
        descriptors = sum(1 for i in items if isinstance(i, rp.Response) and i.ans_type in list(rp.AnsType))
        if descriptors:
            return 0.9
        reqs = rp.RequestDecoder().feed(data[:256])
        good = sum(1 for i in reqs if isinstance(i, rp.Request) and i.cmd in list(rp.Cmd))
        return 0.5 if good and good == len(reqs) else 0.0


#: The instrument this module registers (entry point ``hilbench.instruments``).
INSTRUMENT = RplidarInstrument()

__all__ = ["INSTRUMENT", "RplidarInstrument"]
