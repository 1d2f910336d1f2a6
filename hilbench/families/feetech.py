"""The Feetech family and bus: STS/SCS serial-bus servos (the SO-100/SO-101 arms) on one bus per endpoint.

:data:`~hilbench.families.feetech.BUS_KIND` is the bus (endpoint ``protocol = "feetech"``), :data:`~hilbench.families.feetech.FAMILY` the servos on it.

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
(``endpoint.bus``); ``bench.device(3)`` is the servo answering at ID 3,
``bench.family("feetech").servo(3)`` too and ``.bus()`` the bus.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.knobs import check_fault_table
from hilbench.families.servo_bus import (
    SERVO_FAULT_RULES,
    ServoBusAccess,
    ServoBusFamily,
    ServoBusKind,
    ServoBusSpec,
    apply_faults,
    initial_values,
)
from hilbench.protocols.feetech_models import STS_BAUD_CODES, find_model, model_names

FEETECH_BAUDS = tuple(sorted(set(STS_BAUD_CODES.values())))
DEVICE_KEYS = ("model", "id", "ids", "name", "endpoint", "firmware", "init", "faults", "position",
               "supply_voltage", "ambient_temperature")


@dataclass
class FeetechSpec(ServoBusSpec):
    """One Feetech servo of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""


class FeetechBusKind(ServoBusKind):
    """A Feetech bus: Protocol 1.0 framing with Feetech's instructions and baud codes."""

    protocol = "feetech"

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        baud = 1_000_000 if value is None else value
        if baud not in FEETECH_BAUDS or isinstance(baud, bool):
            c.fail(key, f"expected a Feetech baud rate ({', '.join(map(str, FEETECH_BAUDS))}), got {baud!r}")
        return baud

    def open(self, bench, endpoint):
        from hilbench.fakes.feetech.bus import FeetechBus

        bus = FeetechBus([], name=f"{endpoint.name}-devices")
        bus.attach(endpoint.medium)
        return bus

    def summary(self, endpoint) -> str:
        timing = "paced" if endpoint.medium.paced else "unpaced"
        n = len(endpoint.bus.servos) if endpoint.bus is not None else 0
        return f"feetech, {endpoint.spec.baud} baud, {timing}, {n} servos"


class FeetechServos(ServoBusAccess):
    """The Feetech servos of a running bench: ``bench.family("feetech")``."""

    family_name = "feetech"


class FeetechFamily(ServoBusFamily):
    """Feetech STS/SCS servos on Feetech buses."""

    name = "feetech"
    access = FeetechServos
    joins = ("feetech",)
    device_keys = DEVICE_KEYS
    models = tuple(model_names())
    example_model = "STS3215"

    def find_model(self, name: Any, **how: Any) -> Any:
        return find_model(name)

    def model_names(self) -> list[str]:
        return list(model_names())

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[FeetechSpec]:
        model = self.check_model(c, key, dev)
        ids = self.check_ids(c, key, dev, 253)
        init = self.check_init(c, key, dev, model, integers=True)
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), SERVO_FAULT_RULES)
        name = self.check_name(c, key, dev, ids)
        top = model.motion.position_max if model.motion else 4095
        return [
            FeetechSpec(
                name=name or f"{endpoint.name}.{i}",
                model=model.name,
                id=i,
                address=i,
                endpoint=endpoint.name,
                firmware=c.integer(dev["firmware"], f"{key}.firmware", 0, 255) if "firmware" in dev else None,
                init=dict(init),
                faults=faults,
                position=c.number(dev["position"], f"{key}.position", 0, top) if "position" in dev else None,
                supply_voltage=c.number(dev["supply_voltage"], f"{key}.supply_voltage", 0, 30)
                if "supply_voltage" in dev else None,
                ambient_temperature=c.number(dev["ambient_temperature"], f"{key}.ambient_temperature", -40, 100)
                if "ambient_temperature" in dev else None,
            )
            for i in ids
        ]

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[FeetechSpec], t: float) -> None:
        from hilbench.fakes.table_servo import TableServo

        spec = endpoint.spec
        defaults = bench.profile.defaults
        for dev in devices:
            model = find_model(dev.model)
            init = initial_values(dev.init, model.baud_codes, spec.baud)
            servo = TableServo(
                model, dev.id, name=dev.name, initial=init, position=dev.position, t=t,
                supply_voltage=dev.supply_voltage or defaults.get("supply_voltage", 12.0),
                ambient_temperature=dev.ambient_temperature or defaults.get("ambient_temperature", 30.0),
                firmware=dev.firmware, seed=dev.faults.get("seed", 0),
            )
            apply_faults(servo, dev.faults, t)
            endpoint.add_device(dev.name, servo)

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


#: The bus kind this module registers (entry point ``hilbench.bus_kinds``).
BUS_KIND = FeetechBusKind()
#: The device family this module registers (entry point ``hilbench.families``).
FAMILY = FeetechFamily()

__all__ = ["BUS_KIND", "FAMILY", "FEETECH_BAUDS", "FeetechBusKind", "FeetechFamily", "FeetechServos", "FeetechSpec"]
