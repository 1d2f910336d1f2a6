"""The servo-bus monitor kit: what the Dynamixel (Protocol 2.0 and 1.0) and Feetech monitors share.

- :mod:`~hilbench.monitor.servo_bus.devices`: what the monitor knows of one servo
  (:class:`~hilbench.monitor.servo_bus.devices.DeviceState`);
- :mod:`~hilbench.monitor.servo_bus.bus_state`: one servo bus's state, timing and counters;
- :mod:`~hilbench.monitor.servo_bus.protocol1`: the Protocol 1.0-framed tracker and its
  :class:`~hilbench.monitor.servo_bus.protocol1.Dialect` (what the bytes mean on a bus: Dynamixel 1.0's, Feetech's);
- :mod:`~hilbench.monitor.servo_bus.summary`: the servo-bus summary;
- :class:`Protocol1Instrument`: a Protocol 1.0-framed bus's instrument, which a family subclasses with its
  protocol and dialect (:mod:`hilbench.monitor.dynamixel1`, :mod:`hilbench.monitor.feetech`).

This module stays light (the instruments that subclass it are loaded by every monitor of a raw capture).
"""

from __future__ import annotations

import argparse
import importlib
from typing import TYPE_CHECKING, Any, ClassVar

from hilbench.errors import UsageError
from hilbench.monitor.instrument import Instrument
from hilbench.protocols import dynamixel_protocol1 as p1

if TYPE_CHECKING:
    from hilbench.monitor.servo_bus.protocol1 import Bus1Tracker, Dialect


def sniff_protocol1(data: bytes, typical: set[tuple[int, int]], own_codes: set[int]) -> float:
    """How sure a Protocol 1.0-framed dialect is of ``data``: the share of valid packets, raised by what
    only that dialect sends (its own instructions, its usual addresses)."""
    items = p1.Decoder1().feed(data[:8192])
    packets = [i for i in items if type(i) is p1.Packet1]
    if not packets:
        return 0.0
    base = len(packets) / (len(items) + 1)
    hints = sum(1 for pk in packets if pk.code in own_codes
                or (pk.params and (pk.code, pk.params[0]) in typical))
    return base * (0.5 + 0.5 * min(1.0, hints / max(1, len(packets) / 4)))


class Protocol1Instrument(Instrument):
    """A Protocol 1.0-framed servo bus monitor; subclasses give the protocol and the dialect."""

    #: ``"module:ATTRIBUTE"`` of its :class:`~hilbench.monitor.servo_bus.protocol1.Dialect`, imported when first
    #: used (a tracker, a summary line): the plug-in itself imports no tracker and no device table.
    dialect_path: ClassVar[str] = ""
    views_path = "hilbench.dashboard.servo_bus_views:VIEW_SET"
    #: ``(instruction, first parameter)`` pairs its clients typically send (raise :meth:`sniff`'s score).
    _typical: ClassVar[set[tuple[int, int]]] = set()
    #: Instruction codes only its dialect sends.
    _own: ClassVar[set[int]] = set()
    #: Whether a USB2AX may sit on the bus (it answers SYNC_READ from ID 0xFD), as the dialect says.
    _usb2ax: ClassVar[bool] = True

    @property
    def dialect(self) -> Dialect:
        """What Protocol 1.0-framed bytes mean on this bus (imported on first use)."""
        module, _, attr = self.dialect_path.partition(":")
        return getattr(importlib.import_module(module), attr)

    def sniff(self, data: bytes) -> float:
        score = sniff_protocol1(data, self._typical, self._own)
        if score and self._usb2ax and b"\xff\xff\xfd" in data and b"\xff\xff\xfd\x00" not in data:
            score = min(1.0, score + 0.1)  # the USB2AX answers from ID 0xFD
        return score

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        # the Dynamixel monitor's --silence and --miss-limit serve this bus too (same names, same meaning)
        pass

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        silence = getattr(args, "silence", 1.0)
        miss_limit = getattr(args, "miss_limit", 4)
        if miss_limit < 0 or silence < 0:
            raise UsageError("--miss-limit and --silence must not be negative")
        return {"silence": silence, "miss_limit": miss_limit}

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> Bus1Tracker:
        from hilbench.monitor.servo_bus.protocol1 import Bus1Tracker

        options.pop("max_length", None)
        return Bus1Tracker(self.dialect, baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: Bus1Tracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        from hilbench.monitor.servo_bus.summary import summary

        return summary(tracker, source=source, protocol=self.protocol, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        from hilbench.monitor.servo_bus.summary import print_summary

        print_summary(report, console)


__all__ = ["Protocol1Instrument", "sniff_protocol1"]
