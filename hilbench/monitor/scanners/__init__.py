"""Laser-scanner instruments for ``hilbench monitor``: the frame each scanner family's instrument builds on.

A scanner family registers an instrument (``hilbench.instruments`` entry
point, a :class:`ScannerInstrument` subclass in its own module, e.g.
:mod:`hilbench.monitor.scanners.rplidar`) that names its tracker
(:attr:`ScannerInstrument.tracker_path`, a
:class:`~hilbench.monitor.scanners.tracker.ScannerTracker` subclass). The
tracker decodes both directions into a request/reply log, scans, scan rate,
points per scan, health, errors and checksum failures; this class gives every
scanner the same summary and the scanner dashboard views
(:mod:`hilbench.dashboard.scanner_views`).

Importing an instrument is cheap: its tracker (and the protocol's codec,
numpy) is imported when a tracker is made.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any, ClassVar

from hilbench.monitor.instrument import Instrument

if TYPE_CHECKING:
    from hilbench.monitor.scanners.tracker import ScannerTracker


class ScannerInstrument(Instrument):
    """Shared plumbing: the tracker its subclass names, JSON summary, printed summary."""

    views_path = "hilbench.dashboard.scanner_views:VIEW_SET"
    #: ``"module:CLASS"`` of its tracker (a :class:`~hilbench.monitor.scanners.tracker.ScannerTracker`
    #: subclass), imported when the first tracker is made.
    tracker_path: ClassVar[str] = ""

    @property
    def tracker_class(self) -> type[ScannerTracker]:
        """The tracker class :attr:`tracker_path` names."""
        module, _, attr = self.tracker_path.partition(":")
        return getattr(importlib.import_module(module), attr)

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> ScannerTracker:
        return self.tracker_class(baud=baud, timestamps=timestamps)

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


__all__ = ["ScannerInstrument"]
