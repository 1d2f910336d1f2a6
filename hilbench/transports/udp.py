"""A UDP endpoint: a bound socket acting as one host port (on a serial line, or on a datagram net).

:class:`UdpPort` has the pty endpoint's interface (``fileno``, ``read``,
``write``, ``client_baud``, ``close``), so a
:class:`~hilbench.transports.serial_medium.SerialMedium` carries it like a
host port, with the same taps. Each datagram a host sends is one write on
the line (e.g. one 28-byte velocity frame); what the device sends goes out as
datagrams to every peer: the fixed ``peer`` of the profile, if any, and the
most recent senders (a host registers by sending anything, even an empty
datagram). It binds 127.0.0.1 unless told otherwise.

On a :class:`~hilbench.transports.datagram_medium.DatagramMedium` the same port
keeps datagrams whole and addressed: :meth:`UdpPort.recv_from` gives each
with its sender, :meth:`UdpPort.send_to` answers one address.
"""

from __future__ import annotations

import contextlib
import socket
from collections import OrderedDict
from typing import Any

from hilbench.errors import OptionError
from hilbench.transports.channel_book import UDP
from hilbench.transports.host_port import HostPort, bind_address, port_number
from hilbench.transports.listener import bind as bind_socket

#: Largest payload sent in one datagram; longer writes are split.
MAX_DATAGRAM = 8192
#: How many recent senders receive the output.
MAX_PEERS = 8


def parse_address(text: str) -> tuple[str, int]:
    """``"host:port"`` or ``"udp://host:port"`` to ``(host, port)``; raises ValueError."""
    if text.startswith("udp://"):
        text = text[6:]
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"expected udp://HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


class UdpPort(HostPort):
    """A bound UDP socket acting as one host port; see the module docstring.

    Profile keys: ``bind`` (default 127.0.0.1), ``port`` (0: any free port),
    ``peer`` (``"host:port"`` that always receives the output).
    """

    kind = "udp"
    carries = "datagrams"
    profile_keys = {"bind": "127.0.0.1", "port": 0, "peer": None}

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        peer = raw.get("peer")
        if peer is not None:
            try:
                if not isinstance(peer, str):
                    raise ValueError
                parse_address(peer)  # what the endpoint will parse: the rules live in one place
            except ValueError:
                raise OptionError("peer", f"expected \"host:port\", got {peer!r}") from None
        return {"bind": bind_address(raw.get("bind", "127.0.0.1")), "port": port_number(raw.get("port", 0)),
                "peer": peer}

    @classmethod
    def open(cls, name: str, options: dict[str, Any], **_: Any) -> UdpPort:
        return cls(name, options["bind"], options["port"], options["peer"])

    def describe(self) -> dict[str, Any]:
        host, port = self.address
        # "pty" and "link" stay (as None) for manifest readers written before ports were plug-ins.
        return {"path": self.url, "pty": None, "link": None, "address": [host, port], "host": host, "port": port,
                "counters": self.counters()}

    def counters(self) -> dict[str, int]:
        """Traffic and losses: datagrams and bytes in, bytes out, bytes the socket refused to send, the peers
        receiving the output (at most :data:`MAX_PEERS`, the most recent senders)."""
        return {"datagrams_in": self.datagrams_in, "bytes_in": self.bytes_in, "bytes_out": self.bytes_out,
                "dropped_bytes": self.dropped, "peers": len(self.peers), "max_peers": MAX_PEERS}

    def __init__(self, name: str = "udp", bind: str = "127.0.0.1", port: int = 0, peer: str | None = None) -> None:
        self.name = name
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        bind_socket(self.sock, (bind, port), "UDP port")  # BindError: taken, or not this machine's address
        self.sock.setblocking(False)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        # Room for bursts while the medium's thread is busy (the kernel drops what does not fit).
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.fixed_peer = parse_address(peer) if peer else None
        self.peers: OrderedDict[tuple[str, int], None] = OrderedDict()
        self.bytes_in = 0
        self.bytes_out = 0
        self.datagrams_in = 0
        self.dropped = 0  #: bytes a full socket buffer refused
        self.book: Any = None  # a virtual bench's ChannelBook: datagrams per client address

    def vt_channels(self, book: Any) -> None:
        """Virtual time: count datagrams in and out per address in ``book`` (the lockstep's channels)."""
        self.book = book
        book.door(UDP, self.address, self)

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()[:2]

    @property
    def url(self) -> str:
        host, port = self.address
        return f"udp://{host}:{port}"

    @property
    def client_path(self) -> str:
        return self.url

    def fileno(self) -> int:
        return self.sock.fileno()

    def client_baud(self) -> int | None:
        return None  # datagrams have no line rate

    def read(self, size: int = 65536) -> bytes:
        """One datagram's payload (b'' if none is waiting, or for an empty registration datagram). ``size``, a
        pty's read size (a serial line's), does not cut a datagram: it is read whole."""
        try:
            data, addr = self.sock.recvfrom(65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # e.g. ICMP port unreachable reported on a later call
            return b""
        if self.book is not None:
            self.book.took(UDP, addr, 1)
        self.peers.pop(addr, None)
        self.peers[addr] = None
        while len(self.peers) > MAX_PEERS:
            self.peers.popitem(last=False)
        self.datagrams_in += 1
        self.bytes_in += len(data)
        return data

    def recv_from(self) -> tuple[bytes, tuple[str, int]] | None:
        """One datagram and its sender (None if none is waiting); a datagram net reads this way."""
        try:
            data, addr = self.sock.recvfrom(65536)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:  # ICMP port unreachable from an earlier send: nothing to read
            return None
        self.datagrams_in += 1
        self.bytes_in += len(data)
        if self.book is not None:
            self.book.took(UDP, addr, 1)
        return data, addr[:2]

    def send_to(self, data: bytes, addr: tuple[str, int]) -> bool:
        """Send one datagram to ``addr``; False (counted in :attr:`dropped`) if the socket refused it or
        the address is not one (a port outside 0..65535: OverflowError)."""
        try:
            self.sock.sendto(data, addr)
        except (OSError, OverflowError, ValueError, TypeError):
            self.dropped += len(data)
            return False
        self.bytes_out += len(data)
        if self.book is not None:
            self.book.sent(UDP, addr, 1)
        return True

    def targets(self) -> list[tuple[str, int]]:
        out = list(self.peers)
        if self.fixed_peer and self.fixed_peer not in self.peers:
            out.append(self.fixed_peer)
        return out

    def write(self, data: bytes) -> int:
        """Send ``data`` to every peer (split into datagrams of at most :data:`MAX_DATAGRAM` bytes)."""
        sent = 0
        for addr in self.targets():
            for i in range(0, len(data), MAX_DATAGRAM):
                chunk = data[i : i + MAX_DATAGRAM]
                try:
                    self.sock.sendto(chunk, addr)
                    sent += len(chunk)
                    if self.book is not None:
                        self.book.sent(UDP, addr, 1)
                except (BlockingIOError, InterruptedError):
                    self.dropped += len(chunk)
                except OSError:
                    self.dropped += len(chunk)
        self.bytes_out += sent
        return sent

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()

    def __enter__(self) -> UdpPort:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"UdpPort({self.name!r}, {self.url})"
