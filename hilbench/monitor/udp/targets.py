"""The UDP monitor's tracker as a fuzz target (:mod:`hilbench.fuzzing`), and the datagram mix that
``tools/bench_udp.py`` measures it with.

Rough-input targets read byte streams split anywhere, and the tracker reads whole datagrams with their
addresses, so the target's stream frames each datagram as a capture would: :data:`MAGIC`, one byte choosing
its address pair from :data:`ADDRESSES`, a 16-bit big-endian length, the datagram. A frame counts only if
the next one's :data:`MAGIC` follows it (or the input ends there); anything else is skipped to the next
:data:`MAGIC`, so a damaged length loses one datagram, not the stream. What that feeds the tracker is the
point: every XRCE-DDS and RTPS parser behind it meets whatever the mutations made of the datagrams.
"""

from __future__ import annotations

import random

from hilbench.fuzzing import FuzzTarget
from hilbench.monitor.udp import classify as cl
from hilbench.monitor.udp.tracker import UdpTracker
from hilbench.protocols import rtps as r
from hilbench.protocols import xrce_dds as x

CLIENT, AGENT, NODE_A, NODE_B = ("127.0.0.1", 40001), ("127.0.0.1", 8888), ("127.0.0.1", 7411), ("127.0.0.1", 7413)
#: The address pairs (source host, port, destination host, port) a framed datagram chooses from.
ADDRESSES = ((*CLIENT, *AGENT), (*AGENT, *CLIENT), (*NODE_A, *NODE_B))
#: A jumbo frame's payload: no datagram the monitor reads from a link is longer.
MAX_DATAGRAM = 9000
#: Starts every framed datagram.
MAGIC = b"\xa5\x5a"
HEADER = len(MAGIC) + 3
#: A saturated 100 Mbit/s Ethernet link of 100-byte datagrams (166 byte times each on the wire, as
#: ``tools/bench_udp.py`` counts), in framed bytes per second.
LINK_100M = 100e6 / (8 * 166) * (100 + HEADER)


def datagrams(n: int, t: float = 0.0) -> list[tuple[float, bytes, tuple[str, int, str, int]]]:
    """A mix of 100-byte datagrams between a micro-ROS client, its agent and two RTPS nodes, 10 us apart:
    best-effort and reliable XRCE WRITE_DATA, the agent's DATA and ACKNACKs, RTPS user DATA from two
    writers. Clean: the tracker raises no flag on it."""
    prefix = bytes.fromhex("2C2F2C4D5901235300000000")
    out = []
    for i in range(n):
        t += 1e-5
        k = i % 8
        if k < 3:  # best-effort WRITE_DATA, 100 bytes
            body = x.data(b"\x00\x0a", b"\x00\x15", bytes(88))
            d = x.build_message(0x81, 0x01, i & 0xFFFF, [(7, 1, body)])
            out.append((t, d, ADDRESSES[0]))
        elif k == 3:  # the agent's DATA to a reader
            d = x.build_message(0x81, 0x01, i & 0xFFFF, [(9, 1, x.data(b"\x00\x0e", b"\x00\x16", bytes(88)))])
            out.append((t, d, ADDRESSES[1]))
        elif k == 4:  # reliable WRITE_DATA
            d = x.build_message(0x81, 0x80, (i // 8) & 0xFFFF, [(7, 1, x.data(b"\x00\x0b", b"\x00\x25", bytes(88)))])
            out.append((t, d, ADDRESSES[0]))
        elif k == 5:  # the agent's ACKNACK
            d = x.build_message(0x81, 0, 0, [(10, 1, x.acknack((i // 8 + 1) & 0xFFFF, 0, 0x80))])
            out.append((t, d, ADDRESSES[1]))
        else:  # RTPS user DATA: INFO_TS + DATA, 100 bytes
            writer = b"\x00\x00\x01\x03" if k == 6 else b"\x00\x00\x02\x03"
            payload = r.CDR_LE + b"\x00\x00" + bytes(36)
            d = r.message(prefix, r.info_ts(1436564565, i), r.data(r.ENTITYID_UNKNOWN, writer, i // 8 + 1, payload))
            out.append((t, d, ADDRESSES[2]))
    return out


def udp_traffic(_rng: random.Random, size: int) -> bytes:
    """:func:`datagrams` framed as the target reads them, about ``size`` bytes."""
    out = bytearray()
    for _, d, addr in datagrams(max(1, size // (100 + HEADER))):
        out += MAGIC + bytes((ADDRESSES.index(addr),)) + len(d).to_bytes(2, "big") + d
    return bytes(out)


class _DatagramReader:
    """Framed datagrams in, the tracker fed one datagram at a time 10 us apart. ``good``: datagrams it
    classified as XRCE-DDS or RTPS without a new flag; ``dropped``: framing bytes skipped plus the bytes of
    datagrams it flagged or could not classify."""

    def __init__(self) -> None:
        self.tracker = UdpTracker()
        self._buf = bytearray()
        self.t = 0.0
        self.ok = 0
        self.bad = 0
        self.skipped = 0
        self._flags = 0  # flags raised so far

    def feed(self, data: bytes) -> None:
        self._buf += data
        self._frames(final=False)

    def _frames(self, final: bool) -> None:
        buf = self._buf
        pos = 0
        while True:
            start = buf.find(MAGIC, pos)
            if start < 0:
                keep = max(pos, len(buf) - len(MAGIC) + 1)  # (a MAGIC may be split across feeds)
                self.skipped += keep - pos
                pos = keep
                break
            self.skipped += start - pos
            pos = start
            if len(buf) - pos < HEADER:
                break
            n = int.from_bytes(buf[pos + 3 : pos + 5], "big")
            end = pos + HEADER + n
            if n > MAX_DATAGRAM:
                pos += 1
                self.skipped += 1
                continue
            if end + len(MAGIC) > len(buf) and not (final and end <= len(buf)):
                break  # the frame, or the next one's MAGIC, is still to come
            if end < len(buf) and buf[end : end + len(MAGIC)] != MAGIC:
                pos += 1  # a damaged header or length: resynchronise at the next MAGIC
                self.skipped += 1
                continue
            self._datagram(bytes(buf[pos + HEADER : end]), ADDRESSES[buf[pos + 2] % len(ADDRESSES)])
            pos = end
        del buf[:pos]
        if final:
            self.skipped += len(buf)
            buf.clear()

    def _datagram(self, datagram: bytes, addr: tuple[str, int, str, int]) -> None:
        tracker = self.tracker
        classes = tracker.classes
        self.t += 1e-5
        known, events = classes[cl.XRCE][0] + classes[cl.RTPS][0], tracker.events_total
        tracker.feed_datagram(self.t, "udp", datagram, addr)
        flagged = False
        if tracker.events_total != events:  # (flags are events; most datagrams make none)
            flags = sum(tracker.flags.values())
            flagged, self._flags = flags != self._flags, flags
        if not flagged and classes[cl.XRCE][0] + classes[cl.RTPS][0] == known + 1:
            self.ok += 1
        else:
            self.bad += len(datagram)

    def finish(self) -> None:
        from hilbench.monitor.udp.summary import summary

        self._frames(final=True)
        self.tracker.finish()
        summary(self.tracker, source="fuzz", protocol="udp", timestamps=None)  # must survive whatever was tracked

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.skipped + self.bad


TRACKER = FuzzTarget("monitor-udp", "UDP monitor (classify, XRCE-DDS sessions, RTPS writers, flags)",
                        _DatagramReader, LINK_100M, "100 Mbit/s Ethernet link of 100-byte datagrams", udp_traffic,
                        kind="instrument")

__all__ = ["ADDRESSES", "MAGIC", "TRACKER", "datagrams", "udp_traffic"]
