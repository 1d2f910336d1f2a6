"""The agent's DDS side: XRCE topics on RTPS, so micro-ROS clients and ROS 2 nodes see each other.

The real agent creates a Fast DDS participant per client participant; this
bridge is one RTPS participant (:class:`~hilbench.fakes.rtps_participant.RtpsParticipant`,
vendor eProsima) on the agent's datagram net, at the standard ports of its
domain and participant index, 127.0.0.1 only. Every XRCE datawriter gets an
RTPS writer on its topic and type (its reliability), every XRCE datareader an
RTPS reader (best effort, which matches any writer). Samples a client writes
go to the RTPS readers that matched; samples RTPS writers send go to the XRCE
readers of the topic (never back to RTPS). Both run in the net's thread.
"""

from __future__ import annotations

import os
import random
from typing import Any

from hilbench.fakes.rtps_participant import RtpsParticipant

VENDOR_EPROSIMA = b"\x01\x0f"


class _BridgeDevice:
    def __init__(self, bridge: RtpsBridge, name: str) -> None:
        self.bridge = bridge
        self.name = name

    def on_datagram(self, data: bytes, src: tuple[str, int], dst: tuple[str, int], t: float) -> None:
        self.bridge.participant.on_datagram(data, src, dst, t)


class RtpsBridge:
    """See the module docstring. Raises :class:`~hilbench.errors.BenchError` if its ports are taken."""

    def __init__(self, agent: Any, net: Any, *, domain_id: int, participant_index: int,
                 peers: list[str] | None = None) -> None:
        from hilbench.errors import BenchError
        from hilbench.protocols import rtps

        self.agent = agent
        self.domain_id = domain_id
        self.participant_index = participant_index
        self.port = net.add_device(_BridgeDevice(self, f"{agent.name}-rtps"))
        clock = self.port.clock
        if clock.virtual:  # the same GUID every run of a virtual bench with the same (pinned) epoch
            prefix = VENDOR_EPROSIMA + random.Random(f"{agent.name}:{domain_id}:{participant_index}:"
                                                     f"{clock.wall(clock.now())}").randbytes(10)
        else:
            prefix = VENDOR_EPROSIMA + os.urandom(10)
        self.participant = RtpsParticipant(f"{agent.name}-rtps", self.port, domain_id=domain_id,
                                           participant_index=participant_index, guid_prefix=prefix, peers=peers,
                                           vendor_id=VENDOR_EPROSIMA, pl_vendor_id=VENDOR_EPROSIMA, clock="wall",
                                           lease_s=20, entity_name="micro_ros_agent")
        try:
            self.participant.open()
        except OSError as exc:
            ports = rtps.ports(domain_id, participant_index)
            raise BenchError(f"agent bridge: cannot bind 127.0.0.1 ports {ports['metatraffic_unicast']}/"
                             f"{ports['user_unicast']} (domain {domain_id}, participant index "
                             f"{participant_index}): {exc.strerror or exc}") from None
        self.writers: dict[tuple[str, str], Any] = {}
        self.readers: dict[tuple[str, str], Any] = {}
        self._refs: dict[tuple[str, str, str], int] = {}
        self.to_rtps = 0
        self.from_rtps = 0
        agent.bridge = self

    def start(self) -> None:
        self.participant.start()

    def stop(self) -> None:
        self.participant.stop()

    def entity(self, session: Any, ent: Any, topic: str | None, type_name: str | None, removed: bool) -> None:
        """An XRCE datawriter or datareader was created or deleted."""
        from hilbench.protocols.xrce_dds import ObjectKind

        if not topic or not type_name:
            return
        writer = ent.kind == ObjectKind.DATAWRITER
        key = (topic, type_name)
        ref = ("w" if writer else "r", topic, type_name)
        n = self._refs.get(ref, 0) + (-1 if removed else 1)
        self._refs[ref] = max(0, n)
        table = self.writers if writer else self.readers
        if removed:
            if n <= 0 and key in table:
                self.participant.remove(table.pop(key).entity_id)
            return
        if key in table:
            return
        if writer:
            table[key] = self.participant.add_writer(topic, type_name, reliable=bool(ent.reliable))
        else:
            table[key] = self.participant.add_reader(
                topic, type_name, lambda data, le, guid, ts, _t=topic, _y=type_name: self._from_rtps(_t, _y, data,
                                                                                                    guid))

    def publish(self, topic: str | None, type_name: str | None, cdr: bytes, session: Any, ent: Any) -> None:
        """A client's sample: to every RTPS reader matched on its topic."""
        w = self.writers.get((topic or "", type_name or ""))
        if w is not None and w.matched:
            self.participant.write(w, cdr)
            self.to_rtps += 1

    def _from_rtps(self, topic: str, type_name: str, cdr: bytes, writer_guid: bytes) -> None:
        ep = self.participant.remote_endpoints.get(writer_guid)
        self.from_rtps += 1
        self.agent.route(topic, type_name, cdr, reliable=bool(ep.reliable) if ep is not None else True)

    def describe(self) -> dict[str, Any]:
        return {**self.participant.describe(), "to_rtps": self.to_rtps, "from_rtps": self.from_rtps}


__all__ = ["RtpsBridge"]
