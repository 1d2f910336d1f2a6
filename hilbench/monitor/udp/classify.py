"""What a UDP datagram carries (spec sheet §3.1): RTPS, XRCE, a Vel2d frame, trace stamps, or unknown.

Order of the rules: the ``RTPS`` magic; a datagram to or from a known XRCE
agent port (8888 and every port seen answering as an agent), or one that
looks like XRCE (header size, first submessage id <= 15, its length fits);
a 28-byte Vel2d frame with a good CRC-32/MPEG-2; the rover board's trace
output (binary stamp words, stamp or log lines); else unknown. A datagram on
a standard RTPS port without the magic is unknown and counted as
``rtps.non_rtps``.
"""

from __future__ import annotations

from hilbench.protocols import rtps, vel2d
from hilbench.protocols import xrce_dds as x

RTPS, XRCE, VEL2D, STAMPS, UNKNOWN = "rtps", "xrce", "vel2d", "stamps", "unknown"
CLASSES = (XRCE, RTPS, VEL2D, STAMPS, UNKNOWN)


def is_stamps(data: bytes) -> bool:
    """The board's trace output: binary stamp words (every byte >= 0x80, a 11xxxxxx byte every 4) or text
    lines of stamps, logs and reports."""
    n = len(data)
    if not n:
        return False
    if data[0] >= 0xC0:
        return all(b >= 0x80 for b in data[:64])
    if data[0] < 0x80 and data.count(b"\n") and all(b < 0x80 for b in data[:256]):
        from hilbench.protocols.tracestamp import classify

        line = data.split(b"\n", 1)[0]
        return classify(line) not in ("error", "blank")
    return False


def is_vel2d(data: bytes) -> bool:
    return len(data) == vel2d.FRAME_SIZE and vel2d.crc(data[:24]) == int.from_bytes(data[24:28], "little")


def classify(data: bytes, src_port: int | None, dst_port: int | None, agent_ports: set[int]) -> str:
    """The class of one datagram (the ports may be None when the source has no addresses)."""
    if data[:4] == b"RTPS":
        return RTPS
    if (dst_port in agent_ports or src_port in agent_ports) and len(data) >= 4:
        return XRCE
    if x.looks_like_xrce(data):
        return XRCE
    if is_vel2d(data):
        return VEL2D
    if is_stamps(data):
        return STAMPS
    return UNKNOWN


def on_rtps_port(port: int | None) -> bool:
    """A standard RTPS port of domains 0-232 (unicast or multicast, §2.2)."""
    return port is not None and 7400 <= port < 7400 + 250 * 233 and rtps.port_owner(port) is not None


__all__ = ["CLASSES", "RTPS", "STAMPS", "UNKNOWN", "VEL2D", "XRCE", "classify", "is_stamps", "is_vel2d",
           "on_rtps_port"]
