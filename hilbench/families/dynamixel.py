"""The Dynamixel family and bus: emulated servos and boards on a multi-drop RS-485 bus (Protocol 2.0 or 1.0).

:data:`~hilbench.families.dynamixel.BUS_KIND` is the bus (endpoint ``protocol = "dynamixel"``): its keys, the
:class:`~hilbench.fakes.dynamixel.bus.DynamixelBus` (or Protocol 1.0 bus) every
device on it joins, addressed by ID. :data:`~hilbench.families.dynamixel.FAMILY` is the Dynamixel devices
(chosen by model); a lab's own board family may join the same bus.

Profile schema (endpoint ``protocol = "dynamixel"``, a pty)::

    [defaults]
    supply_voltage = 14.0          # V, drives Present Input Voltage
    ambient_temperature = 30.0     # C

    [endpoints.dxl]
    protocol = "dynamixel"
    protocol_version = 2           # 2 (default) or 1: one bus carries one protocol
    baud = 2_000_000               # a rate the SDK can open
    chain_policy = "continue"      # Sync/Bulk read after a silent device: "continue" or "stall"
    fast_missing = "truncate"      # Fast read lacking a device: "truncate", "drop" or "silent"
    strict_stuffing = false
    usb2ax = true                  # Protocol 1.0 only: a USB2AX adapter (ID 0xFD) answers SYNC_READ 0x84

A Protocol 1.0 bus hosts the AX-12A/AX-18A and MX-28/64/106 with 1.0 firmware
(``model = "MX-28"`` means the 1.0 table there); a Protocol 2.0 bus the X
series, the MX(2.0), the XL-320 and the custom boards. Its traffic is
``dynamixel1`` to taps and monitors.

    [[devices]]
    model = "MX-106"               # see hilbench/protocols/dynamixel_models.py
    ids = [1, 2, 3]                # or id = 7 (and then an optional name)
    firmware = 41
    init = { return_delay_time = 0 }
    faults = { drop_rate = 0.01, delay = 0.0, vanished = false, hardware_error = 0 }
    fast_read = false

A board hilbench has no model of is ``model = "control-table"`` with its
registers (:mod:`hilbench.families.dynamixel_custom_board`).

Devices of one endpoint share one :class:`~hilbench.fakes.dynamixel.bus.DynamixelBus`
(``endpoint.bus``); ``bench.device(3)`` is the device answering at ID 3 (of any family),
``bench.family("dynamixel").servo(3)`` the Dynamixel device there and ``.bus()`` the bus
(:class:`~hilbench.families.servo_bus.ServoBusAccess`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hilbench.bench.bus import LabgridDriver
from hilbench.bench.checks import Checker
from hilbench.bench.knobs import check_fault_table
from hilbench.fakes.dynamixel.bus import CHAIN_POLICIES, FAST_MISSING_POLICIES
from hilbench.families.dynamixel_custom_board import BOARD_KEYS, CONTROL_TABLE, check_board
from hilbench.families.servo_bus import (
    SERVO_FAULT_RULES,
    ServoBusAccess,
    ServoBusFamily,
    ServoBusKind,
    ServoBusSpec,
    apply_faults,
    initial_values,
)
from hilbench.protocols.dynamixel_classic_models import P1_NOMINAL_BAUDS
from hilbench.protocols.dynamixel_models import BAUD_CODES, find_model, model_names
from hilbench.rules import Rule

#: Protocol 2.0 baud codes. The official SDK's list (spec §7.1) lacks 4.5 Mbaud, which pyserial opens on
#: Linux all the same (BOTHER): docs/families/dynamixel.md shows the one-method PortHandler subclass that lifts the list.
DYNAMIXEL_BAUDS = tuple(sorted(set(BAUD_CODES.values())))
#: Rates of the Protocol 1.0 baud codes hosts open (1 Mbaud is code 1, 57 600 code 34, ...).
PROTOCOL1_BAUDS = tuple(sorted(set(P1_NOMINAL_BAUDS.values())))
#: What a Protocol 1.0 bus's traffic is called to taps and monitors.
PROTOCOL1_TRAFFIC = "dynamixel1"
#: An emulated bus's line rate (``endpoints.NAME.baud``): a baud code of either protocol (the endpoint
#: check then holds it to its protocol's list).
BUS_BAUD = Rule(int, choices=tuple(sorted(set(DYNAMIXEL_BAUDS + PROTOCOL1_BAUDS))), what="a Dynamixel baud rate")
#: A Dynamixel servo's fault knobs: every servo's, and the Hardware Error Status bits to raise.
FAULT_RULES = {**SERVO_FAULT_RULES, "hardware_error": Rule(int, 0, 0x3D)}
DEVICE_KEYS = ("model", "id", "ids", "name", "endpoint", "firmware", "init", "faults", "position",
               "supply_voltage", "ambient_temperature", "fast_read", *BOARD_KEYS)


@dataclass
class ServoSpec(ServoBusSpec):
    """One Dynamixel device of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""

    fast_read: bool | None = None
    #: The table of a ``control-table`` board (None: the model's own, by name).
    table: Any = None


def speaks_protocol1(model) -> bool:
    """Whether ``model`` can sit on a Protocol 1.0 bus: 1.0 firmware, or 2.0 firmware whose Protocol Type
    (address 13) may be set to 1, as the X series and the MX 2.0 firmware allow (ROBOTIS's own Protocol
    1.0 examples drive X-series servos at their X-series addresses)."""
    if model.protocol == 1:
        return True
    try:
        f = model.field_named("protocol_type")
    except KeyError:
        return False
    return f.min is not None and f.min <= 1


class DynamixelBusKind(ServoBusKind):
    """A Dynamixel RS-485 bus (Protocol 2.0, or 1.0 with ``protocol_version = 1``): its keys and the bus object
    its devices join."""

    protocol = "dynamixel"
    endpoint_keys = ("protocol_version", "chain_policy", "fast_missing", "strict_stuffing", "usb2ax")

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        return c.rule(57_600 if value is None else value, key, BUS_BAUD)

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        version = raw.get("protocol_version", 2)
        if version not in (1, 2) or isinstance(version, bool):
            c.fail(f"{key}.protocol_version", f"expected 1 or 2, got {version!r}")
        baud = raw.get("baud", 57_600)
        bauds = PROTOCOL1_BAUDS if version == 1 else DYNAMIXEL_BAUDS
        if baud not in bauds:
            c.fail(f"{key}.baud", f"expected a Protocol {version}.0 baud rate ({', '.join(map(str, bauds))}), "
                                  f"got {baud!r}")
        if "usb2ax" in raw and version != 1:
            c.fail(f"{key}.usb2ax", "only on protocol_version = 1 buses (the USB2AX speaks Protocol 1.0)")
        return {
            "protocol_version": version,
            "usb2ax": c.boolean(raw.get("usb2ax", True), f"{key}.usb2ax") if version == 1 else False,
            "chain_policy": c.choice(raw.get("chain_policy", "continue"), f"{key}.chain_policy", CHAIN_POLICIES),
            "fast_missing": c.choice(raw.get("fast_missing", "truncate"), f"{key}.fast_missing",
                                     FAST_MISSING_POLICIES),
            "strict_stuffing": c.boolean(raw.get("strict_stuffing", False), f"{key}.strict_stuffing"),
        }

    def open(self, bench, endpoint):
        from hilbench.fakes.dynamixel.bus import DynamixelBus
        from hilbench.fakes.protocol1_bus import Protocol1Bus

        spec = endpoint.spec
        if spec.options.get("protocol_version", 2) == 1:
            bus = Protocol1Bus([], name=f"{spec.name}-devices", usb2ax=spec.options["usb2ax"])
            endpoint.medium.protocol = PROTOCOL1_TRAFFIC
        else:
            bus = DynamixelBus([], name=f"{spec.name}-devices", chain_policy=spec.options["chain_policy"],
                               fast_missing=spec.options["fast_missing"],
                               strict_stuffing=spec.options["strict_stuffing"])
        bus.attach(endpoint.medium)
        return bus

    def join(self, endpoint, device, spec) -> None:
        endpoint.bus.add(device)
        fast_read = getattr(spec, "fast_read", None)
        if fast_read is not None and hasattr(endpoint.bus, "fast_read"):
            endpoint.bus.fast_read[device.id] = fast_read

    def labgrid_driver(self, endpoint: dict[str, Any]) -> LabgridDriver | None:
        """:class:`~hilbench.labgrid.dynamixel.DynamixelDriver` (Protocol 2.0) on a Protocol 2.0 bus."""
        if endpoint.get("protocol_version", 2) != 2:
            return None
        return LabgridDriver("hilbench.labgrid.dynamixel", "DynamixelDriver", "-dxl")

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        opts = endpoint.spec.options
        out: dict[str, Any] = {"protocol_version": opts.get("protocol_version", 2)}
        if out["protocol_version"] == 1:
            out["usb2ax"] = opts["usb2ax"]
        return out

    def summary(self, endpoint) -> str:
        timing = "paced" if endpoint.medium.paced else "unpaced"
        n = len(endpoint.bus.servos) if endpoint.bus is not None else 0
        opts = endpoint.spec.options
        version = f"Protocol {opts.get('protocol_version', 2)}.0"
        if opts.get("usb2ax"):
            version += " with a USB2AX"
        return f"{endpoint.spec.protocol} ({version}), {endpoint.spec.baud} baud, {timing}, {n} devices"


class DynamixelServos(ServoBusAccess):
    """The Dynamixel servos and boards of a running bench: ``bench.family("dynamixel")``."""

    family_name = "dynamixel"


class DynamixelFamily(ServoBusFamily):
    """Dynamixel Protocol 2.0/1.0 servos and boards (the Wolfgang boards) on Dynamixel buses."""

    name = "dynamixel"
    access = DynamixelServos
    joins = ("dynamixel",)
    device_keys = DEVICE_KEYS
    models = (*model_names(), CONTROL_TABLE)
    default_keys = {"supply_voltage": (0, 50, 12.0), "ambient_temperature": (-40, 100, 30.0)}
    example_model = "XM430-W350"

    # ------------------------------------------------------------------ profile

    def find_model(self, name: Any, **how: Any) -> Any:
        return find_model(name, **how)

    def model_names(self) -> list[str]:
        return list(model_names())

    def knows_model(self, model: Any) -> bool:
        return model == CONTROL_TABLE or super().knows_model(model)

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[ServoSpec]:
        version = endpoint.options.get("protocol_version", 2)
        board = dev.get("model") == CONTROL_TABLE
        model = check_board(c, key, dev, version) if board else self.check_model(c, key, dev, protocol=version)
        for extra in BOARD_KEYS:
            if extra in dev and not board:
                c.fail(f"{key}.{extra}", f'only for model = "{CONTROL_TABLE}" boards')
        if model.protocol != version and not (version == 1 and speaks_protocol1(model)):
            c.fail(f"{key}.model", f"{model.name} speaks Protocol {model.protocol}.0 but endpoint "
                                   f"{endpoint.name!r} is a Protocol {version}.0 bus (protocol_version)")
        ids = self.check_ids(c, key, dev, 252)
        init = self.check_init(c, key, dev, model, integers=False)
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), FAULT_RULES)
        name = self.check_name(c, key, dev, ids)
        firmware = c.integer(dev["firmware"], f"{key}.firmware", 0, 255) if "firmware" in dev and not board else None
        position = c.number(dev["position"], f"{key}.position", -1_048_575, 1_048_575) if "position" in dev else None
        supply = c.number(dev["supply_voltage"], f"{key}.supply_voltage", 0, 50) if "supply_voltage" in dev else None
        ambient = (c.number(dev["ambient_temperature"], f"{key}.ambient_temperature", -40, 100)
                   if "ambient_temperature" in dev else None)
        fast = c.boolean(dev["fast_read"], f"{key}.fast_read") if "fast_read" in dev else None
        return [
            ServoSpec(
                name=name or f"{endpoint.name}.{i}",
                model=CONTROL_TABLE if board else model.name,
                id=i,
                address=i,
                endpoint=endpoint.name,
                firmware=firmware,
                init=dict(init),
                faults=dict(faults),
                position=position,
                supply_voltage=supply,
                ambient_temperature=ambient,
                fast_read=fast,
                table=model if board else None,
            )
            for i in ids
        ]

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[ServoSpec], t: float) -> None:
        for dev in devices:
            endpoint.add_device(dev.name, self._make_servo(dev, endpoint.spec, bench.profile, t))

    @staticmethod
    def _make_servo(dev: ServoSpec, spec, profile, t: float):
        from hilbench.fakes.dynamixel.servo import Servo
        from hilbench.fakes.table_servo import TableServo
        from hilbench.protocols.dynamixel_classic_models import P1_NOMINAL_BAUDS

        model = dev.table or find_model(dev.model)
        init = dict(dev.init)
        if model.kind == "servo":
            init = initial_values(init, P1_NOMINAL_BAUDS if model.protocol == 1 else model.baud_codes, spec.baud)
        if model.protocol == 2 and spec.options.get("protocol_version", 2) == 1:
            init["protocol_type"] = 1  # an X-series (or MX 2.0 firmware) servo switched to Protocol 1.0
        cls = TableServo if model.motion is not None else Servo  # the classic tables (AX, MX 1.0, XL-320)
        servo = cls(
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
        apply_faults(servo, dev.faults, t)
        return servo

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: ServoSpec, device, endpoint, profile) -> dict[str, Any]:
        ep = profile.endpoints[spec.endpoint]
        return {
            "name": spec.name,
            "model": spec.model,
            "model_number": device.model.number if device else (spec.table or find_model(spec.model)).number,
            "firmware": device.firmware if device else spec.firmware,
            "endpoint": spec.endpoint,
            "id": spec.id,
            "protocol": ep.protocol,
            "protocol_version": ep.options.get("protocol_version", 2),
        }


#: The bus kind this module registers (entry point ``hilbench.bus_kinds``).
BUS_KIND = DynamixelBusKind()
#: The device family this module registers (entry point ``hilbench.families``).
FAMILY = DynamixelFamily()

__all__ = ["BUS_KIND", "DYNAMIXEL_BAUDS", "FAMILY", "DynamixelBusKind", "DynamixelFamily", "DynamixelServos",
           "ServoSpec"]
