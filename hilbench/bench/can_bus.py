"""The CAN bus kind (endpoint ``protocol = "can"``): an emulated CAN bus, whichever nodes sit on it.

A CAN endpoint belongs to no device family: any family whose devices join
``can`` puts its nodes on it (the CANopen rover board, a lab's I/O node),
each at its own node id. Profile schema (endpoint ``type = "can"``)::

    [endpoints.can]
    type = "can"
    protocol = "can"
    bitrate = 500_000                # 10 kbit/s .. 1 Mbit/s (``baud`` is accepted too)
    paced = true                     # arbitration and bit-time pacing (false: frames delivered at once)
    socketcand = { port = 0, channel = "can0" }   # the host port's doors, see hilbench.transports.can_port
    slcan = true
    bus_faults = { error_rate = 0.0, error_next = 0, auto_recover = true }
    # seed = 0                       # the bus's fault draws

Devices on it are addressed by ``node_id`` (:attr:`~hilbench.bench.family.DeviceSpec.address`): a node id
is taken once per bus, across families. The bus answers one control command itself, addressed by endpoint
(``{"cmd": "bus", "endpoint": "can"}``, ``hilbench can bus``): its figures, error knobs and bus-off.
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlRequestError
from hilbench.bench.knobs import check_fault_table, check_knobs
from hilbench.transports.can_medium import FAULT_RULES


class CanBus(BusKind):
    """An emulated CAN bus behind a CAN host port (socketcand, SLCAN, virtual, SocketCAN doors)."""

    protocol = "can"
    medium = "can"
    endpoint_types = ("can",)
    rate_key = "bitrate"
    endpoint_keys = ("bus_faults", "seed")
    address_key = "node_id"
    address_word = "node id"
    control_commands = {"bus": "the bus's figures; with knobs: error_rate, error_next, auto_recover; bus_off=SENDER"}

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        return c.integer(500_000 if value is None else value, key, 10_000, 1_000_000)

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        faults = check_fault_table(c, f"{key}.bus_faults", raw.get("bus_faults", {}), FAULT_RULES)
        seed = raw.get("seed")
        if seed is not None:
            seed = c.integer(seed, f"{key}.seed", 0, 2**31)
        return {"bus_faults": faults, "seed": seed}

    def open(self, bench, endpoint) -> None:
        medium = endpoint.medium
        options = endpoint.spec.options
        if options.get("seed") is not None:
            medium.rng.seed(options["seed"])
        if options.get("bus_faults"):
            medium.set_faults(**options["bus_faults"])
        return None  # the nodes share the medium itself

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        medium = endpoint.medium
        return {"bitrate": medium.bitrate, "baud": medium.bitrate,
                "nodes": sorted(s.address for s in endpoint.specs.values() if s.address is not None)}

    def summary(self, endpoint) -> str:
        port = endpoint.port
        nodes = ", ".join(f"node {s.address} {name!r}" for name, s in
                          sorted(endpoint.specs.items(), key=lambda item: item[1].address or 0))
        doors = []
        if getattr(port, "slcan", None) is not None:
            doors.append(f"SLCAN {port.slcan.path}")
        if getattr(port, "virtual", None) is not None:
            doors.append(f"virtual {port.virtual.channel!r}")
        if getattr(port, "socketcan", None) is not None:
            doors.append(f"SocketCAN {port.socketcan.channel}")
        elif getattr(port, "socketcan_error", None):
            doors.append("SocketCAN skipped: " + port.socketcan_error)
        paced = "paced" if endpoint.medium.paced else "unpaced"
        extra = f"; {'; '.join(doors)}" if doors else ""
        return f"CAN {endpoint.medium.bitrate} bit/s {paced}, {nodes or 'no nodes'}{extra}"

    def control(self, bench, endpoint, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd != "bus":
            raise ControlRequestError(f"unknown command {cmd!r}")
        medium = endpoint.medium
        knobs = req.get("knobs", {}) or {}
        if not isinstance(knobs, dict):
            raise ControlRequestError("knobs: expected an object")
        knobs = dict(knobs)
        bus_off = knobs.pop("bus_off", None)
        if knobs:
            try:
                medium.set_faults(**check_knobs(knobs, FAULT_RULES, "bus fault"))
            except ValueError as exc:
                raise ControlRequestError(str(exc)) from None
        if bus_off is not None:
            medium.force_bus_off(str(bus_off))
        # The doors' counters beside the bus's (the socketcand server's clients, refusals, drops and queue
        # bounds), so `hilbench can bus` shows what a hostile or slow client cost without a second command.
        doors = endpoint.port.status() if hasattr(endpoint.port, "status") else {}
        return {"bus": {**medium.status(), **({"doors": doors} if doors else {})}}


BUS_KIND = CanBus()

__all__ = ["BUS_KIND", "CanBus"]
