"""What the serial-bus servo families (Dynamixel, Feetech) share: the bus, a servo's profile entry, its checks.

A servo bus endpoint holds devices by ID, one bus object per endpoint
(``endpoint.bus``), which :class:`ServoBusKind` makes its devices join and
finds them in by their current ID (the bus kind refuses an ID taken twice,
across families). :class:`ServoBusFamily` reads the parts of a
``[[devices]]`` entry both families write the same way (model,
``id``/``ids``, ``name``), and :func:`apply_faults` turns a checked ``faults``
table into the servo's fault knobs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.rules import FAULT_COUNT, PROBABILITY, SWITCH, Rule

#: The fault knobs every emulated servo has (profile ``faults`` tables), with their rules; a family adds its own.
SERVO_FAULT_RULES = {"drop_rate": PROBABILITY, "drop_next": FAULT_COUNT, "corrupt_rate": PROBABILITY,
                     "corrupt_next": FAULT_COUNT, "delay": Rule(float, 0.0, 10.0), "vanished": SWITCH,
                     "seed": FAULT_COUNT}
#: Fault knobs a servo takes straight from a profile's ``faults`` table.
FAULT_SETTINGS = ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay")


@dataclass
class ServoBusSpec(DeviceSpec):
    """One servo of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""

    id: int = 0
    firmware: int | None = None
    init: dict[str, int | float] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    position: float | None = None
    supply_voltage: float | None = None
    ambient_temperature: float | None = None


class ServoBusKind(BusKind):
    """A servo bus on a pty: devices addressed by ``id`` join the bus object :meth:`open` makes
    (``endpoint.bus``, a :class:`~hilbench.fakes.servo_bus.ServoBusBase`)."""

    endpoint_types = ("pty",)
    address_key = "id"
    address_word = "ID"

    def join(self, endpoint, device, spec) -> None:
        endpoint.bus.add(device)

    def device_at(self, endpoint, address: int):
        return endpoint.bus.servo(address)  # by its current ID: a host may have changed it


class ServoBusAccess(FamilyAccess):
    """A servo family's devices on a running bench: by profile name (:meth:`device`), by ID, and their bus."""

    def servo(self, servo_id: int, endpoint: str | None = None) -> Any:
        """The family's device answering at ``servo_id`` now (a host may have changed its ID) on ``endpoint``
        (or the only endpoint carrying the family's devices); KeyError if there is none."""
        ep = self.endpoint(endpoint)
        try:
            device = ep.bus.servo(servo_id)
        except KeyError:
            raise KeyError(f"no {self.family.device_word} at ID {servo_id} on endpoint {ep.name!r}") from None
        if not any(d is device for d in ep.devices_of(self.family.name).values()):
            raise KeyError(f"ID {servo_id} on endpoint {ep.name!r} is not a {self.family.name} device")
        return device

    def bus(self, endpoint: str | None = None) -> Any:
        """The bus object of ``endpoint`` (or of the only endpoint carrying the family's devices):
        its ``servos``, ``stats``, ``servo(id)``."""
        return self.endpoint(endpoint).bus


class ServoBusFamily(DeviceFamily):
    """Servos addressed by ID on servo buses (a subclass says how its models are found)."""

    device_word = "servo"
    access = ServoBusAccess
    #: A model name the "missing model" error suggests.
    example_model = ""

    def find_model(self, name: Any, **how: Any) -> Any:
        """The model called ``name``; KeyError (or TypeError, AttributeError) if there is none."""
        raise NotImplementedError

    def model_names(self) -> list[str]:
        """The names :meth:`find_model` knows, for error messages."""
        raise NotImplementedError

    def knows_model(self, model: Any) -> bool:
        try:
            self.find_model(model)
        except (KeyError, TypeError, AttributeError):
            return False
        return True

    def check_model(self, c: Checker, key: str, dev: dict[str, Any], **how: Any) -> Any:
        """The model a device entry names (``how`` goes to :meth:`find_model`)."""
        if "model" not in dev:
            c.fail(f"{key}.model", f"missing (expected a model name such as {self.example_model!r})")
        try:
            return self.find_model(dev["model"], **how)
        except (KeyError, TypeError, AttributeError):
            c.fail(f"{key}.model", f"unknown model {dev['model']!r} (expected one of: {', '.join(self.model_names())})")

    @staticmethod
    def check_ids(c: Checker, key: str, dev: dict[str, Any], max_id: int) -> list[int]:
        """The IDs of a device entry: ``id = N`` or ``ids = [N, ...]``, each 0..``max_id``."""
        if ("id" in dev) == ("ids" in dev):
            c.fail(f"{key}.id", "expected exactly one of id = N or ids = [N, ...]")
        ids = [dev["id"]] if "id" in dev else dev["ids"]
        if not isinstance(ids, list) or not ids:
            c.fail(f"{key}.ids", f"expected a non-empty array of IDs, got {ids!r}")
        return [c.integer(i, f"{key}.id", 0, max_id) for i in ids]

    @staticmethod
    def check_init(c: Checker, key: str, dev: dict[str, Any], model: Any, *, integers: bool) -> dict[str, Any]:
        """The entry's ``init`` table: control-table items of ``model`` with values in their ranges
        (whole numbers only where ``integers``)."""
        init = c.table(dev.get("init", {}), f"{key}.init")
        kinds = int if integers else int | float
        for field_key, value in init.items():
            try:
                f = model.field_named(field_key)
            except KeyError:
                c.fail(f"{key}.init.{field_key}", f"{model.name} has no such control-table item")
            if not isinstance(value, kinds) or isinstance(value, bool) or not f.in_range(value):
                if integers:
                    expected = f"an integer {f.min}..{f.max}"
                else:
                    expected = f"one of {f.allowed}" if f.allowed else f"{f.min}..{f.max}"
                c.fail(f"{key}.init.{field_key}", f"expected {expected}, got {value!r}")
        return init

    @staticmethod
    def check_name(c: Checker, key: str, dev: dict[str, Any], ids: list[int]) -> str | None:
        """The entry's ``name``: a string, and only for a single ID."""
        name = dev.get("name")
        if name is not None and (not isinstance(name, str) or len(ids) > 1):
            c.fail(f"{key}.name", "expected a string, and only with a single id")
        return name


def initial_values(init: dict[str, int | float], baud_codes: dict[int, int], baud: int | None) -> dict[str, int | float]:
    """A servo's ``init`` values with the Baud Rate code of the endpoint's ``baud`` unless ``init`` sets one."""
    out = dict(init)
    code = {rate: code for code, rate in baud_codes.items()}.get(baud)
    if code is not None:
        out.setdefault("baud_rate", code)
    return out


def apply_faults(servo: Any, faults: dict[str, Any], t: float) -> None:
    """Turn a checked ``faults`` table into the servo's fault knobs (``vanished``, ``hardware_error`` too)."""
    for key in FAULT_SETTINGS:
        if key in faults:
            setattr(servo.faults, key, faults[key])
    if faults.get("vanished"):
        servo.vanish(t, math.inf)
    if faults.get("hardware_error"):
        servo.raise_hardware_error(faults["hardware_error"], t, sticky=True)


__all__ = ["SERVO_FAULT_RULES", "ServoBusAccess", "ServoBusFamily", "ServoBusKind", "ServoBusSpec", "apply_faults", "initial_values"]
