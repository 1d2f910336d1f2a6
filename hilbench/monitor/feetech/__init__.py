"""The Feetech bus monitor (STS/SCS servos: SO-100/SO-101 arms).

:data:`INSTRUMENT` is the ``hilbench.instruments`` plug-in ``feetech``: the
Protocol 1.0-framed tracker (:mod:`hilbench.monitor.servo_bus.protocol1`) with
Feetech's :data:`~hilbench.monitor.feetech.dialect.DIALECT` (SYNC_READ 0x82 answered servo by servo, broadcast
PING answered by all, the model number at address 3, Response Status Level at
8), Feetech's control tables and ERR bits, and the servo-bus summary and views.
"""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.servo_bus import Protocol1Instrument


class FeetechInstrument(Protocol1Instrument):
    """The Feetech bus monitor as an instrument plug-in."""

    protocol = "feetech"
    aliases = ("scs", "sts")
    title = "Feetech STS/SCS servo bus"
    dialect_path = "hilbench.monitor.feetech.dialect:DIALECT"
    _usb2ax = False
    _typical: ClassVar = {(0x02, 3), (0x02, 56), (0x02, 9), (0x02, 31), (0x82, 56), (0x83, 42), (0x03, 40),
                          (0x03, 55), (0x03, 42)}
    _own: ClassVar = {0x82}


#: The plug-in (entry point ``feetech`` of ``hilbench.instruments``).
INSTRUMENT = FeetechInstrument()

__all__ = ["INSTRUMENT", "FeetechInstrument"]
