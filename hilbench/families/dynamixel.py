"""The Dynamixel family: emulated servos and boards on a multi-drop RS-485 bus (Protocol 2.0).

Profile schema (endpoint ``protocol = "dynamixel"``, a pty)::

    [defaults]
    supply_voltage = 14.0          # V, drives Present Input Voltage
    ambient_temperature = 30.0     # C

    [endpoints.dxl]
    protocol = "dynamixel"
    baud = 2_000_000               # a rate the SDK can open
    chain_policy = "continue"      # Sync/Bulk read after a silent device: "continue" or "stall"
    fast_missing = "truncate"      # Fast read lacking a device: "truncate", "drop" or "silent"
    strict_stuffing = false

    [[devices]]
    model = "MX-106"               # see hilbench/protocols/dynamixel_models.py
    ids = [1, 2, 3]                # or id = 7 (and then an optional name)
    firmware = 41
    init = { return_delay_time = 0 }
    faults = { drop_rate = 0.01, delay = 0.0, vanished = false, hardware_error = 0 }
    fast_read = false

Devices of one endpoint share one :class:`~hilbench.fakes.dynamixel.bus.DynamixelBus`
(``endpoint.bus``); ``bench.device(3)`` is the servo answering at ID 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.family import DeviceFamily, DeviceSpec
from hilbench.fakes.dynamixel.bus import CHAIN_POLICIES, FAST_MISSING_POLICIES
from hilbench.protocols.dynamixel_models import BAUD_CODES, SDK_BAUDS, find_model, model_names
from hilbench.rules import FAULT_COUNT, PROBABILITY, Rule

#: Rates the official SDK can open (spec §7.1) that are also Dynamixel baud codes.
DYNAMIXEL_BAUDS = tuple(sorted(set(BAUD_CODES.values()) & set(SDK_BAUDS)))
#: An emulated bus's line rate (``endpoints.NAME.baud``): the servos need a baud code, the host the SDK.
BUS_BAUD = Rule(int, choices=DYNAMIXEL_BAUDS, what="a Dynamixel baud rate the SDK can open")
FAULT_KEYS = ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay", "vanished", "hardware_error",
              "seed")
DEVICE_KEYS = ("model", "id", "ids", "name", "endpoint", "firmware", "init", "faults", "position",
               "supply_voltage", "ambient_temperature", "fast_read")


@dataclass
class ServoSpec(DeviceSpec):
    """One Dynamixel device of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""

    id: int = 0
    firmware: int | None = None
    init: dict[str, int | float] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    position: float | None = None
    supply_voltage: float | None = None
    ambient_temperature: float | None = None
    fast_read: bool | None = None


class DynamixelFamily(DeviceFamily):
    """Dynamixel Protocol 2.0 servos and boards on one bus per endpoint."""

    name = "dynamixel"
    protocols = ("dynamixel",)
    endpoint_types = ("pty",)
    endpoint_keys = ("chain_policy", "fast_missing", "strict_stuffing")
    device_keys = DEVICE_KEYS
    models = tuple(model_names())
    default_keys = {"supply_voltage": (0, 50, 12.0), "ambient_temperature": (-40, 100, 30.0)}
    endpoint_attrs = ("bus",)
    profile_attrs = ("servos",)
    device_word = "servo"

    # ------------------------------------------------------------------ profile

    def knows_model(self, model: Any) -> bool:
        try:
            find_model(model)
        except (KeyError, TypeError, AttributeError):
            return False
        return True

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        return c.rule(57_600 if value is None else value, key, BUS_BAUD)

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        return {
            "chain_policy": c.choice(raw.get("chain_policy", "continue"), f"{key}.chain_policy", CHAIN_POLICIES),
            "fast_missing": c.choice(raw.get("fast_missing", "truncate"), f"{key}.fast_missing",
                                     FAST_MISSING_POLICIES),
            "strict_stuffing": c.boolean(raw.get("strict_stuffing", False), f"{key}.strict_stuffing"),
        }

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[ServoSpec]:
        if "model" not in dev:
            c.fail(f"{key}.model", "missing (expected a model name such as 'XM430-W350')")
        try:
            model = find_model(dev["model"])
        except (KeyError, TypeError, AttributeError):
            c.fail(f"{key}.model", f"unknown model {dev['model']!r} (expected one of: {', '.join(model_names())})")
        if ("id" in dev) == ("ids" in dev):
            c.fail(f"{key}.id", "expected exactly one of id = N or ids = [N, ...]")
        ids = [dev["id"]] if "id" in dev else dev["ids"]
        if not isinstance(ids, list) or not ids:
            c.fail(f"{key}.ids", f"expected a non-empty array of IDs, got {ids!r}")
        ids = [c.integer(i, f"{key}.id", 0, 252) for i in ids]
        init = c.table(dev.get("init", {}), f"{key}.init")
        for field_key, value in init.items():
            try:
                f = model.field_named(field_key)
            except KeyError:
                c.fail(f"{key}.init.{field_key}", f"{model.name} has no such control-table item")
            if not isinstance(value, int | float) or isinstance(value, bool) or not f.in_range(value):
                rng = f"one of {f.allowed}" if f.allowed else f"{f.min}..{f.max}"
                c.fail(f"{key}.init.{field_key}", f"expected {rng}, got {value!r}")
        faults = c.table(dev.get("faults", {}), f"{key}.faults")
        c.unknown(faults, f"{key}.faults", FAULT_KEYS)
        for fk in ("drop_rate", "corrupt_rate"):
            if fk in faults:
                c.rule(faults[fk], f"{key}.faults.{fk}", PROBABILITY)
        for fk in ("drop_next", "corrupt_next", "seed"):
            if fk in faults:
                c.rule(faults[fk], f"{key}.faults.{fk}", FAULT_COUNT)
        if "delay" in faults:
            c.number(faults["delay"], f"{key}.faults.delay", 0.0, 10.0)
        if "vanished" in faults:
            c.boolean(faults["vanished"], f"{key}.faults.vanished")
        if "hardware_error" in faults:
            c.integer(faults["hardware_error"], f"{key}.faults.hardware_error", 0, 0x3D)
        name = dev.get("name")
        if name is not None and (not isinstance(name, str) or len(ids) > 1):
            c.fail(f"{key}.name", "expected a string, and only with a single id")
        firmware = c.integer(dev["firmware"], f"{key}.firmware", 0, 255) if "firmware" in dev else None
        position = c.number(dev["position"], f"{key}.position", -1_048_575, 1_048_575) if "position" in dev else None
        supply = c.number(dev["supply_voltage"], f"{key}.supply_voltage", 0, 50) if "supply_voltage" in dev else None
        ambient = (c.number(dev["ambient_temperature"], f"{key}.ambient_temperature", -40, 100)
                   if "ambient_temperature" in dev else None)
        fast = c.boolean(dev["fast_read"], f"{key}.fast_read") if "fast_read" in dev else None
        return [
            ServoSpec(
                name=name or f"{endpoint.name}.{i}",
                model=model.name,
                id=i,
                endpoint=endpoint.name,
                firmware=firmware,
                init=dict(init),
                faults=dict(faults),
                position=position,
                supply_voltage=supply,
                ambient_temperature=ambient,
                fast_read=fast,
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

    def build(self, bench, endpoint, devices: list[ServoSpec], t: float) -> None:
        from hilbench.fakes.dynamixel.bus import DynamixelBus

        spec = endpoint.spec
        servos = []
        fast_read = {}
        for dev in devices:
            servo = self._make_servo(dev, spec, bench.profile, t)
            servos.append(servo)
            endpoint.add_device(dev.name, servo)
            if dev.fast_read is not None:
                fast_read[dev.id] = dev.fast_read
        bus = DynamixelBus(
            servos,
            name=f"{spec.name}-devices",
            chain_policy=spec.options["chain_policy"],
            fast_missing=spec.options["fast_missing"],
            fast_read=fast_read,
            strict_stuffing=spec.options["strict_stuffing"],
        )
        bus.attach(endpoint.medium)
        endpoint.attrs["bus"] = bus

    @staticmethod
    def _make_servo(dev: ServoSpec, spec, profile, t: float):
        from hilbench.fakes.dynamixel.servo import Servo
        from hilbench.protocols.dynamixel_models import BAUD_TO_CODE

        model = find_model(dev.model)
        init = dict(dev.init)
        if model.kind == "servo":
            init.setdefault("baud_rate", BAUD_TO_CODE[spec.baud])
        servo = Servo(
            model,
            dev.id,
            name=dev.name,
            initial=init,
            position=dev.position,
            supply_voltage=dev.supply_voltage or profile.defaults["supply_voltage"],
            ambient_temperature=dev.ambient_temperature or profile.defaults["ambient_temperature"],
            firmware=dev.firmware,
            board_baud=spec.baud,
            t=t,
            seed=dev.faults.get("seed", 0),
        )
        f = dev.faults
        for key in ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay"):
            if key in f:
                setattr(servo.faults, key, f[key])
        if f.get("vanished"):
            servo.vanish(t, math.inf)
        if f.get("hardware_error"):
            servo.raise_hardware_error(f["hardware_error"], t, sticky=True)
        return servo

    def device_at(self, endpoint, address: int):
        return endpoint.attrs["bus"].servo(address)

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: ServoSpec, device, endpoint, profile) -> dict[str, Any]:
        return {
            "name": spec.name,
            "model": spec.model,
            "model_number": device.model.number if device else find_model(spec.model).number,
            "firmware": device.firmware if device else spec.firmware,
            "endpoint": spec.endpoint,
            "id": spec.id,
            "protocol": profile.endpoints[spec.endpoint].protocol,
        }

    def summary(self, endpoint) -> str:
        timing = "paced" if endpoint.medium.paced else "unpaced"
        bus = endpoint.attrs.get("bus")
        n = len(bus.servos) if bus else 0
        return f"{endpoint.spec.protocol}, {endpoint.spec.baud} baud, {timing}, {n} devices"


FAMILY = DynamixelFamily()

__all__ = ["DYNAMIXEL_BAUDS", "FAMILY", "DynamixelFamily", "ServoSpec"]
