"""The UDP monitor's state machine: datagrams (with their addresses) in, classes, sessions and topics out.

:class:`UdpTracker` takes each datagram (``feed_datagram``; a source without
addresses uses ``feed``, one chunk per datagram), classifies it
(:mod:`~hilbench.monitor.udp.classify`) and hands XRCE to
:class:`~hilbench.monitor.udp.xrce_state.XrceState` and RTPS to
:class:`~hilbench.monitor.udp.rtps_state.RtpsState`. Integrity flags (the
sheet's ``xrce.*`` and ``rtps.*``) are counted and logged with the address
that sent them, so a zeroed datagram shows who sent it and which session it
broke. No I/O; fed under the monitor's lock.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from hilbench.monitor.udp import classify as cl
from hilbench.monitor.udp.flows import Rate
from hilbench.monitor.udp.rtps_state import RtpsState
from hilbench.monitor.udp.xrce_state import XrceState
from hilbench.protocols.xrce_dds import DEFAULT_AGENT_PORT

#: Events kept for the log view and the summary.
MAX_EVENTS = 2000


class UdpTracker:
    """See the module docstring. ``agent_ports``: UDP ports known to be XRCE agents (more are learned)."""

    protocol = "udp"

    def __init__(self, *, baud: int | None = None, timestamps: bool = True,
                 agent_ports: tuple[int, ...] = (DEFAULT_AGENT_PORT,), max_events: int = MAX_EVENTS) -> None:
        self.baud = baud
        self.timestamps = timestamps
        self.t0: float | None = None
        self.t_last: float | None = None
        self.agent_ports: set[int] = set(agent_ports)
        self.classifiers = cl.datagram_classifiers()  # the instruments' own datagram classes (Vel2d, ...)
        self.classes: dict[str, list[int]] = {c: [0, 0] for c in cl.classes(self.classifiers)}
        self.rates: dict[str, Rate] = {c: Rate() for c in self.classes}
        self.flags: dict[str, int] = {}
        self.events: deque[tuple[float, str, str]] = deque(maxlen=max_events)
        self.events_total = 0
        self.datagrams = 0
        self.bytes = 0
        self.lost_bytes = 0
        self.senders: dict[str, list[int]] = {}
        self._names: dict[tuple[str, int], str] = {}  # "host:port" texts, made once per address
        self.xrce = XrceState(self._event, self._flag, self.agent_ports)
        self.rtps = RtpsState(self._event, self._flag)

    # ------------------------------------------------------------------ events

    def _event(self, t: float, kind: str, text: str) -> None:
        self.events.append((t, kind, text))
        self.events_total += 1

    def _flag(self, name: str, t: float, where: str, text: str, session: Any = None) -> None:
        self.flags[name] = self.flags.get(name, 0) + 1
        if session is not None:
            session.flag(name)
        self._event(t, name, f"{where}: {text}")

    # ------------------------------------------------------------------ input

    def feed_datagram(self, t: float, source: str, data: bytes, addr: tuple[str, int, str, int] | None) -> None:
        """One datagram; ``addr`` = (source host, source port, destination host, destination port) or None."""
        if self.t0 is None:
            self.t0 = t
        self.t_last = t
        n = len(data)
        self.datagrams += 1
        self.bytes += n
        if addr is not None:
            names = self._names
            src = names.get((addr[0], addr[1]))
            if src is None:
                src = names[(addr[0], addr[1])] = f"{addr[0]}:{addr[1]}"
            dst = names.get((addr[2], addr[3]))
            if dst is None:
                dst = names[(addr[2], addr[3])] = f"{addr[2]}:{addr[3]}"
            if len(names) > 8192:
                names.clear()
            sport, dport = addr[1], addr[3]
        else:
            src, dst, sport, dport = source, "?", None, None
        counts = self.senders.get(src)
        if counts is None:
            if len(self.senders) < 4096:
                self.senders[src] = [1, n]
        else:
            counts[0] += 1
            counts[1] += n
        kind = cl.classify(data, sport, dport, self.agent_ports, self.classifiers)
        c = self.classes[kind]
        c[0] += 1
        c[1] += n
        self.rates[kind].add(t, n)
        if kind == cl.XRCE:
            self.xrce.feed(t, data, src, dst, sport, dport)
        elif kind == cl.RTPS:
            self.rtps.feed(t, data, src)
        elif kind == cl.UNKNOWN and (cl.on_rtps_port(dport) or cl.on_rtps_port(sport)):
            self._flag("rtps.non_rtps", t, src, f"{n}-byte datagram without the RTPS magic on an RTPS port")

    def feed(self, t: float, source: str, data: bytes) -> None:
        """A chunk without addresses: taken as one datagram."""
        if data:
            self.feed_datagram(t, source, data, None)

    def gap(self, t: float, source: str, nbytes: int) -> None:
        self.lost_bytes += nbytes
        self._event(t, "gap", f"{source}: {nbytes} bytes lost before the monitor")

    def flush(self, t: float | None = None) -> None:
        """Datagrams are whole: nothing is partial."""

    def tick(self, t: float) -> None:
        """Quiet time: nothing expires (leases and stalls are judged from traffic)."""

    def finish(self) -> None:
        pass

    @property
    def duration(self) -> float | None:
        if self.t0 is None or self.t_last is None:
            return None
        return self.t_last - self.t0


__all__ = ["MAX_EVENTS", "UdpTracker"]
