"""pcap and pcapng: UDP datagrams to and from the files Wireshark and tcpdump read and write (with dpkt).

:class:`PcapReader` yields each UDP datagram of a pcap or pcapng file as a
:class:`~hilbench.transports.chunk.Chunk` with its addresses, stamped with
the packet's Unix time; it understands Ethernet (with VLAN tags), Linux
cooked captures (``tcpdump -i any``, SLL and SLL2), BSD loopback and raw IP
link types, IPv4 and IPv6. Everything else (TCP, ARP, IP fragments after the
first) is skipped and counted.

:class:`PcapWriter` writes datagrams as Ethernet II + IPv4 (or IPv6) + UDP
frames with correct lengths and checksums, so Wireshark's RTPS dissector
decodes what hilbench recorded and a frame is 42 bytes longer than its UDP
payload (the sheet's 106- and 112-byte frames, udp.md §2.7). MAC addresses are
made up from the IPv4 address (``02:00`` + its four octets).
"""

from __future__ import annotations

import ipaddress
import os
import sys
from collections.abc import Iterator
from typing import Any, BinaryIO

from hilbench.transports.chunk import CaptureError, Chunk

PCAP_MAGICS = {b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d"}
PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"
SUFFIXES = (".pcap", ".pcapng", ".cap")
# Link types (pcap LINKTYPE_*).
LINK_NULL, LINK_ETHERNET, LINK_RAW, LINK_LOOP, LINK_SLL, LINK_SLL2, LINK_IPV4, LINK_IPV6 = 0, 1, 101, 108, 113, 276, \
    228, 229


def is_pcap(head: bytes) -> bool:
    """Whether the first bytes of a file are a pcap or pcapng magic."""
    return head[:4] in PCAP_MAGICS or head[:4] == PCAPNG_MAGIC


class PcapReader:
    """UDP datagrams of a pcap/pcapng file (path, ``-`` or binary file); see the module docstring."""

    def __init__(self, target: str | os.PathLike[str] | BinaryIO) -> None:
        import dpkt  # (here, not at the top: the recorder plug-in is loaded for every monitor's --help)

        self.name = str(target) if isinstance(target, str | os.PathLike) else getattr(target, "name", "pcap")
        if isinstance(target, str | os.PathLike):
            self._f = sys.stdin.buffer if str(target) == "-" else open(target, "rb")  # noqa: SIM115
            self._owned = str(target) != "-"
        else:
            self._f, self._owned = target, False
        head = self._f.read(4)
        if not is_pcap(head):
            self.close()
            raise CaptureError(f"{self.name}: not a pcap or pcapng file")
        import io

        stream = io.BufferedReader(_Prefixed(head, self._f))  # dpkt reads the magic itself
        try:
            self._reader = dpkt.pcapng.Reader(stream) if head == PCAPNG_MAGIC else dpkt.pcap.Reader(stream)
        except (ValueError, dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError) as exc:
            self.close()
            raise CaptureError(f"{self.name}: unreadable pcap header: {exc}") from None
        self.linktype = self._reader.datalink()
        self.packets = 0
        self.datagrams = 0
        self.skipped = 0
        self.fragments = 0

    def __iter__(self) -> Iterator[Chunk]:
        import dpkt

        link = self.linktype
        try:
            for ts, buf in self._reader:
                self.packets += 1
                chunk = self._datagram(float(ts), buf, link)
                if chunk is None:
                    self.skipped += 1
                    continue
                self.datagrams += 1
                yield chunk
        except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, ValueError):
            return  # a capture cut short: what was read stands

    def _datagram(self, ts: float, buf: bytes, link: int) -> Chunk | None:
        import dpkt

        try:
            if link == LINK_ETHERNET:
                ip = dpkt.ethernet.Ethernet(buf).data
            elif link == LINK_SLL:
                ip = dpkt.sll.SLL(buf).data
            elif link == LINK_SLL2:
                ip = dpkt.sll2.SLL2(buf).data
            elif link in (LINK_NULL, LINK_LOOP):
                ip = dpkt.loopback.Loopback(buf).data
            elif link in (LINK_RAW, LINK_IPV4, LINK_IPV6, 12, 14):
                ip = dpkt.ip6.IP6(buf) if buf and buf[0] >> 4 == 6 else dpkt.ip.IP(buf)
            else:
                return None
        except (dpkt.dpkt.UnpackError, dpkt.dpkt.NeedData, ValueError, IndexError):
            return None
        if isinstance(ip, dpkt.ip.IP):
            if ip.p != dpkt.ip.IP_PROTO_UDP:
                return None
            if getattr(ip, "offset", 0):
                self.fragments += 1
                return None
            src, dst = str(ipaddress.IPv4Address(ip.src)), str(ipaddress.IPv4Address(ip.dst))
        elif isinstance(ip, dpkt.ip6.IP6):
            if ip.nxt != dpkt.ip.IP_PROTO_UDP:
                return None
            src, dst = str(ipaddress.IPv6Address(ip.src)), str(ipaddress.IPv6Address(ip.dst))
        else:
            return None
        udp = ip.data
        if not isinstance(udp, dpkt.udp.UDP):
            return None
        data = bytes(udp.data)
        return Chunk(ts, f"udp:{src}:{udp.sport}", data, 0, (src, udp.sport, dst, udp.dport))

    def close(self) -> None:
        if self._owned:
            self._f.close()


class _Prefixed:
    """A raw stream that gives back bytes already read from it first (for io.BufferedReader)."""

    def __init__(self, head: bytes, f: BinaryIO) -> None:
        self._head = head
        self._f = f
        self.closed = False

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:  # noqa: ANN001 (io protocol)
        if self._head:
            n = min(len(b), len(self._head))
            b[:n] = self._head[:n]
            self._head = self._head[n:]
            return n
        data = self._f.read(len(b))
        b[:len(data)] = data
        return len(data)

    def close(self) -> None:
        self.closed = True


def _mac(host: str) -> bytes:
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return b"\x02\x00\x00\x00\x00\x00"
    return b"\x02\x00" + (ip.packed if ip.version == 4 else ip.packed[-4:])


def frame(data: bytes, addr: tuple[str, int, str, int]) -> bytes:
    """An Ethernet II frame carrying ``data`` as a UDP datagram between ``addr``'s endpoints."""
    import dpkt

    src, sport, dst, dport = addr
    udp = dpkt.udp.UDP(sport=sport, dport=dport, data=data)
    udp.ulen = 8 + len(data)
    s_ip, d_ip = ipaddress.ip_address(src), ipaddress.ip_address(dst)
    if s_ip.version == 4 and d_ip.version == 4:
        ip = dpkt.ip.IP(src=s_ip.packed, dst=d_ip.packed, p=dpkt.ip.IP_PROTO_UDP, ttl=64, data=udp)
        ip.len = 20 + udp.ulen
        eth_type = dpkt.ethernet.ETH_TYPE_IP
    else:
        def v6(a: ipaddress._BaseAddress) -> bytes:
            return a.packed if a.version == 6 else ipaddress.IPv6Address(b"\0" * 10 + b"\xff\xff" + a.packed).packed

        ip = dpkt.ip6.IP6(src=v6(s_ip), dst=v6(d_ip), nxt=dpkt.ip.IP_PROTO_UDP, hlim=64, data=udp, plen=udp.ulen)
        eth_type = dpkt.ethernet.ETH_TYPE_IP6
    eth = dpkt.ethernet.Ethernet(src=_mac(src), dst=_mac(dst), type=eth_type, data=ip)
    return bytes(eth)


class PcapWriter:
    """Writes addressed datagrams as a pcap (or, for a ``.pcapng`` name or ``ng=True``, pcapng) file.

    ``offset`` turns a chunk's time into Unix time (``t + offset``): 0 for Unix
    times, ``t0_wall - t0_monotonic`` for a recording's monotonic times. A chunk
    without addresses (serial bytes) cannot be a UDP frame: :class:`CaptureError`.
    A file named by its path is created at the first datagram (or at
    :meth:`close`), so a recording refused at its first chunk leaves no file.
    """

    def __init__(self, target: str | os.PathLike[str] | BinaryIO, *, offset: float = 0.0, ng: bool | None = None,
                 description: str = "") -> None:
        name = str(target) if isinstance(target, str | os.PathLike) else getattr(target, "name", "pcap")
        self._target = target
        self._f: BinaryIO | None = None
        self._owned = False
        if not isinstance(target, str | os.PathLike):
            self._f = target
        elif str(target) == "-":
            self._f = sys.stdout.buffer
        self.name = name
        self.ng = name.lower().endswith(".pcapng") if ng is None else ng
        self.offset = offset
        self._w: Any = None
        self._closed = False
        self.records = 0
        self.bytes = 0
        self.gaps = 0

    def _writer(self) -> Any:
        """The dpkt writer (its file created, and its header written, on first use)."""
        import dpkt

        if self._w is None:
            if self._f is None:
                self._f = open(self._target, "wb")  # noqa: SIM115 (closed by close())
                self._owned = True
            if self.ng:
                self._w = dpkt.pcapng.Writer(self._f, snaplen=65535, linktype=dpkt.pcap.DLT_EN10MB)
            else:
                self._w = dpkt.pcap.Writer(self._f, snaplen=65535, linktype=dpkt.pcap.DLT_EN10MB, nano=True)
        return self._w

    def chunk(self, chunk: Chunk) -> None:
        """Store one datagram (a loss report is counted only: pcap has no record for it)."""
        if chunk.lost:
            self.gaps += chunk.lost
            return
        if chunk.addr is None:
            raise CaptureError(f"{self.name}: {chunk.source} is not UDP traffic (no addresses): pcap and pcapng "
                               "hold datagrams; record it to a .hbcap file instead")
        self.write(chunk.t, chunk.data, chunk.addr)

    def write(self, t: float, data: bytes, addr: tuple[str, int, str, int]) -> None:
        self._writer().writepkt(frame(data, addr), ts=t + self.offset)
        self.records += 1
        self.bytes += len(data)

    def flush(self) -> None:
        """Hand what was written to the system; a failed write (disk full) raises :class:`OSError`."""
        if self._f is not None and not self._f.closed:
            self._f.flush()

    def close(self) -> None:
        """Finish the file (a recording of nothing still gets its header)."""
        if self._closed:
            return
        self._closed = True
        self._writer()
        assert self._f is not None
        try:
            self.flush()
        finally:
            if self._owned:
                self._f.close()

    def __enter__(self) -> PcapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PcapFormat:
    """The recorder plug-in (``hilbench.recorders`` entry point ``pcap``): ``hilbench record SOURCE x.pcapng``."""

    name = "pcap"
    suffixes = SUFFIXES

    def accepts(self, path: str, protocol: str | None) -> bool:
        return str(path).lower().endswith(self.suffixes)

    def open(self, path: str, *, source: Any, description: str = "") -> PcapWriter:
        import time

        offset = getattr(source, "wall_offset", None)  # 0.0 for sources stamped in Unix time (a pcap's)
        if offset is None:
            info = getattr(getattr(source, "reader", None), "info", None) or \
                getattr(getattr(source, "parser", None), "info", None)
            if info is not None and info.measured and info.t0_wall:
                offset = info.t0_wall - info.t0_monotonic  # a hilbench capture or tap: its clock's Unix time
            else:
                offset = time.time() - time.monotonic()  # live sources stamp with the monotonic clock
        return PcapWriter(path, offset=offset, description=description)


RECORDER = PcapFormat()

__all__ = ["PCAPNG_MAGIC", "PCAP_MAGICS", "RECORDER", "SUFFIXES", "PcapFormat", "PcapReader", "PcapWriter", "frame",
           "is_pcap"]
