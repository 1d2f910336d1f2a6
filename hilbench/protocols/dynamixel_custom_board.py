"""A generic control-table board on a Dynamixel bus: the registers a profile lists, and nothing else.

A lab's own board (a foot sensor, a power board, an IMU) answers Ping, Read
and Write like a servo but has a table of its own. Where hilbench has no
model for it, a profile describes the registers (``model = "control-table"``,
see :mod:`hilbench.families.dynamixel_custom_board`): :func:`board_model`
makes a :class:`~hilbench.protocols.control_table.Model` of kind ``board`` from
them, with the Model Number at 0, the firmware version and the ID where the
profile says (Protocol 2.0 servos' 6 and 7 by default; 2 and 3 on a Protocol
1.0 bus). Register values do not change by themselves: a read returns the
value the profile gives or the host last wrote.
"""

from __future__ import annotations

from dataclasses import dataclass

from hilbench.protocols.control_table import Field, Model

#: The model name a profile gives such a board.
CONTROL_TABLE = "control-table"
#: Register sizes (bytes).
SIZES = (1, 2, 4)
#: The largest table (bounded memory: Protocol 2.0 tables end at 661, Protocol 1.0 ones at 255).
MAX_TABLE = {1: 256, 2: 1024}
#: Where the firmware version and the ID are unless the profile says (by protocol version).
HEAD = {1: (2, 3), 2: (6, 7)}


@dataclass(frozen=True)
class Register:
    """One register of a custom board."""

    address: int
    size: int
    name: str = ""
    access: str = "RW"
    value: int = 0
    signed: bool = False

    @property
    def end(self) -> int:
        return self.address + self.size

    def field(self) -> Field:
        bits = 8 * self.size
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)
        return Field(self.address, self.size, self.name or f"Register {self.address}", self.access, self.value,
                     lo if self.access == "RW" else None, hi if self.access == "RW" else None, signed=self.signed)


def board_model(number: int, registers: list[Register], *, firmware: int = 1, protocol: int = 2,
                firmware_address: int | None = None, id_address: int | None = None) -> Model:
    """The model of a board with ``registers`` (checked: inside the table, not overlapping each other)."""
    fw_at, id_at = HEAD[protocol]
    fw_at = fw_at if firmware_address is None else firmware_address
    id_at = id_at if id_address is None else id_address
    taken = {a for r in registers for a in range(r.address, r.end)}
    fields = [r.field() for r in registers]
    head = [Field(0, 2, "Model Number", "R", number), Field(fw_at, 1, "Firmware Version", "R", firmware),
            Field(id_at, 1, "ID", "RW", 1, 0, 252)]
    fields += [f for f in head if not taken & set(range(f.address, f.address + f.size))]
    fields.sort(key=lambda f: f.address)
    size = max(f.address + f.size for f in fields)
    return Model(name=f"{CONTROL_TABLE} 0x{number:04X}", number=number, firmware=firmware, fields=tuple(fields),
                 table_size=size, kind="board", firmware_address=fw_at, id_address=id_at, protocol=protocol,
                 notes="a custom board: the registers of its profile entry")


__all__ = ["CONTROL_TABLE", "HEAD", "MAX_TABLE", "SIZES", "Register", "board_model"]
