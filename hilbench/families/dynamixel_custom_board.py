"""Profile entries of generic control-table boards on a Dynamixel bus (``model = "control-table"``).

::

    [[devices]]
    model = "control-table"          # a board hilbench has no model of: these registers, nothing else
    id = 101
    name = "foot"
    model_number = 0xAFFE            # what its Ping reply and address 0 say
    firmware = 1
    # firmware_address = 6           # where the firmware version and the ID are (default 6 and 7 on a
    # id_address = 7                 # Protocol 2.0 bus, 2 and 3 on a Protocol 1.0 bus)
    registers = [
      { address = 36, size = 4, name = "Front Left", value = 120 },   # access "R" or "RW" (default)
      { address = 40, size = 2, access = "RW", value = 0, signed = true },
    ]

A register is 1, 2 or 4 bytes, little-endian, inside the table (1024 bytes on
Protocol 2.0, 256 on 1.0), not overlapping another. Reads return the value
given (or last written); a write must cover whole registers and hit ``RW``
ones (else the status says Access Error or Data Length Error, as a servo's).
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.checks import Checker
from hilbench.protocols.control_table import Model
from hilbench.protocols.dynamixel_custom_board import (
    CONTROL_TABLE,
    HEAD,
    MAX_TABLE,
    SIZES,
    Register,
    board_model,
)

#: Keys of a control-table board's entry beyond a servo's.
BOARD_KEYS = ("model_number", "registers", "firmware_address", "id_address")
REGISTER_KEYS = ("address", "size", "name", "access", "value", "signed")


def check_board(c: Checker, key: str, dev: dict[str, Any], protocol: int) -> Model:
    """The model of a ``control-table`` entry, its keys checked (one-line errors naming the key)."""
    top = MAX_TABLE[protocol]
    number = c.integer(dev.get("model_number", 0), f"{key}.model_number", 0, 0xFFFF)
    firmware = c.integer(dev.get("firmware", 1), f"{key}.firmware", 0, 255)
    fw_at = c.integer(dev.get("firmware_address", HEAD[protocol][0]), f"{key}.firmware_address", 2, top - 1)
    id_at = c.integer(dev.get("id_address", HEAD[protocol][1]), f"{key}.id_address", 2, top - 1)
    raw = dev.get("registers", [])
    if not isinstance(raw, list):
        c.fail(f"{key}.registers", f"expected an array of tables, got {raw!r}")
    registers: list[Register] = []
    taken: dict[int, int] = {}
    for n, item in enumerate(raw):
        where = f"{key}.registers[{n}]"
        item = c.table(item, where)
        c.unknown(item, where, REGISTER_KEYS)
        if "address" not in item:
            c.fail(f"{where}.address", "missing")
        address = c.integer(item["address"], f"{where}.address", 0, top - 1)
        size = c.integer(item.get("size", 1), f"{where}.size", 1, 4)
        if size not in SIZES:
            c.fail(f"{where}.size", f"expected 1, 2 or 4, got {size}")
        if address + size > top:
            c.fail(f"{where}.address", f"the register ends past the table ({top} bytes)")
        access = c.choice(item.get("access", "RW"), f"{where}.access", ("R", "RW"))
        signed = c.boolean(item.get("signed", False), f"{where}.signed")
        bits = 8 * size
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
        value = c.integer(item.get("value", 0), f"{where}.value", lo, hi)
        name = c.string(item.get("name", ""), f"{where}.name") if "name" in item else ""
        for a in range(address, address + size):
            if a in taken:
                c.fail(f"{where}.address", f"overlaps registers[{taken[a]}]")
            taken[a] = n
        if address < 2:
            c.fail(f"{where}.address", "0 and 1 hold the Model Number")
        registers.append(Register(address, size, name, access, value, signed))
    return board_model(number, registers, firmware=firmware, protocol=protocol, firmware_address=fw_at,
                       id_address=id_at)


__all__ = ["BOARD_KEYS", "CONTROL_TABLE", "check_board"]
