"""The STM32 rover board's control commands from another process (``hilbench board`` uses them).

A bench's control channel (:class:`~hilbench.bench.control.ControlClient`) with named methods for the
commands the rover board family serves (:attr:`hilbench.families.stm32_rover.Stm32RoverFamily.control_commands`)::

    from hilbench.clients.stm32_rover import BoardClient

    BoardClient.from_manifest("bench.json").button()
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.control import ControlClient


class BoardClient(ControlClient):
    """The rover board's control commands from another process (``hilbench board`` uses it)."""

    def status(self, device: str | None = None) -> dict[str, Any]:
        return self.call("status", device=device)["status"]

    def button(self, device: str | None = None) -> dict[str, Any]:
        return self.call("button", device=device)["status"]

    def reset(self, device: str | None = None) -> dict[str, Any]:
        return self.call("reset", device=device)["status"]

    def fault(self, device: str | None = None, **knobs: float) -> dict[str, Any]:
        return self.call("fault", device=device, knobs=knobs)["faults"]

    def log(self, device: str | None = None) -> list[str]:
        return self.call("log", device=device)["log"]

    def micro_ros(self, device: str | None = None, **knobs: int) -> dict[str, Any]:
        """The micro-ROS link's status (``zeroed_next=N``: zero its next N datagrams first)."""
        return self.call("micro_ros", device=device, **knobs)["micro_ros"]

    def wait_report(self, device: str | None = None, timeout: float = 10.0, after: int | None = None) -> dict:
        return self.call("wait_report", device=device, timeout=timeout, after=after)


__all__ = ["BoardClient"]
