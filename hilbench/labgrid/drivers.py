"""labgrid drivers and a strategy that speak to any bench through labgrid's protocols.

Importing this module registers them with labgrid (an environment lists it
under ``imports:``; ``hilbench labgrid env`` does). They sit on labgrid's
``ConsoleProtocol`` (the ``SerialDriver`` of a ``NetworkSerialPort``,
``RawSerialPort`` or ``USBSerialPort``), so one labgrid test suite drives an
emulated bench and a real one alike:

``BenchControlDriver``
    The bench's control channel (a raw ``NetworkSerialPort``): ``call(cmd,
    **args)``, ``manifest()``, ``devices()``, ``status()``, ``button()``.
``HilbenchStrategy``
    States ``off`` and ``ready``: ready means the drivers are active and the
    bench answers (the bus driver finds the listed addresses, the control
    channel replies).
:class:`BusProtocol`
    What a family's bus driver offers the strategy (``ready(addresses)``).

A family's own driver for its bus (the Dynamixel family's
:class:`~hilbench.labgrid.dynamixel.DynamixelDriver`) lives in its own module
and is named by its bus kind
(:meth:`~hilbench.bench.bus.BusKind.labgrid_driver`), which is how ``hilbench
labgrid env`` puts it on the endpoint's console and imports it.

Needs labgrid (``pip install 'hilbench[labgrid]'``).
"""

from __future__ import annotations

import abc
import enum
import json
import time
from typing import Any

import attr
from labgrid.driver import Driver
from labgrid.factory import target_factory
from labgrid.protocol import ConsoleProtocol
from labgrid.step import step
from labgrid.strategy import Strategy, StrategyError
from pexpect import TIMEOUT

from hilbench.errors import BenchError


class BusProtocol(abc.ABC):
    """What :class:`HilbenchStrategy` needs of a bus driver (a labgrid protocol: the strategy binds any
    driver that implements it)."""

    @abc.abstractmethod
    def ready(self, addresses: list[int]) -> None:
        """Raise unless the devices at ``addresses`` answer (none listed: unless some device answers)."""


@target_factory.reg_driver
@attr.s(eq=False)
class BenchControlDriver(Driver):
    """A bench's control channel (JSON lines) through a console on its raw ``control`` port."""

    bindings = {"console": ConsoleProtocol}
    timeout = attr.ib(default=10.0, validator=attr.validators.instance_of(float))

    @Driver.check_active
    @step(args=["cmd"], result=True)
    def call(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command; returns the reply, raises :class:`~hilbench.errors.BenchError` if refused."""
        request = {"cmd": cmd, **{k: v for k, v in args.items() if v is not None}}
        self.console.write((json.dumps(request) + "\n").encode())
        buf = b""
        deadline = time.monotonic() + self.timeout + float(args.get("timeout") or 0)
        while not buf.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0:
                raise BenchError(f"the bench's control channel did not answer {cmd!r} within {self.timeout} s")
            try:
                buf += self.console.read(size=1, timeout=min(left, 0.5))
            except TIMEOUT:
                continue
        reply = json.loads(buf)
        if not reply.get("ok"):
            raise BenchError(str(reply.get("error", "command failed")))
        return reply

    def manifest(self) -> dict[str, Any]:
        """The bench's manifest (where everything is, the devices and their models)."""
        return self.call("manifest")["manifest"]

    def devices(self) -> dict[str, list[str]]:
        """Each device that takes commands, with the commands."""
        return self.call("devices")["devices"]

    def status(self, device: str | None = None) -> dict[str, Any]:
        """A board's status (boards that answer ``status``)."""
        return self.call("status", device=device)["status"]

    def button(self, device: str | None = None) -> dict[str, Any]:
        """Press a board's user button."""
        return self.call("button", device=device)


class Status(enum.Enum):
    unknown = 0
    off = 1
    ready = 2


@target_factory.reg_driver
@attr.s(eq=False)
class HilbenchStrategy(Strategy):
    """``off`` / ``ready`` for a bench: ready = its drivers active and answering.

    ``bus`` is a family's bus driver (a :class:`BusProtocol`); on the way to ready it checks that the devices
    at ``addresses`` answer (none listed: that one does). Either binding may be absent (a bus without a
    control channel, a board without a bus).
    """

    bindings = {"bus": {BusProtocol, None}, "control": {"BenchControlDriver", None}}
    status = attr.ib(default=Status.unknown)
    addresses = attr.ib(default=attr.Factory(list), validator=attr.validators.instance_of(list))

    @step(args=["status"])
    def transition(self, status: Status | str, *, step: Any) -> None:  # noqa: D417 (labgrid's signature)
        if not isinstance(status, Status):
            status = Status[status]
        if status == Status.unknown:
            raise StrategyError(f"can not transition to {status}")
        if status == self.status:
            step.skip("nothing to do")
            return
        drivers = [d for d in (self.bus, self.control) if d is not None]
        if status == Status.off:
            for d in drivers:
                self.target.deactivate(d)
        else:
            for d in drivers:
                self.target.activate(d)
            if self.bus is not None:
                self.bus.ready(self.addresses)
            if self.control is not None:
                self.control.call("devices")
        self.status = status


__all__ = ["BenchControlDriver", "BusProtocol", "HilbenchStrategy", "Status"]
