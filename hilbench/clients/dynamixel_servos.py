"""The Dynamixel family's servo client: its buses through the official ``dynamixel-sdk``, as ``hilbench demo``
drives them (entry point ``dynamixel`` of ``hilbench.clients``,
:data:`~hilbench.clients.dynamixel_servos.CLIENT`).

- Protocol 2.0 (X series, MX 2.0, XL-320): Sync Read and Sync Write (:class:`Dxl2Connection`);
- Protocol 1.0 (AX, MX 1.0, pypot's robots): the same SDK's Protocol 1.0 handler, which has no Sync Read:
  one Read per servo, and Sync Write (:class:`Dxl1Connection`).

The SDK is imported when a link opens (:mod:`hilbench.clients.dynamixel`'s port handler): listing the
clients loads neither.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar

from hilbench.clients.servo_connections import ServoClient, ServoConnection
from hilbench.protocols.control_table import Field, Model

#: The Wolfgang robot's foot sensor (a device on the servo bus that is not a servo): what its robot reads of it.
FOOT_MODEL = "Wolfgang Foot"
FOOT_READ = (36, 16)


class _DynamixelConnection(ServoConnection):
    version: ClassVar[float] = 2.0

    def open(self) -> None:
        import dynamixel_sdk as sdk

        from hilbench.clients.dynamixel import open_port

        self._sdk = sdk
        self._ctx = open_port(self.path, self.baud)
        self.port = self._ctx.__enter__()
        self.ph = sdk.PacketHandler(self.version)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._ctx.__exit__(None, None, None)

    def ping(self, dev_id: int) -> bool:
        return self.ph.ping(self.port, dev_id)[1] == self._sdk.COMM_SUCCESS

    def read(self, dev_id: int, address: int, size: int) -> bytes | None:
        data, result, _ = self.ph.readTxRx(self.port, dev_id, address, size)
        return bytes(data) if result == self._sdk.COMM_SUCCESS else None

    def sync_write(self, f: Field, values: dict[int, int]) -> None:
        writer = self._sdk.GroupSyncWrite(self.port, self.ph, f.address, f.size)
        for i, v in values.items():
            writer.addParam(i, list(f.encode(v)))
        writer.txPacket()


class Dxl2Connection(_DynamixelConnection):
    """Dynamixel Protocol 2.0 through the official SDK: Sync Read and Sync Write."""

    protocol = "dynamixel"
    version = 2.0

    def open(self) -> None:
        super().open()
        self._readers: dict[tuple[int, int, tuple[int, ...]], Any] = {}

    def group_read(self, address: int, size: int, ids: list[int]) -> tuple[dict[int, bytes], int]:
        key = (address, size, tuple(ids))
        reader = self._readers.get(key)
        if reader is None:  # made once per range and list, as a control loop does
            reader = self._readers[key] = self._sdk.GroupSyncRead(self.port, self.ph, address, size)
            for i in ids:
                reader.addParam(i)
        if reader.txRxPacket() != self._sdk.COMM_SUCCESS:
            return {}, 1
        return {i: bytes(reader.data_dict[i]) for i in ids if len(reader.data_dict.get(i) or ()) == size}, 0


class Dxl1Connection(_DynamixelConnection):
    """Dynamixel Protocol 1.0 through the official SDK: a Read per servo (it has no Sync Read), Sync Write."""

    protocol = "dynamixel1"
    version = 1.0
    group_reads = False
    status_errors = True


class DynamixelServoClient(ServoClient):
    """Dynamixel buses (Protocol 2.0 and 1.0, by the endpoint's ``protocol_version``) for ``hilbench demo``."""

    protocol = "dynamixel"
    title = "Dynamixel servo bus host (dynamixel-sdk)"
    bus_title = "Dynamixel"

    def connection(self, options: Mapping[str, Any], path: str, baud: int,
                   models: Iterable[Model] = ()) -> ServoConnection:
        return (Dxl1Connection if options.get("protocol_version", 2) == 1 else Dxl2Connection)(path, baud)

    def sensor_reads(self, devices: Iterable[tuple[int, Model]]) -> list[tuple[int, int, int]]:
        return [(i, *FOOT_READ) for i, model in devices if model.name == FOOT_MODEL]


#: The client driver this module registers (entry point ``hilbench.clients``).
CLIENT = DynamixelServoClient()

__all__ = ["CLIENT", "Dxl1Connection", "Dxl2Connection", "DynamixelServoClient"]
