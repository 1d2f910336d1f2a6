"""The Dynamixel Protocol 1.0 bus monitor (AX, MX with 1.0 firmware, the USB2AX's SYNC_READ).

:data:`INSTRUMENT` is the ``hilbench.instruments`` plug-in ``dynamixel1`` (a
:class:`~hilbench.monitor.servo_bus.Protocol1Instrument` of the servo-bus kit): a
:class:`~hilbench.monitor.servo_bus.protocol1.Bus1Tracker` with the Protocol 1.0
:data:`~hilbench.monitor.dynamixel1.dialect.DIALECT`, the Dynamixel monitor's summary and dashboard views. A bench's
Protocol 1.0 endpoint names its traffic ``dynamixel1``; a raw dump is told from
Protocol 2.0 (whose header is ``FF FF FD 00``) and from Feetech (whose traffic
reads other addresses and uses SYNC_READ 0x82) by its first bytes.
"""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.servo_bus import Protocol1Instrument, sniff_protocol1
from hilbench.protocols import dynamixel_protocol1 as p1


def describe_error(err: int) -> str:
    """A Protocol 1.0 ERR byte in words."""
    if not err:
        return "ok"
    return ", ".join(name for bit, name in p1.ERROR_BITS.items() if err & bit) or f"0x{err:02x}"


#: Addresses Protocol 1.0 clients read and write (model, limits, goal/present position, torque, LED).
_TYPICAL = {(0x02, 0), (0x02, 36), (0x02, 6), (0x02, 5), (0x02, 43), (0x02, 42), (0x83, 30), (0x83, 24), (0x83, 26),
            (0x84, 36), (0x84, 30), (0x84, 24), (0x03, 30), (0x03, 24), (0x03, 25)}


class Dynamixel1Instrument(Protocol1Instrument):
    """The Dynamixel Protocol 1.0 bus monitor as an instrument plug-in."""

    protocol = "dynamixel1"
    aliases = ("dynamixel-1.0", "dxl1")
    title = "Dynamixel Protocol 1.0 bus"
    dialect_path = "hilbench.monitor.dynamixel1.dialect:DIALECT"
    _typical: ClassVar[set[tuple[int, int]]] = _TYPICAL
    _own: ClassVar[set[int]] = {0x84, 0x92}


#: The plug-in (entry point ``dynamixel1`` of ``hilbench.instruments``).
INSTRUMENT = Dynamixel1Instrument()

__all__ = ["INSTRUMENT", "Dynamixel1Instrument", "Protocol1Instrument", "describe_error", "sniff_protocol1"]
