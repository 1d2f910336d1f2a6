"""An emulated FreeRTPS board: a minimal RTPS participant publishing and echoing ROS 2 messages.

A node has topics (:class:`TopicSpec`): publishers at a stated rate (the value
may carry a counter: ``"Hello {n}"``), subscribers that count and keep what
arrives, and echo outputs that republish, unchanged, every sample their input
topic receives. Topic names follow the naming mode of spec sheet §2.10:
``ros2`` (``rt/`` prefix, what ROS 2 nodes look for), ``legacy`` (the bare
name FreeRTPS-FreeRTOS used) or ``legacy-partition`` (bare name, partition
``rt``). Its GUID prefix is FreeRTPS's: ``2C 2F`` + the MAC + four zeros.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import Any

from hilbench.fakes.rtps_participant import RtpsParticipant
from hilbench.protocols import cdr

log = logging.getLogger(__name__)
NAMING = ("ros2", "legacy", "legacy-partition")


@dataclass
class TopicSpec:
    """One topic of a node (``direction`` ``pub`` or ``sub``; ``echo_of`` names the input an output repeats)."""

    name: str
    type: str
    direction: str
    rate_hz: float = 0.0
    value: Any = None
    echo_of: str | None = None
    reliable: bool = False

    def dds_name(self, naming: str) -> str:
        return f"rt/{self.name.lstrip('/')}" if naming == "ros2" else self.name.lstrip("/")

    @property
    def ros_type(self) -> cdr.RosType:
        t = cdr.ros_type(self.type)
        if t is None:
            raise KeyError(self.type)
        return t

    def sample(self, n: int) -> dict[str, Any]:
        """The message published the ``n``-th time (from 1)."""
        value = self.value
        fields = cdr.MESSAGES[self.ros_type.ros_name]
        if isinstance(value, dict):
            return value
        if len(fields) == 1:
            fname, ftype = fields[0]
            if ftype == "string":
                text = "Hello" if value is None else str(value)
                return {fname: text.replace("{n}", str(n))}
            return {fname: (n if value is None else value)}
        return {}


def mac_prefix(mac: str) -> bytes:
    """FreeRTPS's GUID prefix: ``2C 2F`` + the six MAC octets + four zeros (§2.3)."""
    octets = bytes(int(p, 16) for p in mac.replace("-", ":").split(":"))
    if len(octets) != 6:
        raise ValueError(f"expected a MAC address like 2C:4D:59:01:23:51, got {mac!r}")
    return b"\x2c\x2f" + octets + b"\x00\x00\x00\x00"


class FreeRtpsNode:
    """A FreeRTPS board as a device on a datagram net."""

    def __init__(self, name: str, *, domain_id: int, participant_index: int, mac: str, topics: list[TopicSpec],
                 peers: list[Any] | None = None, naming: str = "ros2", clock: str = "freertps",
                 keep: int = 100) -> None:
        if naming not in NAMING:
            raise ValueError(f"naming must be one of {NAMING}, got {naming!r}")
        self.name = name
        self.domain_id = domain_id
        self.participant_index = participant_index
        self.mac = mac
        self.topics = topics
        self.peers = peers
        self.naming = naming
        self.clock = clock
        self.port: Any = None
        self.participant: RtpsParticipant | None = None
        self.writers: dict[str, Any] = {}
        self.readers: dict[str, Any] = {}
        self.published: dict[str, int] = {t.name: 0 for t in topics}
        self.received: dict[str, int] = {t.name: 0 for t in topics if t.direction == "sub"}
        self.samples: dict[str, deque[dict[str, Any]]] = {t.name: deque(maxlen=keep) for t in topics
                                                            if t.direction == "sub"}
        self.decode_errors = 0
        self._echo: dict[str, list[str]] = {}
        for t in topics:
            if t.echo_of:
                self._echo.setdefault(t.echo_of, []).append(t.name)
        self._running = False
        self._t0 = 0.0

    @property
    def guid_prefix(self) -> bytes:
        return mac_prefix(self.mac)

    def attach(self, net: Any) -> None:
        """Join the net and bind the node's standard ports (OSError if another program holds them)."""
        self.port = net.add_device(self)
        self.participant = RtpsParticipant(self.name, self.port, domain_id=self.domain_id,
                                           participant_index=self.participant_index, guid_prefix=self.guid_prefix,
                                           peers=self.peers, clock=self.clock)
        self.participant.open()

    def on_datagram(self, data: bytes, src: tuple[str, int], dst: tuple[str, int], t: float) -> None:
        if self.participant is not None:
            self.participant.on_datagram(data, src, dst, t)

    def start(self) -> None:
        p = self.participant
        assert p is not None
        partition = "rt" if self.naming == "legacy-partition" else None
        for t in self.topics:
            dds = t.dds_name(self.naming)
            type_name = t.ros_type.dds_name
            if t.direction == "pub":
                self.writers[t.name] = p.add_writer(dds, type_name, reliable=t.reliable, partition=partition)
            else:
                self.readers[t.name] = p.add_reader(
                    dds, type_name, lambda data, le, guid, ts, _t=t: self._on_sample(_t, data, le),
                    reliable=t.reliable, partition=partition)
        self._running = True
        p.start()
        self._t0 = self.port.now()
        for t in self.topics:
            if t.direction == "pub" and t.rate_hz > 0 and not t.echo_of:
                self.port.call_at(self._t0 + 1.0 / t.rate_hz, lambda _t=t: self._publish(_t, 1))

    def stop(self) -> None:
        self._running = False
        if self.participant is not None:
            self.participant.stop()

    def _publish(self, t: TopicSpec, n: int) -> None:
        if not self._running:
            return
        # Release times from the start: no drift however late one tick ran. Queued first, so that nothing
        # the publication meets can stop the timer.
        self.port.call_at(self._t0 + (n + 1) / t.rate_hz, lambda: self._publish(t, n + 1))
        self.publish(t.name, t.sample(self.published[t.name] + 1))

    def publish(self, topic: str, value: dict[str, Any]) -> int:
        """Publish ``value`` on one of the node's output topics now; returns the readers it went to."""
        spec = next(t for t in self.topics if t.name == topic and t.direction == "pub")
        return self._write(spec, spec.ros_type.encode(value))

    def _write(self, spec: TopicSpec, raw: bytes, le: bool = True) -> int:
        self.published[spec.name] += 1
        return self.participant.write(self.writers[spec.name], raw, le)

    def _on_sample(self, t: TopicSpec, data: bytes, le: bool) -> None:
        self.received[t.name] += 1
        value, err = t.ros_type.try_decode(data, le)
        if err is not None:
            self.decode_errors += 1
        else:
            self.samples[t.name].append(value)
        for out in self._echo.get(t.name, ()):
            spec = next(o for o in self.topics if o.name == out)
            self._write(spec, data, le)  # unchanged, as received

    def describe_topics(self) -> list[dict[str, Any]]:
        out = []
        for t in self.topics:
            d = {"name": t.name, "dds_name": t.dds_name(self.naming), "type": t.ros_type.short_name,
                 "dds_type": t.ros_type.dds_name, "direction": t.direction, "rate_hz": t.rate_hz,
                 "reliable": t.reliable}
            if t.echo_of:
                d["echo_of"] = t.echo_of
            out.append(d)
        return out

    def status(self) -> dict[str, Any]:
        p = self.participant
        return {"name": self.name, "published": dict(self.published), "received": dict(self.received),
                "decode_errors": self.decode_errors, "participant": p.describe() if p else None,
                "counters": dict(p.counters) if p else {},
                "last": {k: list(v)[-5:] for k, v in self.samples.items()}}


__all__ = ["NAMING", "FreeRtpsNode", "TopicSpec", "mac_prefix"]
