"""The Dynamixel bus monitor: turning Protocol 2.0 traffic into device and bus state.

- :class:`~hilbench.monitor.dynamixel.tracker.BusTracker`: pure state machine, fed bytes
  with times (no I/O), testable with bytes alone;
- :class:`~hilbench.monitor.servo_bus.devices.DeviceState`: what is known about one device;
- :func:`~hilbench.monitor.servo_bus.summary.summary`: the JSON summary;
- :data:`INSTRUMENT`: the plug-in (``hilbench.instruments`` entry point ``dynamixel``):
  options, tracker, summary and dashboard views for the generic monitor frames.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from hilbench.monitor.instrument import Instrument
from hilbench.rules import SECONDS, Rule

if TYPE_CHECKING:  # the tracker (numpy) is imported when one is made: the plug-in stays light
    from hilbench.monitor.dynamixel.tracker import BusTracker

#: ``--miss-limit``: consecutive missed replies before a device counts as disconnected.
MISS_LIMIT = Rule(int, 0, 1_000_000)
#: ``--max-length``: the largest LENGTH field the decoder accepts (the field is 16 bits; 3 is the least).
MAX_LENGTH = Rule(int, 3, 0xFFFF)


class DynamixelInstrument(Instrument):
    """The Dynamixel Protocol 2.0 bus monitor as an instrument plug-in."""

    protocol = "dynamixel"
    title = "Dynamixel Protocol 2.0 bus"
    views_path = "hilbench.dashboard.servo_bus_views:VIEW_SET"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols.dynamixel import Decoder
        from hilbench.protocols.problem import Problem

        items = Decoder().feed(data[:8192])
        packets = sum(1 for i in items if not isinstance(i, Problem))
        problems = len(items) - packets
        return packets / (packets + problems + 1) if packets else 0.0

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("Dynamixel bus")
        g.add_argument("--silence", type=SECONDS, default=1.0,
                       help="disconnect a device owing a reply that said nothing for S seconds (0: off; default 1)")
        g.add_argument("--miss-limit", type=MISS_LIMIT, default=4,
                       help="disconnect after more than N consecutive missed replies (default 4, as the thesis "
                            "monitor)")
        g.add_argument("--max-length", type=MAX_LENGTH, default=1024,
                       help="largest LENGTH accepted (default 1024 like the SDK; 65535 counts like the spec sheet)")

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        # checked by the options' rules as they were parsed
        return {"silence": args.silence, "max_length": args.max_length, "miss_limit": args.miss_limit}

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> BusTracker:
        from hilbench.monitor.dynamixel.tracker import BusTracker

        return BusTracker(baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: BusTracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        from hilbench.monitor.servo_bus.summary import summary

        return summary(tracker, source=source, protocol=self.protocol, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        from hilbench.monitor.servo_bus.summary import print_summary

        print_summary(report, console)


#: The plug-in (entry point ``dynamixel`` of ``hilbench.instruments``).
INSTRUMENT = DynamixelInstrument()

__all__ = ["INSTRUMENT", "DynamixelInstrument"]
