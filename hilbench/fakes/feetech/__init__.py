"""Emulated Feetech STS/SCS servos on a serial bus (the SO-100/SO-101 arms' servos)."""

from hilbench.fakes.feetech.bus import FeetechBus
from hilbench.fakes.table_servo import TableServo

__all__ = ["FeetechBus", "TableServo"]
