"""What Protocol 1.0-framed bytes mean on a Dynamixel bus: the dialect its tracker reads them with.

:data:`DIALECT` names the device tables, the error bits and the USB2AX's SYNC_READ for
:class:`~hilbench.monitor.servo_bus.protocol1.Bus1Tracker`. Its own module, imported when a tracker is
made: the instrument plug-in stays light (``hilbench monitor`` loads every instrument to tell a raw dump's
protocol)."""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.dynamixel1 import describe_error
from hilbench.monitor.servo_bus.devices import DeviceState
from hilbench.monitor.servo_bus.protocol1 import Dialect
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols.dynamixel_classic_models import MX28_1
from hilbench.protocols.dynamixel_models import MODEL_NAMES, MODELS_BY_NUMBER


class Device1(DeviceState):
    """A device of a Protocol 1.0 bus (its control table read with the 1.0 layouts)."""

    __slots__ = ()
    models_by_number: ClassVar = MODELS_BY_NUMBER
    model_names: ClassVar = MODEL_NAMES
    fallback_layout: ClassVar = MX28_1


#: What Protocol 1.0-framed bytes mean on a Dynamixel bus (:class:`Dialect`).
DIALECT = Dialect(
    protocol="dynamixel1",
    instruction_names=dict(p1.INSTRUCTION_NAMES),
    describe_error=describe_error,
    device_class=Device1,
    usb2ax_sync_read=p1.Instruction1.SYNC_READ,
    bulk_read=p1.Instruction1.BULK_READ,
)


__all__ = ["DIALECT", "Device1"]
