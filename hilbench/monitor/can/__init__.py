"""The CAN bus monitor: per-identifier timing, decoded signals, CANopen nodes, SDO, EMCY, bus load, errors.

- :class:`~hilbench.monitor.can.tracker.CanTracker`: the state machine, fed SocketCAN frame records with times;
- :mod:`~hilbench.monitor.can.decoders`: DBC (cantools) and EDS (canopen) decoders;
- :func:`~hilbench.monitor.can.summary.summary`: the JSON summary;
- :data:`INSTRUMENT`: the plug-in (``hilbench.instruments`` entry point ``can``): options ``--dbc``,
  ``--eds``, ``--no-canopen``, ``--miss-factor``, the tracker, summary and dashboard views.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from hilbench.monitor.instrument import Instrument
from hilbench.protocols import can_frame as cf
from hilbench.rules import Rule

if TYPE_CHECKING:  # the tracker is imported when one is made: the plug-in stays light
    from hilbench.monitor.can.tracker import CanTracker

#: ``--miss-factor``: a heartbeat gap longer than this many periods is a miss.
MISS_FACTOR = Rule(float, 1, 1000, above=True)


class CanInstrument(Instrument):
    """The CAN monitor as an instrument plug-in."""

    protocol = "can"
    aliases = ("canopen", "socketcan")
    title = "CAN bus (CANopen aware)"
    views_path = "hilbench.dashboard.can_views:VIEW_SET"

    def sniff(self, data: bytes) -> float:
        # Raw SocketCAN records: every 16-byte record must have a sane length byte and zero padding.
        n = len(data) // cf.FRAME_SIZE
        if n < 2 or len(data) % cf.FRAME_SIZE:
            return 0.0
        for i in range(min(n, 64)):
            rec = data[i * 16 : i * 16 + 16]
            if rec[4] > 8 or rec[5] or rec[6]:
                return 0.0
        return 0.5

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("CAN bus")
        g.add_argument("--dbc", action="append", default=[], metavar="FILE",
                       help="decode signals with this DBC (or KCD, SYM, ARXML), or a bench profile's boards "
                            "(e.g. mecarover-can); repeatable")
        g.add_argument("--eds", action="append", default=[], metavar="FILE:NODE",
                       help="an EDS and the node it describes: object names for SDO transfers, PDOs decoded by its "
                            "mapping; repeatable")
        g.add_argument("--no-canopen", action="store_true",
                       help="do not read frames as CANopen (NMT, heartbeat, SDO, EMCY by COB-ID)")
        g.add_argument("--miss-factor", type=MISS_FACTOR, default=1.5,
                       help="a heartbeat gap longer than this many periods is a miss (default 1.5)")

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        decoders = []
        if args.dbc or args.eds:  # (cantools and canopen only for a monitor that was given a file to load)
            from hilbench.monitor.can.decoders import load_dbc, load_eds

            decoders = [load_dbc(spec) for spec in args.dbc] + [load_eds(spec) for spec in args.eds]
        return {"decoders": decoders, "canopen": not args.no_canopen, "miss_factor": args.miss_factor}

    def input_files(self, args: argparse.Namespace) -> list[str]:
        # --dbc FILE (or a profile's name: no file) and --eds FILE:NODE
        return [*(getattr(args, "dbc", None) or []),
                *(e.rpartition(":")[0] or e for e in getattr(args, "eds", None) or [])]

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> CanTracker:
        from hilbench.monitor.can.tracker import CanTracker

        return CanTracker(baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: CanTracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        from hilbench.monitor.can.summary import summary

        return summary(tracker, source=source, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        from hilbench.monitor.can.summary import print_summary

        print_summary(report, console)


#: The plug-in (entry point ``can`` of ``hilbench.instruments``).
INSTRUMENT = CanInstrument()

__all__ = ["INSTRUMENT", "CanInstrument"]
