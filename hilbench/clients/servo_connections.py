"""One servo bus seen through its vendor's own SDK: what ``hilbench demo`` drives (the kit).

Each servo family registers a :class:`ServoClient` (role ``servo``, entry
point ``hilbench.clients`` named after its bus protocol) that opens its buses
the way its robots drive them, with a :class:`ServoConnection` of its own: the
Dynamixel family's through the official ``dynamixel-sdk``
(:mod:`hilbench.clients.dynamixel_servos`), the Feetech family's through
Feetech's ``scservo_sdk`` (:mod:`hilbench.clients.feetech`). The demo finds
them with :func:`servo_clients` and names no family.

A connection reads and writes control-table :class:`~hilbench.protocols.control_table.Field` s
(so it encodes sign-magnitude and big-endian words as the model says) and
answers ``None`` for what did not come back; it never raises for a device
that is silent. :func:`layout` finds the registers the demo uses in any
model's table.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from hilbench.clients.base import ClientDriver
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
    #: Whether its servos report their condition in every status's error byte (Protocol 1.0, Feetech) rather
    #: than in a Hardware Error Status register (Protocol 2.0).
    status_errors: ClassVar[bool] = False

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


class ServoClient(ClientDriver):
    """A servo family's host side for ``hilbench demo`` (role ``servo``): subclasses open their links."""

    role = "servo"
    #: The bus's name in messages ("a servo bus (Dynamixel or Feetech)").
    bus_title: ClassVar[str] = ""

    def check(self) -> None:
        """Raise :class:`~hilbench.errors.MissingExtra` (one line) if the SDK is not installed, before a bench
        starts."""

    def connection(self, options: Mapping[str, Any], path: str, baud: int,
                   models: Iterable[Model] = ()) -> ServoConnection:
        """The connection that drives a bench endpoint of its protocol (``options``: the endpoint's, e.g. the
        Dynamixel ``protocol_version``; ``models``: its servos')."""
        raise NotImplementedError

    def sensor_reads(self, devices: Iterable[tuple[int, Model]]) -> list[tuple[int, int, int]]:
        """``(id, address, size)`` reads a robot makes now and then of the bus's devices that are not servos
        (``devices``: their IDs and models), e.g. the Wolfgang foot sensor."""
        return []


def servo_clients() -> dict[str, ServoClient]:
    """Protocol -> its :class:`ServoClient`, for every registered servo client (hilbench's first)."""
    from hilbench import registry

    return {c.protocol: c for c in registry.clients.values() if c.role == ServoClient.role}


__all__ = ["Layout", "ServoClient", "ServoConnection", "layout", "role_field", "servo_clients"]
