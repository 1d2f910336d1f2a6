"""Byte streams an instrument reads from: a file, stdin, a serial port, or a UDP port.

:func:`open_stream` turns a source string into a :class:`ByteStream`:

=====================================  ==============================================================
``trace.txt``, ``capture.bin``         a file, read to its end (not live)
``-``                                  stdin (live when it is a pipe or a terminal)
``/dev/ttyACM0``, a pty path           a serial port opened with pyserial in raw mode at ``baud``
``serial:///dev/ttyACM0?baud=N``       the same with the baud rate in the URL
``udp://127.0.0.1:PORT``               bind that address and receive datagrams (``udp://:PORT``
                                       binds 127.0.0.1); ``?peer=HOST:PORT`` also announces this
                                       socket to a board there (an empty datagram, repeated
                                       until data arrives), as the emulated board expects
=====================================  ==============================================================

``read(timeout)`` returns the bytes available (waiting up to ``timeout``
seconds for the first), ``b""`` when nothing came, and ``None`` at the end of
a file or pipe. Everything is receive-only: a profiler never writes to the
board's port.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import stat
import sys
import time
from pathlib import Path
from urllib.parse import parse_qs, urlparse

READ_SIZE = 1 << 20


class StreamError(ValueError):
    """A source string that cannot be opened; the message is one line."""


class ByteStream:
    """Base: ``name``, ``live`` (data arrives as it happens), :meth:`read`, :meth:`close`."""

    name = "stream"
    live = True

    def read(self, timeout: float = 0.1) -> bytes | None:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> ByteStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class FileStream(ByteStream):
    """A regular file (not live), or stdin / a FIFO (live): read until the end."""

    def __init__(self, path: str) -> None:
        self.name = path
        if path == "-":
            self.fd = sys.stdin.buffer.fileno()
            self._own = False
            self.name = "stdin"
        else:
            try:
                self.fd = os.open(path, os.O_RDONLY)
            except FileNotFoundError:
                raise StreamError(f"{path}: no such file, port or source") from None
            self._own = True
        self.live = not stat.S_ISREG(os.fstat(self.fd).st_mode)

    def read(self, timeout: float = 0.1) -> bytes | None:
        if self.live and not select.select([self.fd], [], [], timeout)[0]:
            return b""
        data = os.read(self.fd, READ_SIZE)
        return data if data else None

    def close(self) -> None:
        if self._own:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self._own = False


class SerialStream(ByteStream):
    """A serial port (real or a pty) through :class:`~hilbench.transports.host_link.HostLink`."""

    def __init__(self, port: str, baud: int) -> None:
        from hilbench.transports.host_link import HostLink

        self.name = port
        self.baud = baud
        try:
            self.link = HostLink.open(port, baud)
        except (OSError, ValueError) as exc:
            raise StreamError(f"cannot open {port}: {exc}") from None

    def read(self, timeout: float = 0.1) -> bytes | None:
        try:
            return self.link.read(timeout)
        except OSError as exc:  # the port went away (USB unplugged, bench stopped)
            raise StreamError(f"{self.name}: {exc}") from None

    def close(self) -> None:
        self.link.close()


class UdpReceiver(ByteStream):
    """A bound UDP socket: every datagram's payload, in arrival order.

    With ``peer``, an empty datagram announces this socket to a board that
    streams to whoever registers (hilbench's emulated board does); it is
    repeated every ``announce_s`` seconds until data arrives.
    """

    def __init__(self, host: str, port: int, *, peer: tuple[str, int] | None = None,
                 announce_s: float = 0.5) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise StreamError(f"cannot bind udp://{host}:{port}: {exc.strerror or exc}") from None
        self.sock.setblocking(False)
        self.peer = peer
        self.announce_s = announce_s
        self._announced = 0.0
        self._heard = False
        self.datagrams = 0
        h, p = self.sock.getsockname()[:2]
        self.address = (h, p)
        self.name = f"udp://{h}:{p}"
        self._announce()

    def _announce(self) -> None:
        if self.peer is not None and not self._heard:
            now = time.monotonic()
            if now - self._announced >= self.announce_s:
                self._announced = now
                with contextlib.suppress(OSError):
                    self.sock.sendto(b"", self.peer)

    def read(self, timeout: float = 0.1) -> bytes | None:
        self._announce()
        if not select.select([self.sock], [], [], timeout)[0]:
            return b""
        out = []
        while True:
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # an ICMP error for the announcement: nobody there yet
                break
            self.datagrams += 1
            out.append(data)
        if out:
            self._heard = True
        return b"".join(out)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


def _host_port(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise StreamError(f"{what}: expected HOST:PORT, got {text!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def open_stream(spec: str, *, baud: int | None = None, default_baud: int = 115_200) -> ByteStream:
    """Open a source string (see the module docstring); raises :class:`StreamError` with one line."""
    if spec == "-":
        return FileStream("-")
    url = urlparse(spec)
    if url.scheme == "udp":
        host, port = _host_port(url.netloc, spec)
        peer = None
        q = parse_qs(url.query)
        if "peer" in q:
            peer = _host_port(q["peer"][0], f"{spec}: peer")
        return UdpReceiver(host, port, peer=peer)
    if url.scheme == "serial":
        q = parse_qs(url.query)
        if "baud" in q:
            try:
                baud = int(q["baud"][0])
            except ValueError:
                raise StreamError(f"{spec}: baud must be an integer") from None
        return SerialStream(url.path or url.netloc, baud or default_baud)
    if url.scheme and len(url.scheme) > 1 and url.scheme not in ("file",):
        raise StreamError(f"{spec}: unknown source scheme {url.scheme!r} (use a path, -, serial:// or udp://)")
    path = url.path if url.scheme == "file" else spec
    p = Path(path)
    if not p.exists():
        raise StreamError(f"{path}: no such file, port or source")
    if stat.S_ISCHR(os.stat(p).st_mode):
        return SerialStream(str(p), baud or default_baud)
    return FileStream(str(p))
