"""One servo bus seen through its vendor's own SDK: what ``hilbench demo`` drives.

Each kind of bus is driven the way its robots drive it:

- Dynamixel Protocol 2.0 (X series, MX 2.0, XL-320): the official
  ``dynamixel-sdk`` with Sync Read and Sync Write (:class:`Dxl2Connection`);
- Dynamixel Protocol 1.0 (AX, MX 1.0, pypot's robots): the same SDK's
  Protocol 1.0 handler, which has no Sync Read: one Read per servo, and Sync
  Write (:class:`Dxl1Connection`);
- Feetech STS/SCS (SO-100/SO-101): Feetech's ``scservo_sdk`` with its Sync
  Read 0x82 and Sync Write, as LeRobot's motor bus does (:class:`FeetechConnection`).

A connection reads and writes control-table :class:`~hilbench.protocols.control_table.Field` s
(so it encodes sign-magnitude and big-endian words as the model says) and
answers ``None`` for what did not come back; it never raises for a device
that is silent. :func:`layout` finds the registers the demo uses in any
model's table.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, ClassVar

from hilbench.errors import DeviceError, UsageError, require
from hilbench.protocols.control_table import Field, Model

#: Register roles the demo uses, and their names in the X-series tables (which have no roles).
_X_KEYS = {
    "torque_enable": "torque_enable",
    "goal_position": "goal_position",
    "present_position": "present_position",
    "present_voltage": "present_input_voltage",
    "present_temperature": "present_temperature",
    "hardware_error": "hardware_error_status",
    "min_position": "min_position_limit",
    "max_position": "max_position_limit",
    "temperature_limit": "temperature_limit",
}


def role_field(model: Model, role: str) -> Field | None:
    """The register that plays ``role`` in ``model``'s table (None if it has none)."""
    if model.roles:
        return model.role(role)
    try:
        return model.field_named(_X_KEYS[role])
    except KeyError:
        return None


@dataclass(frozen=True)
class Layout:
    """Where a servo model keeps what the demo reads and writes (servos of one layout share group packets)."""

    torque: Field
    goal: Field
    present: Field
    min_position: Field | None
    max_position: Field | None
    #: Present voltage and temperature, adjacent in every table: read as one range of ``condition_size`` bytes.
    voltage: Field | None
    condition_size: int
    hardware_error: Field | None
    temperature_limit: Field | None


def layout(model: Model) -> Layout | None:
    """The demo's registers in ``model``'s table; None for a table without torque, goal and present position."""
    torque, goal, present = (role_field(model, r) for r in ("torque_enable", "goal_position", "present_position"))
    if torque is None or goal is None or present is None:
        return None
    volt, temp = role_field(model, "present_voltage"), role_field(model, "present_temperature")
    size = temp.address + temp.size - volt.address if volt and temp and temp.address > volt.address else 0
    return Layout(torque, goal, present, role_field(model, "min_position"), role_field(model, "max_position"),
                  volt if size else None, size, role_field(model, "hardware_error"),
                  role_field(model, "temperature_limit"))


class ServoConnection:
    """A servo bus opened through an SDK (see the module docstring); use as a context manager."""

    #: The traffic's name to taps and monitors.
    protocol: ClassVar[str] = ""
    #: Whether one request reads a range from every listed servo (Sync Read); else one Read each.
    group_reads: ClassVar[bool] = True

    def __init__(self, path: str, baud: int) -> None:
        self.path = path
        self.baud = baud
        self.port: Any = None
        self.ph: Any = None

    def __enter__(self) -> ServoConnection:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.port.closePort()

    def ping(self, dev_id: int) -> bool:
        """Whether ``dev_id`` answers a Ping."""
        raise NotImplementedError

    def read(self, dev_id: int, address: int, size: int) -> bytes | None:
        """``size`` bytes at ``address`` of one device, or None if it did not answer."""
        raise NotImplementedError

    def read_field(self, dev_id: int, f: Field) -> int | float | None:
        raw = self.read(dev_id, f.address, f.size)
        return f.decode(raw) if raw is not None and len(raw) == f.size else None

    def group_read(self, address: int, size: int, ids: list[int]) -> tuple[dict[int, bytes], int]:
        """``size`` bytes at ``address`` of every listed device: (what came back by ID, requests that failed)."""
        got: dict[int, bytes] = {}
        failed = 0
        for i in ids:
            raw = self.read(i, address, size)
            if raw is None or len(raw) != size:
                failed += 1
            else:
                got[i] = raw
        return got, failed

    def sync_write(self, f: Field, values: dict[int, int]) -> None:
        """One Sync Write of ``f`` with a value per device (nobody answers it)."""
        raise NotImplementedError


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


class FeetechConnection(ServoConnection):
    """Feetech STS/SCS through Feetech's own ``scservo_sdk``: Sync Read 0x82 and Sync Write."""

    protocol = "feetech"

    def __init__(self, path: str, baud: int, *, big_endian: bool = False) -> None:
        super().__init__(path, baud)
        self.big_endian = big_endian

    def open(self) -> None:
        scs = feetech_sdk()
        self._scs = scs
        # the SDK keeps the word order in a global: SCS servos store words big-endian (END 1), STS little
        scs.scservo_def.SCS_SETEND(1 if self.big_endian else 0)
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


def connection_for(protocol: str, version: int, path: str, baud: int, models: Iterable[Model] = ()) -> ServoConnection:
    """The connection that drives a bench endpoint of ``protocol`` (``protocol_version`` for Dynamixel)."""
    if protocol == "feetech":
        models = list(models)
        big = bool(models) and all((f := role_field(m, "present_position")) is not None and f.big_endian
                                   for m in models)
        return FeetechConnection(path, baud, big_endian=big)
    if protocol == "dynamixel":
        return (Dxl1Connection if version == 1 else Dxl2Connection)(path, baud)
    raise UsageError(f"no SDK connection for {protocol!r} buses")


__all__ = ["Dxl1Connection", "Dxl2Connection", "FeetechConnection", "Layout", "ServoConnection", "feetech_sdk", "layout", "connection_for",
           "role_field"]
