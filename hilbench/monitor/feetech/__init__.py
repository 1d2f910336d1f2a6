"""The Feetech bus monitor (STS/SCS servos: SO-100/SO-101 arms).

:data:`INSTRUMENT` is the ``hilbench.instruments`` plug-in ``feetech``: the
Protocol 1.0-framed tracker (:mod:`hilbench.monitor.dynamixel1.tracker`) with
Feetech's :data:`DIALECT` (SYNC_READ 0x82 answered servo by servo, broadcast
PING answered by all, the model number at address 3, Response Status Level at
8), Feetech's control tables and ERR bits, and the servo-bus summary and views.
"""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.dynamixel.devices import DeviceState
from hilbench.monitor.dynamixel1 import Protocol1Instrument
from hilbench.monitor.dynamixel1.tracker import Dialect
from hilbench.protocols import feetech as ft
from hilbench.protocols.feetech_models import MODELS_BY_NUMBER, SCS0009, STS3215


class FeetechDevice(DeviceState):
    """A servo of a Feetech bus (its control table read with Feetech's layouts)."""

    __slots__ = ()
    models_by_number: ClassVar = MODELS_BY_NUMBER
    model_names: ClassVar = {n: m.name for n, m in MODELS_BY_NUMBER.items()}
    fallback_layout: ClassVar = STS3215


#: What Protocol 1.0-framed bytes mean on a Feetech bus (:class:`Dialect`).
DIALECT = Dialect(
    protocol="feetech",
    instruction_names=dict(ft.INSTRUCTION_NAMES),
    describe_error=ft.describe_error,
    device_class=FeetechDevice,
    sync_read=ft.Instruction.SYNC_READ,
    broadcast_ping_answered=True,
    model_address=3,
    firmware_address=0,
    status_return_level_address=8,
    read_level=0,
    write_level=1,
    big_endian_models=frozenset({SCS0009.number}),
)


class FeetechInstrument(Protocol1Instrument):
    """The Feetech bus monitor as an instrument plug-in."""

    protocol = "feetech"
    aliases = ("scs", "sts")
    title = "Feetech STS/SCS servo bus"
    dialect = DIALECT
    _typical: ClassVar = {(0x02, 3), (0x02, 56), (0x02, 9), (0x02, 31), (0x82, 56), (0x83, 42), (0x03, 40),
                          (0x03, 55), (0x03, 42)}
    _own: ClassVar = {0x82}


#: The plug-in (entry point ``feetech`` of ``hilbench.instruments``).
INSTRUMENT = FeetechInstrument()

__all__ = ["DIALECT", "INSTRUMENT", "FeetechDevice", "FeetechInstrument"]
