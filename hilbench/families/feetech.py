"""The Feetech family: STS/SCS serial-bus servos (the SO-100/SO-101 arms) on one bus per endpoint.

Profile schema (endpoint ``protocol = "feetech"``, a pty)::

    [endpoints.arm]
    protocol = "feetech"
    baud = 1_000_000               # a Feetech baud code's rate (1 M is the servos' default)

    [[devices]]
    model = "STS3215"              # or "SCS0009"; LeRobot's names ("sts3215") work too
    ids = [1, 2, 3]                # or id = 7 (and then an optional name)
    init = { homing_offset = -1000, min_position_limit = 700, return_delay_time = 0 }
    position = 2048                # the horn's actual position (counts), default mid-travel
    faults = { drop_rate = 0.01, delay = 0.0, vanished = false, seed = 1 }

Devices of one endpoint share one :class:`~hilbench.fakes.feetech.bus.FeetechBus`
(``endpoint.bus``); ``bench.device(3)`` is the servo answering at ID 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.family import DeviceFamily, DeviceSpec
from hilbench.protocols.feetech_models import STS_BAUD_CODES, find_model, model_names

FEETECH_BAUDS = tuple(sorted(set(STS_BAUD_CODES.values())))
FAULT_KEYS = ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay", "vanished", "seed")
DEVICE_KEYS = ("model", "id", "ids", "name", "endpoint", "firmware", "init", "faults", "position",
               "supply_voltage", "ambient_temperature")


@dataclass
class FeetechSpec(DeviceSpec):
    """One Feetech servo of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""

    id: int = 0
    firmware: int | None = None
    init: dict[str, int | float] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    position: float | None = None
    supply_voltage: float | None = None
    ambient_temperature: float | None = None


class FeetechFamily(DeviceFamily):
    """Feetech STS/SCS servos on one bus per endpoint."""

    name = "feetech"
    protocols = ("feetech",)
    endpoint_types = ("pty",)
    device_keys = DEVICE_KEYS
    models = tuple(model_names())
    endpoint_attrs = ("bus",)
    device_word = "servo"

    def knows_model(self, model: Any) -> bool:
        try:
            find_model(model)
        except (KeyError, TypeError, AttributeError):
            return False
        return True

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        baud = 1_000_000 if value is None else value
        if baud not in FEETECH_BAUDS or isinstance(baud, bool):
            c.fail(key, f"expected a Feetech baud rate ({', '.join(map(str, FEETECH_BAUDS))}), got {baud!r}")
        return baud

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[FeetechSpec]:
        if "model" not in dev:
            c.fail(f"{key}.model", "missing (expected a model name such as 'STS3215')")
        try:
            model = find_model(dev["model"])
        except (KeyError, TypeError, AttributeError):
            c.fail(f"{key}.model", f"unknown model {dev['model']!r} (expected one of: {', '.join(model_names())})")
        if ("id" in dev) == ("ids" in dev):
            c.fail(f"{key}.id", "expected exactly one of id = N or ids = [N, ...]")
        ids = [dev["id"]] if "id" in dev else dev["ids"]
        if not isinstance(ids, list) or not ids:
            c.fail(f"{key}.ids", f"expected a non-empty array of IDs, got {ids!r}")
        ids = [c.integer(i, f"{key}.id", 0, 253) for i in ids]
        init = c.table(dev.get("init", {}), f"{key}.init")
        for field_key, value in init.items():
            try:
                f = model.field_named(field_key)
            except KeyError:
                c.fail(f"{key}.init.{field_key}", f"{model.name} has no such control-table item")
            if not isinstance(value, int) or isinstance(value, bool) or not f.in_range(value):
                c.fail(f"{key}.init.{field_key}", f"expected an integer {f.min}..{f.max}, got {value!r}")
        faults = c.table(dev.get("faults", {}), f"{key}.faults")
        c.unknown(faults, f"{key}.faults", FAULT_KEYS)
        for fk in ("drop_rate", "corrupt_rate"):
            if fk in faults:
                c.number(faults[fk], f"{key}.faults.{fk}", 0.0, 1.0)
        for fk in ("drop_next", "corrupt_next", "seed"):
            if fk in faults:
                c.integer(faults[fk], f"{key}.faults.{fk}", 0, 2**31)
        if "delay" in faults:
            c.number(faults["delay"], f"{key}.faults.delay", 0.0, 10.0)
        if "vanished" in faults:
            c.boolean(faults["vanished"], f"{key}.faults.vanished")
        name = dev.get("name")
        if name is not None and (not isinstance(name, str) or len(ids) > 1):
            c.fail(f"{key}.name", "expected a string, and only with a single id")
        top = model.motion.position_max if model.motion else 4095
        return [
            FeetechSpec(
                name=name or f"{endpoint.name}.{i}",
                model=model.name,
                id=i,
                endpoint=endpoint.name,
                firmware=c.integer(dev["firmware"], f"{key}.firmware", 0, 255) if "firmware" in dev else None,
                init=dict(init),
                faults=dict(faults),
                position=c.number(dev["position"], f"{key}.position", 0, top) if "position" in dev else None,
                supply_voltage=c.number(dev["supply_voltage"], f"{key}.supply_voltage", 0, 30)
                if "supply_voltage" in dev else None,
                ambient_temperature=c.number(dev["ambient_temperature"], f"{key}.ambient_temperature", -40, 100)
                if "ambient_temperature" in dev else None,
            )
            for i in ids
        ]

    def check_profile(self, c: Checker, profile) -> None:
        taken: dict[tuple[str, int], str] = {}
        for spec in profile.devices_of(self.name):
            owner = taken.get((spec.endpoint, spec.id))
            if owner is not None:
                c.fail(f"{spec.where}.id", f"ID {spec.id} is already used on endpoint {spec.endpoint!r} by {owner}")
            taken[(spec.endpoint, spec.id)] = spec.where

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[FeetechSpec], t: float) -> None:
        from hilbench.fakes.feetech.bus import FeetechBus
        from hilbench.fakes.table_servo import TableServo

        spec = endpoint.spec
        defaults = bench.profile.defaults
        servos = []
        for dev in devices:
            model = find_model(dev.model)
            init = dict(dev.init)
            code = {baud: code for code, baud in model.baud_codes.items()}.get(spec.baud)
            if code is not None:
                init.setdefault("baud_rate", code)
            servo = TableServo(
                model, dev.id, name=dev.name, initial=init, position=dev.position, t=t,
                supply_voltage=dev.supply_voltage or defaults.get("supply_voltage", 12.0),
                ambient_temperature=dev.ambient_temperature or defaults.get("ambient_temperature", 30.0),
                firmware=dev.firmware, seed=dev.faults.get("seed", 0),
            )
            for key in ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay"):
                if key in dev.faults:
                    setattr(servo.faults, key, dev.faults[key])
            if dev.faults.get("vanished"):
                servo.vanish(t, math.inf)
            servos.append(servo)
            endpoint.add_device(dev.name, servo)
        bus = FeetechBus(servos, name=f"{spec.name}-devices")
        bus.attach(endpoint.medium)
        endpoint.attrs["bus"] = bus

    def device_at(self, endpoint, address: int):
        return endpoint.attrs["bus"].servo(address)

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: FeetechSpec, device, endpoint, profile) -> dict[str, Any]:
        return {
            "name": spec.name,
            "model": spec.model,
            "model_number": find_model(spec.model).number,
            "firmware": device.firmware if device else spec.firmware,
            "endpoint": spec.endpoint,
            "id": spec.id,
            "protocol": "feetech",
        }

    def summary(self, endpoint) -> str:
        timing = "paced" if endpoint.medium.paced else "unpaced"
        bus = endpoint.attrs.get("bus")
        return f"feetech, {endpoint.spec.baud} baud, {timing}, {len(bus.servos) if bus else 0} servos"


FAMILY = FeetechFamily()

__all__ = ["FAMILY", "FEETECH_BAUDS", "FeetechFamily", "FeetechSpec"]
