"""The CANopen board family: the STM32 rover board as a CANopen node on an emulated CAN bus.

The bus is the generic CAN bus kind (:mod:`hilbench.bench.can_bus`: endpoint
``type = "can"``, ``protocol = "can"``, ``bitrate``, ``bus_faults``, ``seed``);
other families' nodes may share it, each at its own node id. Device entries::

    [[devices]]
    model = "stm32f767-rover-canopen"
    name = "rover"
    node_id = 2
    heartbeat_ms = 1000              # object 0x1017
    setpoint_timeout_ms = 150        # object 0x1400 sub 5
    autostart = false                # true: OPERATIONAL right after boot-up
    tpdo_periods_ms = { encoders = 20, odometry = 50, velocity = 50, status = 100 }
    identity = { vendor_id = 0x0048424E, product_code = 0x00F76701, revision = 0x00010000, serial = 1 }
    faults = { heartbeat_stop = false, silent = false, sdo_abort = 0, motor_fault = false, battery_v = 24.6,
               stuck_odometry = false, dlc_mismatch = false }
    body = "rover"                   # the world body the node drives (RPDO1 setpoints move it)
    odometry = { slip = 0.0, encoder_noise = 0.0 }   # share of wheel motion lost; counts of noise per cycle

A node a capture recorded is ``model = "recorded-node"``
(:mod:`hilbench.families.canopen_recorded`). Several nodes may share an
endpoint (one bus), each with its own node id.
``bench.family("canopen").node(2)`` finds one (:class:`CanopenNodes`; ``bench.device(2)`` finds any
family's node by node id), ``bench.endpoint("can").port.open_bus()`` opens a python-can bus on the
endpoint in this process.
Control commands (``hilbench can status|nmt|reset|fault|emcy``): see
:attr:`CanopenBoardFamily.control_commands`; ``hilbench can bus`` is the bus's own.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError, ControlRequestError
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.bench.knobs import KnobRules, check_fault_table, check_knobs, requested_knobs
from hilbench.bench.world import check_odometry, refuse_second_driver
from hilbench.families.canopen_recorded import FAULT_RULES as RECORDED_FAULT_RULES
from hilbench.families.canopen_recorded import (
    RECORDED,
    RECORDED_KEYS,
    RecordedSpec,
    build_recorded,
    check_recorded,
)
from hilbench.rules import SWITCH, Rule

if TYPE_CHECKING:
    from hilbench.bench.profile import Profile
    from hilbench.fakes.canopen.recorded import RecordedNode
    from hilbench.fakes.canopen.rover import RoverNode

MODELS = ("stm32f767-rover-canopen", "mecarover-canopen", RECORDED)
DEVICE_KEYS = ("model", "name", "endpoint", "node_id", "heartbeat_ms", "setpoint_timeout_ms", "autostart",
               "tpdo_periods_ms", "identity", "faults", "odometry", *RECORDED_KEYS)
IDENTITY_KEYS = {"vendor_id": "vendor_id", "product_code": "product_code", "revision": "revision",
                 "serial": "serial"}
#: The board's fault knobs (the node's and the rover's, as the fake's ROVER_FAULT_KEYS) and their rules.
FAULT_RULES: KnobRules = {
    "heartbeat_stop": SWITCH, "silent": SWITCH, "sdo_abort": Rule(int, 0, 0xFFFFFFFF), "motor_fault": SWITCH,
    "battery_v": Rule(float, 0.0, 60.0), "stuck_odometry": SWITCH, "dlc_mismatch": SWITCH,
}
NMT_STATES = {"operational": 0x01, "start": 0x01, "stopped": 0x02, "stop": 0x02, "pre-operational": 0x80,
              "preop": 0x80, "reset": 0x81, "reset-node": 0x81, "reset-communication": 0x82}


@dataclass
class NodeSpec(DeviceSpec):
    """A CANopen rover board on a ``can`` endpoint."""

    model: str = MODELS[0]
    node_id: int = 2
    heartbeat_ms: int = 1000
    setpoint_timeout_ms: int = 150
    autostart: bool = False
    tpdo_periods_ms: dict[str, int] = field(default_factory=dict)
    identity: dict[str, int] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    odometry: dict[str, float] = field(default_factory=dict)


def board_config(spec: NodeSpec, bitrate: int):
    """The CAN interface configuration (:class:`~hilbench.protocols.board_can.BoardCanConfig`) of a device entry."""
    from hilbench.protocols.board_can import BoardCanConfig

    base = BoardCanConfig()
    periods = {**base.periods_ms, **spec.tpdo_periods_ms}
    return BoardCanConfig(node_id=spec.node_id, heartbeat_ms=spec.heartbeat_ms,
                          setpoint_timeout_ms=spec.setpoint_timeout_ms, periods_ms=periods, bitrate=bitrate,
                          **{IDENTITY_KEYS[k]: v for k, v in spec.identity.items()})


class CanopenBoardFamily(DeviceFamily):
    """CANopen rover boards on ``can`` endpoints."""

    name = "canopen"
    joins = ("can",)
    device_keys = DEVICE_KEYS
    models = MODELS
    device_word = "node"
    control_commands = {
        "status": "a node's NMT state, odometry, setpoint counters, errors and the bus figures",
        "nmt": "put a node into an NMT state from inside (state: operational, stopped, pre-operational, reset)",
        "reset": "reboot a node (boot-up message, defaults restored)",
        "fault": "turn a node's fault knobs: heartbeat_stop, silent, sdo_abort, motor_fault, battery_v, "
                 "stuck_odometry, dlc_mismatch",
        "emcy": "make a node send one EMCY (code, register, data hex)",
    }

    # ------------------------------------------------------------------ profile

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[NodeSpec]:
        from hilbench.protocols.board_can import PDOS

        model = c.choice(dev.get("model", MODELS[0]), f"{key}.model", MODELS)
        if model == RECORDED:
            return [check_recorded(c, key, dev, endpoint.name)]
        for extra in RECORDED_KEYS:
            if extra in dev:
                c.fail(f"{key}.{extra}", f'only for model = "{RECORDED}" nodes')
        name = dev.get("name", endpoint.name)
        if not isinstance(name, str) or not name:
            c.fail(f"{key}.name", f"expected a string, got {name!r}")
        periods = c.table(dev.get("tpdo_periods_ms", {}), f"{key}.tpdo_periods_ms")
        keys = tuple(p.key for p in PDOS if p.kind == "tpdo")
        c.unknown(periods, f"{key}.tpdo_periods_ms", keys)
        for k, v in periods.items():
            c.integer(v, f"{key}.tpdo_periods_ms.{k}", 0, 65535)
        identity = c.table(dev.get("identity", {}), f"{key}.identity")
        c.unknown(identity, f"{key}.identity", tuple(IDENTITY_KEYS))
        for k, v in identity.items():
            c.integer(v, f"{key}.identity.{k}", 0, 0xFFFFFFFF)
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), FAULT_RULES)
        node_id = c.integer(dev.get("node_id", 2), f"{key}.node_id", 1, 127)
        return [NodeSpec(
            name=name, endpoint=endpoint.name, model=model, address=node_id, node_id=node_id,
            heartbeat_ms=c.integer(dev.get("heartbeat_ms", 1000), f"{key}.heartbeat_ms", 0, 65535),
            setpoint_timeout_ms=c.integer(dev.get("setpoint_timeout_ms", 150), f"{key}.setpoint_timeout_ms", 0, 65535),
            autostart=c.boolean(dev.get("autostart", False), f"{key}.autostart"),
            tpdo_periods_ms=dict(periods), identity=dict(identity), faults=faults,
            odometry=check_odometry(c, dev.get("odometry", {}), f"{key}.odometry"),
        )]

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[NodeSpec], t: float) -> None:
        from hilbench.fakes.canopen.rover import RoverNode

        for spec in devices:
            if isinstance(spec, RecordedSpec):
                endpoint.add_device(spec.name, build_recorded(spec))
                continue
            battery = spec.faults.get("battery_v", 24.6)
            node = RoverNode(spec.name, board_config(spec, endpoint.medium.bitrate), autostart=spec.autostart,
                             battery_v=battery, encoder_noise=spec.odometry["encoder_noise"], seed=spec.node_id)
            node.set_faults(**{k: v for k, v in spec.faults.items() if k != "battery_v"})
            endpoint.add_device(spec.name, node)
            if spec.body is not None:  # RPDO1 setpoints move the body through the firmware's motion model
                refuse_second_driver(bench.world.world, spec.body, spec.name)
                bench.world.world.drive(spec.body, node.body_motion, spec.odometry["slip"])

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        now = endpoint.medium.clock.now()  # power-up happens now: the boot-up and the heartbeat phase count from here
        for node in devices.values():
            node.start(now)

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for node in devices.values():
            node.stop()

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: NodeSpec, device, endpoint, profile) -> dict[str, Any]:
        return {"name": spec.name, "model": spec.model, "endpoint": spec.endpoint,
                "protocol": profile.endpoints[spec.endpoint].protocol, "node_id": spec.node_id,
                "heartbeat_ms": spec.heartbeat_ms, "autostart": spec.autostart}

    # ------------------------------------------------------------------ artefacts

    artefacts = {
        "dbc": "the DBC of a profile's boards (cantools reads it; ``--dbc PROFILE`` of the CAN monitor)",
        "eds": "a board's EDS (the canopen package and CANopen tools import it)",
    }

    def artefact(self, kind: str, profile: Profile | str, device: str | None = None) -> str | None:
        from hilbench.protocols import board_can

        if isinstance(profile, str):
            from hilbench.bench.checks import ProfileError
            from hilbench.bench.profile import load_profile

            try:
                profile = load_profile(profile)
            except ProfileError:
                return None
        boards = [b for b in profile_boards(profile) if device is None or b[0] == device]
        if not boards:
            return None
        if kind == "dbc":
            return board_can.dbc(boards)
        if kind == "eds":
            name, cfg = boards[0]
            return board_can.eds(cfg, name)
        return None

    # ------------------------------------------------------------------ control channel

    def control(self, bench, node, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        endpoint = next(ep for ep in bench.endpoints.values() if node in ep.devices.values())
        medium = endpoint.medium

        def in_bus_thread(fn):
            """Run ``fn`` in the bus thread (the node's own) and wait for its result."""
            box: dict[str, Any] = {}
            done = threading.Event()

            def run() -> None:
                try:
                    box["value"] = fn()
                except Exception as exc:  # handed back to the caller
                    box["error"] = exc
                done.set()

            medium.call_at(None, run)
            if not done.wait(5):
                raise ControlError("the bus thread did not answer within 5 s")
            if "error" in box:
                raise ControlError(str(box["error"]))
            return box.get("value")

        if cmd == "status":
            return {"status": in_bus_thread(node.status), "bus": medium.status()}
        if cmd == "nmt":
            state = str(req.get("state", "")).lower()
            if state not in NMT_STATES:
                raise ControlRequestError(f"nmt: state must be one of {', '.join(NMT_STATES)}, got {state!r}")
            code = NMT_STATES[state]
            in_bus_thread(lambda: node._nmt(bytes([code, node.node_id]), node.now()))
            return {"status": in_bus_thread(node.status)}
        if cmd == "reset":
            in_bus_thread(lambda: node.reset())
            return {"status": in_bus_thread(node.status)}
        if cmd == "fault":
            rules = RECORDED_FAULT_RULES if getattr(node, "tpdos", None) is not None else FAULT_RULES
            checked = check_knobs(requested_knobs(req), rules)
            return {"faults": in_bus_thread(lambda: node.set_faults(**checked))}
        if cmd == "emcy":
            try:
                code = int(req.get("code", 0x1000))
                register = int(req.get("register", 0x80))
                data = bytes.fromhex(str(req.get("data", "")))
            except (TypeError, ValueError):
                raise ControlRequestError("emcy: code and register are integers, data is hex") from None
            if not 0 <= code <= 0xFFFF or not 0 <= register <= 0xFF or len(data) > 5:
                raise ControlRequestError("emcy: code 0..0xFFFF, register 0..0xFF, at most 5 data bytes")
            in_bus_thread(lambda: node.emcy(code, register, data.ljust(5, b"\0")))
            return {"status": in_bus_thread(node.status)}
        raise ControlRequestError(f"unknown command {cmd!r}")


def profile_boards(profile) -> list[tuple[str, Any]]:
    """``(device name, BoardCanConfig)`` of every CANopen board of a profile."""
    return [(spec.name, board_config(spec, profile.endpoints[spec.endpoint].baud or 500_000))
            for spec in profile.devices_of(CanopenBoardFamily.name) if not isinstance(spec, RecordedSpec)]


class CanopenNodes(FamilyAccess):
    """The CANopen nodes (rover boards, recorded nodes) of a running bench: ``bench.family("canopen")``."""

    family_name = "canopen"

    def node(self, name_or_id: str | int | None = None) -> RoverNode | RecordedNode:
        """A node by profile name or node id (``node(2)``, ``node("rover")``), or the only one."""
        if name_or_id is None or isinstance(name_or_id, str):
            return self.device(name_or_id)
        for name, spec in self.specs().items():
            if spec.node_id == name_or_id and name in self.bench.devices:
                return self.bench.devices[name]
        raise KeyError(f"no CANopen board at node id {name_or_id} "
                       f"(boards: {[(s.node_id, n) for n, s in self.specs().items()]})")


CanopenBoardFamily.access = CanopenNodes


FAMILY = CanopenBoardFamily()

__all__ = ["FAMILY", "MODELS", "CanopenBoardFamily", "CanopenNodes", "NodeSpec", "board_config",
           "profile_boards"]
