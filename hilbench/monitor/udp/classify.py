"""What a UDP datagram carries (spec sheet §3.1): RTPS, XRCE, a class an instrument contributes, or unknown.

Order of the rules: the ``RTPS`` magic; a datagram to or from a known XRCE
agent port (8888 and every port seen answering as an agent), or one that
looks like XRCE (header size, first submessage id <= 15, its length fits);
then each instrument with :attr:`~hilbench.monitor.instrument.Instrument.datagram_classes`
in registration order (the rover board's trace instrument: a 28-byte Vel2d
frame with a good CRC-32/MPEG-2, then its trace output: binary stamp words,
stamp or log lines); else unknown. A datagram on
a standard RTPS port without the magic is unknown and counted as
``rtps.non_rtps``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hilbench.protocols import rtps
from hilbench.protocols import xrce_dds as x

if TYPE_CHECKING:
    from hilbench.monitor.instrument import Instrument

RTPS, XRCE, UNKNOWN = "rtps", "xrce", "unknown"


def datagram_classifiers() -> list[Instrument]:
    """The instruments that classify datagrams of their own (their
    :attr:`~hilbench.monitor.instrument.Instrument.datagram_classes`), in registration order."""
    from hilbench import registry

    return registry.instruments.find(lambda inst: bool(inst.datagram_classes))


def classes(classifiers: list[Instrument]) -> tuple[str, ...]:
    """Every class a tracker counts: XRCE, RTPS, the classifiers' (once each), unknown."""
    found = dict.fromkeys((XRCE, RTPS))
    for inst in classifiers:
        found.update(dict.fromkeys(inst.datagram_classes))
    return (*found, UNKNOWN)


def classify(data: bytes, src_port: int | None, dst_port: int | None, agent_ports: set[int],
             classifiers: list[Instrument] | None = None) -> str:
    """The class of one datagram (the ports may be None when the source has no addresses; ``classifiers``:
    :func:`datagram_classifiers`, which a tracker finds once)."""
    if data[:4] == b"RTPS":
        return RTPS
    if (dst_port in agent_ports or src_port in agent_ports) and len(data) >= 4:
        return XRCE
    if x.looks_like_xrce(data):
        return XRCE
    for inst in datagram_classifiers() if classifiers is None else classifiers:
        kind = inst.classify_datagram(data)
        if kind is not None:
            return kind
    return UNKNOWN


def on_rtps_port(port: int | None) -> bool:
    """A standard RTPS port of domains 0-232 (unicast or multicast, §2.2)."""
    return port is not None and 7400 <= port < 7400 + 250 * 233 and rtps.port_owner(port) is not None


__all__ = ["RTPS", "UNKNOWN", "XRCE", "classes", "classify", "datagram_classifiers", "on_rtps_port"]
