"""SICK LMS 200 traffic for ``hilbench monitor``: the instrument (``hilbench.instruments`` entry point
``sick-lms200``, aliases ``sick``, ``lms200``).

Its tracker is :class:`~hilbench.monitor.scanners.sick_lms200_tracker.SickTracker`.
"""

from __future__ import annotations

from hilbench.monitor.scanners import ScannerInstrument


class SickInstrument(ScannerInstrument):
    """SICK LMS 200 telegrams: requests and replies, ACK/NAK, B0 scans."""

    protocol = "sick-lms200"
    aliases = ("sick", "lms200")
    title = "SICK LMS 200 telegrams"
    tracker_path = "hilbench.monitor.scanners.sick_lms200_tracker:SickTracker"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols import sick_lms200 as lms

        frames = sum(1 for i in lms.Decoder().feed(data[:8192]) if isinstance(i, lms.Frame))
        return 0.95 if frames else 0.0


#: The instrument this module registers (entry point ``hilbench.instruments``).
INSTRUMENT = SickInstrument()

__all__ = ["INSTRUMENT", "SickInstrument"]
