"""What Protocol 1.0-framed bytes mean on a Feetech bus: the dialect its tracker reads them with.

:data:`DIALECT` names Feetech's device tables, error bits, SYNC_READ and big-endian SCS models; imported
when a tracker is made."""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.servo_bus.devices import DeviceState
from hilbench.monitor.servo_bus.protocol1 import Dialect
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


__all__ = ["DIALECT", "FeetechDevice"]
