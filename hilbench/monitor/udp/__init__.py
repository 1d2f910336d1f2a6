"""The UDP monitor: micro-ROS (XRCE-DDS), RTPS and other datagrams, classified and tracked.

- :mod:`classify`: what one datagram carries (XRCE, RTPS, Vel2d, trace stamps, unknown);
- :mod:`xrce_state`, :mod:`rtps_state`: sessions, entities, streams, participants, endpoints, topics;
- :mod:`tracker`: :class:`UdpTracker`, the state machine the monitor feeds;
- :mod:`summary`: the JSON summary and its printed form;
- :data:`INSTRUMENT`: the plug-in (``hilbench.instruments`` entry point ``udp``), for the protocols
  ``udp``, ``xrce-dds`` and ``rtps`` (a bench's agent or FreeRTPS endpoint, a pcap, a UDP relay).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from hilbench.monitor.instrument import Instrument
from hilbench.rules import PORT

if TYPE_CHECKING:  # the tracker is imported when one is made: the plug-in stays light
    from hilbench.monitor.udp.tracker import UdpTracker


class UdpInstrument(Instrument):
    """UDP traffic of micro-ROS boards, agents and RTPS nodes as an instrument plug-in."""

    protocol = "udp"
    aliases = ("xrce-dds", "xrce", "rtps", "micro-ros")
    title = "UDP traffic (Micro XRCE-DDS, RTPS)"
    views_path = "hilbench.dashboard.udp_views:VIEW_SET"

    def sniff(self, data: bytes) -> float:
        if data[:4] == b"RTPS":
            return 0.9
        if not (b"XRCE" in data[:16] or data[:1] in (b"\x80", b"\x81", b"\x00", b"\x01")):
            return 0.0  # (told before the codec's import: other bytes never look like XRCE here)
        from hilbench.protocols import xrce_dds

        return 0.6 if xrce_dds.looks_like_xrce(data) else 0.0

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("UDP (micro-ROS, RTPS)")
        g.add_argument("--agent-port", type=PORT, action="append", metavar="PORT",
                       help="a UDP port where an XRCE agent listens (default 8888; repeatable; agents are also "
                            "learned from their replies)")

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        ports = getattr(args, "agent_port", None)
        if ports is None:
            return {}
        return {"agent_ports": tuple(ports)}

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> UdpTracker:
        from hilbench.monitor.udp.tracker import UdpTracker

        return UdpTracker(baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: UdpTracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        from hilbench.monitor.udp.summary import summary

        return summary(tracker, source=source, protocol=self.protocol, timestamps=timestamps, errors=errors)

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        from hilbench.monitor.udp.summary import print_summary

        print_summary(report, console)


#: The plug-in (entry point ``udp`` of ``hilbench.instruments``).
INSTRUMENT = UdpInstrument()

__all__ = ["INSTRUMENT", "UdpInstrument"]
