"""The Dynamixel Protocol 1.0 bus monitor (AX, MX with 1.0 firmware, the USB2AX's SYNC_READ).

:data:`INSTRUMENT` is the ``hilbench.instruments`` plug-in ``dynamixel1``: a
:class:`~hilbench.monitor.dynamixel1.tracker.Bus1Tracker` with the Protocol 1.0
:data:`~hilbench.monitor.dynamixel1.dialect.DIALECT`, the Dynamixel monitor's summary and dashboard views. A bench's
Protocol 1.0 endpoint names its traffic ``dynamixel1``; a raw dump is told from
Protocol 2.0 (whose header is ``FF FF FD 00``) and from Feetech (whose traffic
reads other addresses and uses SYNC_READ 0x82) by its first bytes.
"""

from __future__ import annotations

import argparse
import importlib
from typing import TYPE_CHECKING, Any, ClassVar

from hilbench.errors import UsageError
from hilbench.monitor.instrument import Instrument
from hilbench.protocols import dynamixel_protocol1 as p1

if TYPE_CHECKING:
    from hilbench.monitor.dynamixel1.tracker import Bus1Tracker, Dialect


def describe_error(err: int) -> str:
    """A Protocol 1.0 ERR byte in words."""
    if not err:
        return "ok"
    return ", ".join(name for bit, name in p1.ERROR_BITS.items() if err & bit) or f"0x{err:02x}"


#: Addresses Protocol 1.0 clients read and write (model, limits, goal/present position, torque, LED).
_TYPICAL = {(0x02, 0), (0x02, 36), (0x02, 6), (0x02, 5), (0x02, 43), (0x02, 42), (0x83, 30), (0x83, 24), (0x83, 26),
            (0x84, 36), (0x84, 30), (0x84, 24), (0x03, 30), (0x03, 24), (0x03, 25)}


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


def _int(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


class Protocol1Instrument(Instrument):
    """A Protocol 1.0-framed servo bus monitor; subclasses give the dialect."""

    #: ``"module:ATTRIBUTE"`` of its :class:`~hilbench.monitor.dynamixel1.tracker.Dialect`, imported when first
    #: used (a tracker, a summary line): the plug-in itself imports no tracker and no device table.
    dialect_path: ClassVar[str] = "hilbench.monitor.dynamixel1.dialect:DIALECT"
    views_path = "hilbench.dashboard.dynamixel_views:VIEW_SET"
    _typical: ClassVar[set[tuple[int, int]]] = _TYPICAL
    _own: ClassVar[set[int]] = {0x84, 0x92}
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
        from hilbench.monitor.dynamixel1.tracker import Bus1Tracker

        options.pop("max_length", None)
        return Bus1Tracker(self.dialect, baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: Bus1Tracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        from hilbench.monitor.dynamixel.summary import summary

        return summary(tracker, source=source, protocol=self.protocol, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        from hilbench.monitor.dynamixel.summary import print_summary

        print_summary(report, console)


class Dynamixel1Instrument(Protocol1Instrument):
    """The Dynamixel Protocol 1.0 bus monitor as an instrument plug-in."""

    protocol = "dynamixel1"
    aliases = ("dynamixel-1.0", "dxl1")
    title = "Dynamixel Protocol 1.0 bus"


#: The plug-in (entry point ``dynamixel1`` of ``hilbench.instruments``).
INSTRUMENT = Dynamixel1Instrument()

__all__ = ["INSTRUMENT", "Dynamixel1Instrument", "Protocol1Instrument", "describe_error", "sniff_protocol1"]
