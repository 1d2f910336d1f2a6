"""A running node's object dictionary: values of the entries a device describes, with CiA 301 access rules.

Reads and writes go through :meth:`ObjectDictionary.read` and
:meth:`ObjectDictionary.write`, which answer with the bytes (or nothing) or a
CiA 301 SDO abort code, never an exception. The device hooks its behaviour
in: ``on_read`` refreshes live values before they are read (the odometry),
``on_write`` checks and applies a written value (the heartbeat period) and may
refuse it with an abort code.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hilbench.protocols import canopen as co
from hilbench.protocols import canopen_od as od

#: ``on_write(index, subindex, value) -> abort code or None``.
WriteHook = Callable[[int, int, Any], int | None]
#: ``on_read(index, subindex) -> None`` (refresh the value before it is read).
ReadHook = Callable[[int, int], None]


class ObjectDictionary:
    """Values of a dictionary description (:mod:`hilbench.protocols.canopen_od`) for node ``node_id``."""

    def __init__(self, entries: list[od.Entry], node_id: int) -> None:
        self.entries = {e.index: e for e in entries}
        self.vars = od.variables(entries)
        self.node_id = node_id
        self.values: dict[tuple[int, int], Any] = {}
        self.read_hooks: dict[int, ReadHook] = {}
        self.write_hooks: dict[int, WriteHook] = {}
        self.reset()

    def reset(self, lo: int = 0x0000, hi: int = 0xFFFF) -> None:
        """Every value of indexes ``lo``..``hi`` back to its default (a reset of the node or its communication)."""
        for key, var in self.vars.items():
            if lo <= key[0] <= hi:
                self.values[key] = od.resolve(var.default, self.node_id)

    def on_read(self, index: int, hook: ReadHook) -> None:
        self.read_hooks[index] = hook

    def on_write(self, index: int, hook: WriteHook) -> None:
        self.write_hooks[index] = hook

    def __getitem__(self, key: tuple[int, int]) -> Any:
        return self.values[key]

    def __setitem__(self, key: tuple[int, int], value: Any) -> None:
        """Set a value from the device's side (no access check)."""
        self.values[key] = value

    def lookup(self, index: int, subindex: int) -> od.Variable | int:
        """The variable at ``index``/``subindex``, or the abort code saying why there is none."""
        var = self.vars.get((index, subindex))
        if var is not None:
            return var
        return co.ABORT_NO_SUBINDEX if index in self.entries else co.ABORT_NO_OBJECT

    def read(self, index: int, subindex: int) -> bytes | int:
        """The bytes of a value as an SDO upload returns them, or an abort code."""
        var = self.lookup(index, subindex)
        if isinstance(var, int):
            return var
        if var.access == "wo":
            return co.ABORT_WRITE_ONLY
        hook = self.read_hooks.get(index)
        if hook is not None:
            hook(index, subindex)
        try:
            return od.encode(var.data_type, self.values[(index, subindex)])
        except (ValueError, OverflowError, TypeError):
            return co.ABORT_GENERAL

    def write(self, index: int, subindex: int, data: bytes) -> int | None:
        """Store an SDO download; None when done, else the abort code."""
        var = self.lookup(index, subindex)
        if isinstance(var, int):
            return var
        if var.access in ("ro", "const"):
            return co.ABORT_READ_ONLY
        size = od.type_size(var.data_type)
        if size is not None and len(data) != size:
            return co.ABORT_TOO_LONG if len(data) > size else co.ABORT_TOO_SHORT
        try:
            value = od.decode(var.data_type, bytes(data))
        except ValueError:
            return co.ABORT_LENGTH
        if var.low is not None and value < var.low:
            return co.ABORT_VALUE_LOW
        if var.high is not None and value > var.high:
            return co.ABORT_VALUE_HIGH
        hook = self.write_hooks.get(index)
        if hook is not None:
            code = hook(index, subindex, value)
            if code:
                return code
        self.values[(index, subindex)] = value
        return None


__all__ = ["ObjectDictionary", "ReadHook", "WriteHook"]
