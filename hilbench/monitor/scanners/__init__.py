"""Laser-scanner instruments: RPLIDAR, SICK LMS 200 and SCIP 2.0 traffic for ``hilbench monitor``.

Each protocol registers an :class:`~hilbench.monitor.instrument.Instrument`
(``hilbench.instruments`` entry points ``rplidar``, ``sick-lms200``, ``scip2``)
whose tracker (:mod:`hilbench.monitor.scanners.tracker`) decodes both
directions into a request/reply log, scans, scan rate, points per scan,
health, errors and checksum failures, shown by the scanner dashboard views
(:mod:`hilbench.dashboard.scanner_views`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench.monitor.instrument import Instrument

if TYPE_CHECKING:  # the trackers (numpy) are imported when one is made: the plug-ins stay light
    from hilbench.monitor.scanners.tracker import ScannerTracker


class ScannerInstrument(Instrument):
    """Shared plumbing: tracker by protocol, JSON summary, printed summary."""

    views_path = "hilbench.dashboard.scanner_views:VIEW_SET"

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> ScannerTracker:
        from hilbench.monitor.scanners.tracker import TRACKERS

        return TRACKERS[self.protocol](baud=baud, timestamps=timestamps)

    def summary(self, tracker: ScannerTracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        return tracker.summary(source=source, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        rate = report["scan_rate_hz"]
        console.print(f"[bold]{report['source']}[/]: {report['protocol']}, {report['bytes']} bytes, "
                      f"{report['requests']} requests, {report['replies']} replies", highlight=False)
        console.print(f"  scans {report['scans']}, rate {rate if rate is not None else '-'} Hz, points per scan "
                      f"{report['points_per_scan'] if report['points_per_scan'] is not None else '-'}, "
                      f"health {report['health']}", highlight=False)
        if report["device"]:
            console.print("  device " + ", ".join(f"{k} {v}" for k, v in report["device"].items()), highlight=False)
        console.print(f"  checksum failures {report['checksum_failures']}, dropped bytes {report['dropped_bytes']}, "
                      f"errors {report['error_count']}", highlight=False)
        for line in report["errors"][-10:]:
            console.print(f"  ! {line}", highlight=False)


class RplidarInstrument(ScannerInstrument):
    protocol = "rplidar"
    title = "Slamtec RPLIDAR serial protocol"

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


class SickInstrument(ScannerInstrument):
    protocol = "sick-lms200"
    aliases = ("sick", "lms200")
    title = "SICK LMS 200 telegrams"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols import sick_lms200 as lms

        frames = sum(1 for i in lms.Decoder().feed(data[:8192]) if isinstance(i, lms.Frame))
        return 0.95 if frames else 0.0


class ScipInstrument(ScannerInstrument):
    protocol = "scip2"
    aliases = ("scip", "hokuyo")
    title = "Hokuyo SCIP 2.0"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols import scip

        reps = [r for r in scip.ReplyDecoder().feed(data[:8192]) if isinstance(r, scip.Reply)]
        good = sum(1 for r in reps if r.status is not None and not r.bad_sums)
        return 0.9 if good and good >= len(reps) / 2 else 0.0


RPLIDAR = RplidarInstrument()
SICK = SickInstrument()
SCIP = ScipInstrument()

__all__ = ["RPLIDAR", "SCIP", "SICK", "ScannerInstrument"]
