"""The FreeRTPS family: microcontroller boards speaking minimal RTPS on 127.0.0.1 unicast.

:data:`~hilbench.families.freertps.BUS_KIND` is the RTPS net (endpoint ``protocol = "rtps"``: domain, peers, naming; nodes addressed
by participant index), :data:`~hilbench.families.freertps.FAMILY` the boards on it.

Profile schema (endpoint ``protocol = "rtps"``, ``type = "udp"``)::

    [endpoints.nodes]
    type = "udp"
    protocol = "rtps"
    port = 0                       # a shared discovery port: SPDP sent here reaches every node
    domain_id = 42                 # non-zero by default, away from a real DDS on the machine
    peers = ["127.0.0.1"]          # where SPDP goes: every participant index of a host, or "host:port"
    naming = "ros2"                # "ros2" (rt/ prefix), "legacy" or "legacy-partition" (spec §2.10)

    [[devices]]
    model = "freertps-node"
    name = "talker"
    participant_index = 0          # ports 7410/7411 + 250 * domain_id + 2 * index
    mac = "2C:4D:59:01:23:53"      # the GUID prefix is 2C 2F + MAC + 00 00 00 00
    topics = [{ name = "chatter", type = "std_msgs/String", direction = "pub", rate_hz = 10,
                value = "Hello" }]

A topic is ``{name, type, direction = "pub" | "sub", rate_hz, value, reliable,
echo_of}``: an output with ``echo_of = "INPUT"`` republishes what the input
receives. The manifest's device entries give ``domain_id``,
``participant_index``, ``guid_prefix``, ``ports``, ``topics`` (each with
its ``dds_name``) and ``limits`` (the remote participants, endpoints, locator
ports and leases a node keeps: :mod:`hilbench.fakes.rtps_participant`).
Control commands: ``status`` (with the participant's counters: refused,
expired, invalid locators ...) and ``publish``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError, ControlRequestError
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.families.rtps_kit import DEFAULT_DOMAIN, check_peers

if TYPE_CHECKING:
    from hilbench.fakes.rtps_node import FreeRtpsNode

NODE_MODELS = ("freertps-node", "stm32f407-freertps")
NODE_KEYS = ("model", "name", "endpoint", "participant_index", "mac", "topics", "clock")
TOPIC_KEYS = ("name", "type", "direction", "rate_hz", "value", "reliable", "echo_of")
NAMING = ("ros2", "legacy", "legacy-partition")
#: Highest participant index: the user unicast port of domain 232 must stay below 65536.
MAX_INDEX = 119


@dataclass
class NodeSpec(DeviceSpec):
    """An emulated FreeRTPS board on an ``rtps`` endpoint."""

    model: str = "freertps-node"
    participant_index: int = 0
    mac: str = ""
    topics: list[dict[str, Any]] = field(default_factory=list)
    clock: str = "freertps"


def _check_topics(c: Checker, key: str, raw: Any) -> list[dict[str, Any]]:
    from hilbench.protocols import cdr

    if not isinstance(raw, list) or not raw:
        c.fail(key, "expected a list of topic tables ({ name, type, direction, rate_hz ... })")
    out = []
    names: set[str] = set()
    for i, t in enumerate(raw):
        where = f"{key}[{i}]"
        t = c.table(t, where)
        c.unknown(t, where, TOPIC_KEYS)
        name = c.string(t.get("name"), f"{where}.name")
        if name in names:
            c.fail(f"{where}.name", f"topic {name!r} is listed twice")
        names.add(name)
        typ = c.string(t.get("type"), f"{where}.type")
        if cdr.ros_type(typ) is None:
            known = ", ".join(cdr.ros_type(n).short_name for n in cdr.known_types())
            c.fail(f"{where}.type", f"unknown message type {typ!r} (known: {known})")
        direction = c.choice(t.get("direction"), f"{where}.direction", ("pub", "sub"))
        rate = c.number(t.get("rate_hz", 0.0), f"{where}.rate_hz", 0.0, 10_000.0)
        out.append({"name": name, "type": typ, "direction": direction, "rate_hz": rate, "value": t.get("value"),
                    "reliable": c.boolean(t.get("reliable", False), f"{where}.reliable"),
                    "echo_of": t.get("echo_of")})
    for i, t in enumerate(out):
        if t["echo_of"] is not None:
            src = next((s for s in out if s["name"] == t["echo_of"]), None)
            if t["direction"] != "pub" or src is None or src["direction"] != "sub" or src["type"] != t["type"]:
                c.fail(f"{key}[{i}].echo_of", "expected the name of a subscribed topic of the same type, on a "
                                              "published topic")
    return out


class RtpsBusKind(BusKind):
    """An RTPS net on 127.0.0.1 (a datagram medium): one domain; participants addressed by their index."""

    protocol = "rtps"
    endpoint_types = ("udp",)
    medium = "datagram"
    endpoint_keys = ("domain_id", "peers", "naming")
    address_key = "participant_index"
    address_word = "participant index"

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int | None:
        if value is not None:
            c.fail(key, "an RTPS endpoint has no baud rate")
        return None

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        return {"domain_id": c.integer(raw.get("domain_id", DEFAULT_DOMAIN), f"{key}.domain_id", 0, 232),
                "peers": check_peers(c, f"{key}.peers", raw.get("peers")),
                "naming": c.choice(raw.get("naming", "ros2"), f"{key}.naming", NAMING)}

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        opts = endpoint.spec.options
        return {"domain_id": opts["domain_id"], "naming": opts["naming"], "peers": opts["peers"]}

    def summary(self, endpoint) -> str:
        opts = endpoint.spec.options
        nodes = ", ".join(f"{name}#{s.address}" for name, s in endpoint.specs.items())
        return (f"RTPS domain {opts['domain_id']}, {len(endpoint.devices)} nodes ({nodes}), "
                f"naming {opts['naming']}")


class FreeRtpsFamily(DeviceFamily):
    """FreeRTPS boards (one RTPS participant each) on RTPS nets."""

    name = "freertps"
    joins = ("rtps",)
    device_keys = NODE_KEYS
    models = NODE_MODELS
    device_word = "node"
    control_commands = {
        "status": "what a node published and received, its discovered peers and counters",
        "publish": "publish one sample now: topic, value (a table of the message's fields)",
    }

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[NodeSpec]:
        model = c.choice(dev.get("model", NODE_MODELS[0]), f"{key}.model", NODE_MODELS)
        index = c.integer(dev.get("participant_index", 0), f"{key}.participant_index", 0, MAX_INDEX)
        mac = dev.get("mac", f"2C:4D:59:01:23:{0x51 + index:02X}")
        from hilbench.fakes.rtps_node.node import mac_prefix

        try:
            mac_prefix(str(mac))
        except ValueError as exc:
            c.fail(f"{key}.mac", str(exc))
        return [NodeSpec(name=c.string(dev.get("name", f"node{index}"), f"{key}.name"), endpoint=endpoint.name,
                         model=model, participant_index=index, address=index, mac=str(mac),
                         topics=_check_topics(c, f"{key}.topics", dev.get("topics")),
                         clock=c.choice(dev.get("clock", "freertps"), f"{key}.clock", ("freertps", "wall")))]

    def check_profile(self, c: Checker, profile) -> None:
        macs: dict[str, str] = {}
        for spec in profile.devices_of(self.name):
            if spec.mac.upper() in macs:
                c.fail(f"{spec.where}.mac", f"same MAC as {macs[spec.mac.upper()]!r}: the GUID prefixes collide")
            macs[spec.mac.upper()] = spec.name

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[NodeSpec], t: float) -> None:
        from hilbench.fakes.rtps_node import FreeRtpsNode, TopicSpec
        from hilbench.protocols import rtps
        from hilbench.transports.listener import BindError

        opts = endpoint.spec.options
        for spec in devices:
            node = FreeRtpsNode(spec.name, domain_id=opts["domain_id"], participant_index=spec.participant_index,
                                mac=spec.mac, topics=[TopicSpec(**t) for t in spec.topics], peers=opts["peers"],
                                naming=opts["naming"], clock=spec.clock)
            try:
                endpoint.add_device(spec.name, node)  # joins the net: binds the node's ports
            except OSError as exc:
                ports = rtps.ports(opts["domain_id"], spec.participant_index)
                reason = (f"{exc.reason if isinstance(exc, BindError) else exc.strerror or exc} (node {spec.name!r}: "
                          f"domain {opts['domain_id']}, {spec.where}.participant_index {spec.participant_index} "
                          f"use ports {ports['metatraffic_unicast']}/{ports['user_unicast']})")
                raise BindError(getattr(exc, "address", ("127.0.0.1", ports["metatraffic_unicast"])), reason,
                                exc.errno, "RTPS port", key="domain_id") from None

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        for node in devices.values():
            node.start()

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for node in devices.values():
            node.stop()

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: NodeSpec, device, endpoint, profile) -> dict[str, Any]:
        from hilbench.fakes.rtps_node.node import mac_prefix
        from hilbench.fakes.rtps_participant import limits
        from hilbench.protocols import rtps

        ep = profile.endpoints[spec.endpoint]
        domain = ep.options["domain_id"]
        ports = rtps.ports(domain, spec.participant_index)
        topics = device.describe_topics() if device is not None else spec.topics
        return {"name": spec.name, "model": spec.model, "endpoint": spec.endpoint, "protocol": "rtps",
                "domain_id": domain, "participant_index": spec.participant_index, "mac": spec.mac,
                "guid_prefix": mac_prefix(spec.mac).hex(), "host": "127.0.0.1",
                "ports": {"metatraffic_unicast": ports["metatraffic_unicast"], "user_unicast": ports["user_unicast"]},
                "topics": topics, "limits": limits()}

    def overflow(self, node, endpoint) -> dict[str, Any]:
        """Its participant's limits and the remote participants, endpoints and locators it refused or expired."""
        return node.participant.overflow() if node.participant is not None else {}

    # ------------------------------------------------------------------ control channel

    def control(self, bench, node, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "status":
            return {"status": node.status()}
        if cmd == "publish":
            topic, value = req.get("topic"), req.get("value", {})
            if not isinstance(value, dict):
                raise ControlRequestError("value: expected an object of the message's fields")
            done: dict[str, Any] = {}
            ev = __import__("threading").Event()

            def run() -> None:
                try:
                    done["readers"] = node.publish(topic, value)
                except StopIteration:
                    done["error"] = f"node {node.name!r} publishes no topic {topic!r}"
                except Exception as exc:  # noqa: BLE001 (a bad value: one line back to the caller)
                    done["error"] = f"{type(exc).__name__}: {exc}"
                ev.set()

            node.port.call_at(None, run)  # in the net's thread, like every other node action
            if not ev.wait(5):
                raise ControlError("the node did not publish within 5 s")
            if "error" in done:
                raise ControlError(done["error"])
            return {"readers": done["readers"]}
        raise ControlRequestError(f"unknown command {cmd!r}")


class FreeRtpsNodes(FamilyAccess):
    """The FreeRTPS nodes of a running bench: ``bench.family("freertps")``."""

    family_name = "freertps"

    def node(self, name: str | None = None) -> FreeRtpsNode:
        """A node by profile name (``node("echo")``), or the only one."""
        return self.device(name)


FreeRtpsFamily.access = FreeRtpsNodes
#: The bus kind this module registers (entry point ``hilbench.bus_kinds``).
BUS_KIND = RtpsBusKind()
#: The device family this module registers (entry point ``hilbench.families``).
FAMILY = FreeRtpsFamily()

__all__ = ["BUS_KIND", "DEFAULT_DOMAIN", "FAMILY", "FreeRtpsFamily", "FreeRtpsNodes", "NodeSpec", "RtpsBusKind", "check_peers"]
