"""The Dynamixel family's labgrid driver: Protocol 2.0 on a bus through labgrid's ``ConsoleProtocol``.

``DynamixelDriver``: ``ping``, ``read``, ``write``, ``sync_read``,
``broadcast_ping``; packets built and parsed by
:mod:`hilbench.protocols.dynamixel`. It sits on the ``SerialDriver`` of a
``NetworkSerialPort`` (a served bench's endpoint), ``RawSerialPort`` or
``USBSerialPort`` (a U2D2 on the exporter), so one labgrid test suite drives
an emulated bus and a real one alike. As a
:class:`~hilbench.labgrid.drivers.BusProtocol` it is what
:class:`~hilbench.labgrid.drivers.HilbenchStrategy` binds as its ``bus``.

The Dynamixel bus kind names it
(:meth:`~hilbench.families.dynamixel.DynamixelBusKind.labgrid_driver`), so
``hilbench labgrid env`` puts one on each served Protocol 2.0 endpoint and
lists this module under ``imports:`` (importing it registers the driver with
labgrid). Needs labgrid (``pip install 'hilbench[labgrid]'``).
"""

from __future__ import annotations

import time

import attr
from labgrid.driver import Driver
from labgrid.factory import target_factory
from labgrid.protocol import ConsoleProtocol
from labgrid.step import step
from pexpect import TIMEOUT

from hilbench.errors import DeviceError
from hilbench.labgrid.drivers import BusProtocol
from hilbench.protocols import dynamixel as dxl


@target_factory.reg_driver
@attr.s(eq=False)
class DynamixelDriver(Driver, BusProtocol):
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

    def ready(self, addresses: list[int]) -> None:
        """:class:`~hilbench.labgrid.drivers.HilbenchStrategy`'s check: each of ``addresses`` (servo IDs) pings,
        or with none listed a broadcast ping finds a device; :class:`~hilbench.errors.DeviceError` if not."""
        if addresses:
            for dxl_id in addresses:
                self.ping(dxl_id)
        elif not self.broadcast_ping():
            raise DeviceError("no Dynamixel device answered a broadcast ping")


__all__ = ["DynamixelDriver"]
