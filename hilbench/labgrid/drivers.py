"""labgrid drivers and a strategy that speak to a bench through labgrid's protocols.

Importing this module registers them with labgrid (an environment lists it
under ``imports:``; ``hilbench labgrid env`` does). They sit on labgrid's
``ConsoleProtocol`` (the ``SerialDriver`` of a ``NetworkSerialPort``,
``RawSerialPort`` or ``USBSerialPort``), so one labgrid test suite drives an
emulated bench and a real one (a U2D2 on the exporter) alike:

``DynamixelDriver``
    Protocol 2.0 on the bus: ``ping``, ``read``, ``write``, ``sync_read``,
    ``broadcast_ping``; packets built and parsed by
    :mod:`hilbench.protocols.dynamixel`.
``BenchControlDriver``
    The bench's control channel (a raw ``NetworkSerialPort``): ``call(cmd,
    **args)``, ``manifest()``, ``devices()``, ``status()``, ``button()``.
``HilbenchStrategy``
    States ``off`` and ``ready``: ready means the drivers are active and the
    bench answers (the listed servo IDs ping, the control channel replies).

Needs labgrid (``pip install 'hilbench[labgrid]'``).
"""

from __future__ import annotations

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

from hilbench.errors import BenchError, DeviceError
from hilbench.protocols import dynamixel as dxl


@target_factory.reg_driver
@attr.s(eq=False)
class DynamixelDriver(Driver):
    """Dynamixel Protocol 2.0 through a console (``bindings: {console: ...}``); ``timeout`` per reply in s."""

    bindings = {"console": ConsoleProtocol}
    timeout = attr.ib(default=0.5, validator=attr.validators.instance_of(float))

    def on_activate(self) -> None:
        self._decoder = dxl.Decoder()

    def _drain(self) -> None:
        """Drop stale input (a late reply of an earlier request) before a new request."""
        while True:
            try:
                self.console.read(size=1, timeout=0.0)
            except TIMEOUT:
                break
        self._decoder = dxl.Decoder()

    def _transact(self, packet: bytes, expect: list[int]) -> dict[int, dxl.StatusPacket]:
        """Send ``packet``; collect status packets of the IDs in ``expect`` until all came or time ran out."""
        self._drain()
        self.console.write(packet)
        replies: dict[int, dxl.StatusPacket] = {}
        deadline = time.monotonic() + self.timeout
        while len(replies) < len(expect) or not expect:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                data = self.console.read(size=1, timeout=min(left, 0.05))
            except TIMEOUT:
                continue
            for item in self._decoder.feed(data):
                if isinstance(item, dxl.StatusPacket) and (not expect or item.id in expect):
                    replies[item.id] = item
        return replies

    def _one(self, dxl_id: int, packet: bytes, what: str) -> dxl.StatusPacket:
        reply = self._transact(packet, [dxl_id]).get(dxl_id)
        if reply is None:
            raise DeviceError(f"{what}: ID {dxl_id} did not answer within {self.timeout} s")
        if reply.error & 0x7F:
            raise DeviceError(f"{what}: ID {dxl_id} reports {dxl.describe_error(reply.error)}")
        return reply

    @Driver.check_active
    @step(args=["dxl_id"], result=True)
    def ping(self, dxl_id: int) -> tuple[int, int]:
        """(model number, firmware version) of ``dxl_id``."""
        reply = self._one(dxl_id, dxl.instruction_packet(dxl_id, dxl.Instruction.PING), "ping")
        return int.from_bytes(reply.data[:2], "little"), reply.data[2]

    @Driver.check_active
    @step(result=True)
    def broadcast_ping(self, wait: float = 0.2) -> dict[int, tuple[int, int]]:
        """Every device on the bus: ID -> (model number, firmware)."""
        saved, self.timeout = self.timeout, wait
        try:
            replies = self._transact(dxl.instruction_packet(dxl.BROADCAST_ID, dxl.Instruction.PING), [])
        finally:
            self.timeout = saved
        return {i: (int.from_bytes(r.data[:2], "little"), r.data[2]) for i, r in sorted(replies.items())}

    @Driver.check_active
    @step(args=["dxl_id", "address", "length"], result=True)
    def read(self, dxl_id: int, address: int, length: int) -> bytes:
        """``length`` bytes of the control table from ``address``."""
        params = address.to_bytes(2, "little") + length.to_bytes(2, "little")
        return self._one(dxl_id, dxl.instruction_packet(dxl_id, dxl.Instruction.READ, params), "read").data

    @Driver.check_active
    @step(args=["dxl_id", "address", "data"])
    def write(self, dxl_id: int, address: int, data: bytes) -> None:
        """Write ``data`` at ``address`` and wait for the status packet."""
        self._one(dxl_id, dxl.instruction_packet(dxl_id, dxl.Instruction.WRITE, address.to_bytes(2, "little") + data),
                  "write")

    @Driver.check_active
    @step(args=["ids", "address", "length"], result=True)
    def sync_read(self, ids: list[int], address: int, length: int) -> dict[int, bytes]:
        """Sync Read: ID -> data for each ID that answered."""
        params = address.to_bytes(2, "little") + length.to_bytes(2, "little") + bytes(ids)
        replies = self._transact(dxl.instruction_packet(dxl.BROADCAST_ID, dxl.Instruction.SYNC_READ, params), ids)
        return {i: r.data for i, r in replies.items()}


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

    ``servo_ids`` are pinged on the way to ready (none: a broadcast ping must find one device).
    Either binding may be absent (a bus without a control channel, a board without a bus).
    """

    bindings = {"dynamixel": {"DynamixelDriver", None}, "control": {"BenchControlDriver", None}}
    status = attr.ib(default=Status.unknown)
    servo_ids = attr.ib(default=attr.Factory(list), validator=attr.validators.instance_of(list))

    @step(args=["status"])
    def transition(self, status: Status | str, *, step: Any) -> None:  # noqa: D417 (labgrid's signature)
        if not isinstance(status, Status):
            status = Status[status]
        if status == Status.unknown:
            raise StrategyError(f"can not transition to {status}")
        if status == self.status:
            step.skip("nothing to do")
            return
        drivers = [d for d in (self.dynamixel, self.control) if d is not None]
        if status == Status.off:
            for d in drivers:
                self.target.deactivate(d)
        else:
            for d in drivers:
                self.target.activate(d)
            if self.dynamixel is not None:
                if self.servo_ids:
                    for i in self.servo_ids:
                        self.dynamixel.ping(i)
                elif not self.dynamixel.broadcast_ping():
                    raise StrategyError("no Dynamixel device answered a broadcast ping")
            if self.control is not None:
                self.control.call("devices")
        self.status = status


__all__ = ["BenchControlDriver", "DynamixelDriver", "HilbenchStrategy", "Status"]
