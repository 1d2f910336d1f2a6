"""Hokuyo SCIP 2.0 traffic for ``hilbench monitor``: the instrument (``hilbench.instruments`` entry point
``scip2``, aliases ``scip``, ``hokuyo``).

Its tracker is :class:`~hilbench.monitor.scanners.scip2_tracker.ScipTracker`.
"""

from __future__ import annotations

from hilbench.monitor.scanners import ScannerInstrument


class ScipInstrument(ScannerInstrument):
    """Hokuyo SCIP 2.0 lines: requests, replies with status and sums, GD/MD scans."""

    protocol = "scip2"
    aliases = ("scip", "hokuyo")
    title = "Hokuyo SCIP 2.0"
    tracker_path = "hilbench.monitor.scanners.scip2_tracker:ScipTracker"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols import scip

        reps = [r for r in scip.ReplyDecoder().feed(data[:8192]) if isinstance(r, scip.Reply)]
        good = sum(1 for r in reps if r.status is not None and not r.bad_sums)
        return 0.9 if good and good >= len(reps) / 2 else 0.0


#: The instrument this module registers (entry point ``hilbench.instruments``).
INSTRUMENT = ScipInstrument()

__all__ = ["INSTRUMENT", "ScipInstrument"]
