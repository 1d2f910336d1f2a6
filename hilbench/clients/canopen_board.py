"""The CANopen board family's control commands from another process (``hilbench can status|fault|...``).

A bench's control channel (:class:`~hilbench.bench.control.ControlClient`) with named methods for the
commands of :attr:`hilbench.families.canopen_board.CanopenBoardFamily.control_commands` and the CAN bus's
own ``bus`` command::

    from hilbench.clients.canopen_board import CanClient

    CanClient.from_manifest("bench.json").fault("rover", motor_fault=True)
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.control import ControlClient


class CanClient(ControlClient):
    """The CANopen board family's control commands from another process (``hilbench can`` uses it)."""

    def status(self, device: str | None = None) -> dict[str, Any]:
        return self.call("status", device=device)

    def nmt(self, state: str, device: str | None = None) -> dict[str, Any]:
        return self.call("nmt", device=device, state=state)["status"]

    def reset(self, device: str | None = None) -> dict[str, Any]:
        return self.call("reset", device=device)["status"]

    def fault(self, device: str | None = None, **knobs: Any) -> dict[str, Any]:
        return self.call("fault", device=device, knobs=knobs)["faults"]

    def emcy(self, code: int, register: int = 0x80, data: str = "", device: str | None = None) -> dict[str, Any]:
        return self.call("emcy", device=device, code=code, register=register, data=data)["status"]

    def bus(self, device: str | None = None, **knobs: Any) -> dict[str, Any]:
        return self.call("bus", device=device, knobs=knobs)["bus"]


__all__ = ["CanClient"]
