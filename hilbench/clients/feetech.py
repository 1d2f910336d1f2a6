"""The Feetech family's servo client: its buses through Feetech's own ``scservo_sdk``, as LeRobot's motor bus
drives them (Sync Read 0x82 and Sync Write), for ``hilbench demo`` (entry point ``feetech`` of
``hilbench.clients``, :data:`~hilbench.clients.feetech.CLIENT`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from hilbench.clients.servo_connections import ServoClient, ServoConnection, role_field
from hilbench.errors import DeviceError, require
from hilbench.protocols.control_table import Field, Model


class FeetechConnection(ServoConnection):
    """Feetech STS/SCS through Feetech's own ``scservo_sdk``: Sync Read 0x82 and Sync Write."""

    protocol = "feetech"
    status_errors = True

    def __init__(self, path: str, baud: int, *, big_endian: bool = False) -> None:
        super().__init__(path, baud)
        self.big_endian = big_endian

    def open(self) -> None:
        scs = feetech_sdk()
        self._scs = scs
        # the SDK keeps the word order in a global: SCS servos store words big-endian (END 1), STS little
        scs.scservo_def.SCS_SETEND(1 if self.big_endian else 0)
        from hilbench.transports.serial_url import check_port

        check_port(self.path)
        self.port = scs.PortHandler(self.path)
        try:
            opened = self.port.openPort() and self.port.setBaudRate(self.baud)
        except Exception as exc:  # pyserial's SerialException with the OS reason
            raise DeviceError(f"cannot open {self.path}: {exc}") from None
        if not opened:
            raise DeviceError(f"Feetech's SDK cannot open {self.path} at {self.baud} baud")
        self.ph = scs.PacketHandler(1 if self.big_endian else 0)
        self._readers: dict[tuple[int, int, tuple[int, ...]], Any] = {}

    def ping(self, dev_id: int) -> bool:
        return self.ph.ping(self.port, dev_id)[1] == self._scs.COMM_SUCCESS

    def read(self, dev_id: int, address: int, size: int) -> bytes | None:
        data, result, _ = self.ph.readTxRx(self.port, dev_id, address, size)
        return bytes(data) if result == self._scs.COMM_SUCCESS else None

    def group_read(self, address: int, size: int, ids: list[int]) -> tuple[dict[int, bytes], int]:
        key = (address, size, tuple(ids))
        reader = self._readers.get(key)
        if reader is None:
            reader = self._readers[key] = self._scs.GroupSyncRead(self.port, self.ph, address, size)
            for i in ids:
                reader.addParam(i)
        # The SDK stops at the first servo that stays silent and leaves the others' statuses unread;
        # drop them before asking again (its clearPort only flushes output).
        self.port.ser.reset_input_buffer()
        result = reader.txRxPacket()
        got = {i: bytes(reader.data_dict[i]) for i in ids if len(reader.data_dict.get(i) or ()) == size}
        return got, 0 if result == self._scs.COMM_SUCCESS else 1

    def sync_write(self, f: Field, values: dict[int, int]) -> None:
        writer = self._scs.GroupSyncWrite(self.port, self.ph, f.address, f.size)
        for i, v in values.items():
            writer.addParam(i, list(f.encode(v)))
        writer.txPacket()


def feetech_sdk() -> Any:
    """Feetech's ``scservo_sdk``, or a one-line :class:`~hilbench.errors.MissingExtra` naming what to install."""
    return require("scservo_sdk", "feetech", "driving a Feetech bus", package="feetech-servo-sdk")



class FeetechServoClient(ServoClient):
    """Feetech STS/SCS buses for ``hilbench demo``: SCS servos keep words big-endian, STS little-endian."""

    protocol = "feetech"
    title = "Feetech servo bus host (scservo_sdk)"
    bus_title = "Feetech"

    def check(self) -> None:
        feetech_sdk()

    def connection(self, options: Mapping[str, Any], path: str, baud: int,
                   models: Iterable[Model] = ()) -> ServoConnection:
        models = list(models)
        big = bool(models) and all((f := role_field(m, "present_position")) is not None and f.big_endian
                                   for m in models)
        return FeetechConnection(path, baud, big_endian=big)


#: The client driver this module registers (entry point ``hilbench.clients``).
CLIENT = FeetechServoClient()

__all__ = ["CLIENT", "FeetechConnection", "FeetechServoClient", "feetech_sdk"]
