"""The Micro XRCE-DDS agent family: what ``micro_ros_agent udp4 --port 8888`` is, on UDP 127.0.0.1.

:data:`~hilbench.families.micro_ros_agent.BUS_KIND` is the agent's UDP port (endpoint ``protocol = "xrce-dds"``: one agent, a default one
when the profile lists none), :data:`~hilbench.families.micro_ros_agent.FAMILY` the agent.

Profile schema (endpoint ``protocol = "xrce-dds"``, ``type = "udp"``)::

    [endpoints.agent]
    type = "udp"
    protocol = "xrce-dds"
    port = 8888                    # 0: any free port (the manifest says which)

    [[devices]]                    # optional: an endpoint without one gets a default agent
    model = "micro-ros-agent"
    name = "agent"
    zeroed = "teardown"            # a zeroed CREATE_CLIENT from a session's address ends it, as the real
                                   # agent does (spec §1.9.4); "keep" keeps the session
    refs = { talker = { topic = "rt/chatter", type = "std_msgs::msg::dds_::String_", reliable = false } }
    bridge = { domain_id = 42, participant_index = 5 }   # optional: the samples on RTPS too
    faults = { drop_next = 0, corrupt_status_agent = 0 }
    max_sessions = 64              # sessions at once (a client beyond: STATUS_AGENT ERR_RESOURCES)
    session_timeout = 300          # seconds a silent session lives (0: for ever)

The manifest's endpoint entry says ``"role": "agent"`` with its ``host`` and
``port``; its device entry the agent's ``limits``;
``bench.family("micro-ros-agent").agent()`` (:class:`MicroRosAgents`) is the
:class:`~hilbench.fakes.xrce_agent.XrceAgent`.
Control commands: ``status`` (counters, sessions, entities, limits, log) and
``fault``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlRequestError
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess

if TYPE_CHECKING:
    from hilbench.fakes.xrce_agent import XrceAgent
    from hilbench.fakes.xrce_agent.bridge import RtpsBridge
from hilbench.bench.knobs import check_fault_table, requested_knobs
from hilbench.rules import FAULT_COUNT

AGENT_MODELS = ("micro-ros-agent", "micro-xrce-dds-agent")
AGENT_KEYS = ("model", "name", "endpoint", "zeroed", "refs", "bridge", "faults", "max_sessions", "session_timeout")
REF_KEYS = ("topic", "type", "reliable", "depth")
FAULT_RULES = {"drop_next": FAULT_COUNT, "corrupt_status_agent": FAULT_COUNT}
BRIDGE_KEYS = ("domain_id", "participant_index", "peers")
#: The agent's counters of what its bounds turned away (:meth:`MicroRosAgentFamily.overflow`).
AGENT_OVERFLOW = ("sessions_refused", "sessions_evicted", "sessions_expired", "entities_refused", "too_big",
                  "input_dropped", "output_dropped", "fragments_dropped", "fragment_nesting", "samples_dropped")


@dataclass
class AgentSpec(DeviceSpec):
    """An emulated Micro XRCE-DDS agent on an ``xrce-dds`` endpoint."""

    model: str = "micro-ros-agent"
    zeroed: str = "teardown"
    refs: dict[str, dict[str, Any]] = field(default_factory=dict)
    bridge: dict[str, Any] | None = None
    faults: dict[str, int] = field(default_factory=dict)
    max_sessions: int = 64
    session_timeout: float = 300.0


def check_bridge(c: Checker, key: str, raw: Any) -> dict[str, Any] | None:
    """An RTPS bridge table (``false``/absent: no bridge)."""
    if raw is None or raw is False:
        return None
    if raw is True:
        raw = {}
    raw = c.table(raw, key)
    c.unknown(raw, key, BRIDGE_KEYS)
    from hilbench.families.rtps_kit import DEFAULT_DOMAIN, check_peers

    return {"domain_id": c.integer(raw.get("domain_id", DEFAULT_DOMAIN), f"{key}.domain_id", 0, 232),
            "participant_index": c.integer(raw.get("participant_index", 9), f"{key}.participant_index", 0, 119),
            "peers": check_peers(c, f"{key}.peers", raw.get("peers"))}


class XrceDdsBusKind(BusKind):
    """An agent's UDP port (a datagram net): one agent per endpoint, a default one if the profile lists none."""

    protocol = "xrce-dds"
    endpoint_types = ("udp",)
    medium = "datagram"
    max_devices = 1
    one_device_reason = "one agent per port"
    default_device = {"model": AGENT_MODELS[0]}

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int | None:
        if value is not None:
            c.fail(key, "a UDP agent has no baud rate")
        return None

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        out: dict[str, Any] = {"role": "agent"}
        agent = next(iter(endpoint.devices.values()), None)
        if getattr(agent, "bridge", None) is not None:
            out["bridge"] = agent.bridge.describe()
        return out

    def summary(self, endpoint) -> str:
        agent = next(iter(endpoint.devices.values()), None)
        if agent is None:
            return "Micro XRCE-DDS agent port, no agent"
        bridge = getattr(agent, "bridge", None)
        extra = f", bridged to RTPS domain {bridge.domain_id}" if bridge is not None else ""
        return f"Micro XRCE-DDS agent {agent.name!r} (zeroed datagrams: {agent.zeroed}){extra}"

    def device_at(self, endpoint, address: int) -> Any:
        if not endpoint.devices:
            raise KeyError(f"endpoint {endpoint.name!r} has no agent")
        return next(iter(endpoint.devices.values()))


class MicroRosAgentFamily(DeviceFamily):
    """The emulated agent, one per ``xrce-dds`` endpoint."""

    name = "micro-ros-agent"
    joins = ("xrce-dds",)
    device_keys = AGENT_KEYS
    models = AGENT_MODELS
    device_word = "agent"
    control_commands = {
        "status": "counters, sessions with their entities and streams, the agent's log",
        "fault": "drop_next (outgoing datagrams to drop), corrupt_status_agent (STATUS_AGENTs with header 0x80)",
    }

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[AgentSpec]:
        model = c.choice(dev.get("model", AGENT_MODELS[0]), f"{key}.model", AGENT_MODELS)
        name = c.string(dev.get("name", endpoint.name), f"{key}.name")
        zeroed = c.choice(dev.get("zeroed", "teardown"), f"{key}.zeroed", ("teardown", "keep"))
        refs_raw = c.table(dev.get("refs", {}), f"{key}.refs")
        refs: dict[str, dict[str, Any]] = {}
        for ref, body in refs_raw.items():
            where = f"{key}.refs.{ref}"
            body = c.table(body, where)
            c.unknown(body, where, REF_KEYS)
            for k in ("topic", "type"):
                if not isinstance(body.get(k, ""), str):
                    c.fail(f"{where}.{k}", f"expected a string, got {body[k]!r}")
            refs[ref] = {"topic": body.get("topic") or None, "type": body.get("type") or None,
                         "reliable": c.boolean(body.get("reliable", True), f"{where}.reliable"),
                         "depth": c.integer(body.get("depth", 1), f"{where}.depth", 1, 1000)}
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), FAULT_RULES)
        from hilbench.fakes.xrce_agent.agent import MAX_SESSIONS, SESSION_TIMEOUT_S

        return [AgentSpec(name=name, endpoint=endpoint.name, model=model, zeroed=zeroed, refs=refs,
                          bridge=check_bridge(c, f"{key}.bridge", dev.get("bridge")), faults=faults,
                          max_sessions=c.integer(dev.get("max_sessions", MAX_SESSIONS), f"{key}.max_sessions", 1,
                                                 4096),
                          session_timeout=c.number(dev.get("session_timeout", SESSION_TIMEOUT_S),
                                                   f"{key}.session_timeout", 0, 86_400))]

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[AgentSpec], t: float) -> None:
        from hilbench.fakes.xrce_agent import XrceAgent

        for spec in devices:
            agent = XrceAgent(spec.name, zeroed=spec.zeroed, refs=spec.refs, max_sessions=spec.max_sessions,
                              session_timeout=spec.session_timeout)
            agent.set_faults(**spec.faults)
            endpoint.add_device(spec.name, agent)
            if spec.bridge is not None:
                from hilbench.fakes.xrce_agent.bridge import RtpsBridge

                RtpsBridge(agent, endpoint.medium, **spec.bridge)  # (it is agent.bridge from now on)

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        for agent in devices.values():
            agent.start()
            if agent.bridge is not None:
                agent.bridge.start()

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for agent in devices.values():
            if agent.bridge is not None:
                agent.bridge.stop()
            agent.stop()

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: AgentSpec, device, endpoint, profile) -> dict[str, Any]:
        out = {"name": spec.name, "model": spec.model, "endpoint": spec.endpoint, "protocol": "xrce-dds",
               "role": "agent", "zeroed": spec.zeroed, "refs": sorted(spec.refs)}
        if endpoint is not None:
            host, port = endpoint.port.address
            out.update(host=host, port=port)
        if device is not None:
            out["limits"] = device.limits()
        return out

    def overflow(self, agent, endpoint) -> dict[str, Any]:
        """The agent's limits and what it refused, expired, evicted or dropped (and its RTPS bridge's)."""
        c = agent.counters
        out: dict[str, Any] = {"limits": agent.limits(), **{k: c[k] for k in AGENT_OVERFLOW}}
        if agent.bridge is not None and agent.bridge.participant is not None:
            out["bridge"] = agent.bridge.participant.overflow()
        return out

    # ------------------------------------------------------------------ control channel

    def control(self, bench, agent, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "status":
            st = agent.status()
            if agent.bridge is not None:  # its RTPS participant: peers, limits and what it refused
                st["bridge"] = {**agent.bridge.describe(), "counters": dict(agent.bridge.participant.counters)}
            return {"status": st}
        if cmd == "fault":
            knobs = requested_knobs(req)
            try:
                return {"faults": agent.set_faults(**{k: int(v) for k, v in knobs.items()})}
            except (KeyError, TypeError, ValueError) as exc:
                raise ControlRequestError(str(exc)) from None
        raise ControlRequestError(f"unknown command {cmd!r}")


class MicroRosAgents(FamilyAccess):
    """The XRCE-DDS agents of a running bench: ``bench.family("micro-ros-agent")``."""

    family_name = "micro-ros-agent"

    def agent(self, name: str | None = None) -> XrceAgent:
        """An agent by profile name, or the only one."""
        return self.device(name)

    def bridge(self, name: str | None = None) -> RtpsBridge | None:
        """The RTPS bridge of an agent (``bridge = {...}`` in its profile entry), or None."""
        return self.agent(name).bridge


MicroRosAgentFamily.access = MicroRosAgents
#: The bus kind this module registers (entry point ``hilbench.bus_kinds``).
BUS_KIND = XrceDdsBusKind()
#: The device family this module registers (entry point ``hilbench.families``).
FAMILY = MicroRosAgentFamily()

__all__ = ["AGENT_MODELS", "BUS_KIND", "FAMILY", "AgentSpec", "MicroRosAgentFamily", "MicroRosAgents", "XrceDdsBusKind",
           "check_bridge"]
