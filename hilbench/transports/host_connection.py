"""A host program's end of a board connection: a serial port (real or emulated) or a UDP address.

``HostConnection.open("/dev/ttyACM0", 115200)`` opens a serial port with pyserial
in raw mode, as the ROS bridge ``vel2d_bridge`` does; ``HostConnection.open(
"udp://127.0.0.1:9000")`` talks to a board endpoint over UDP (the first
datagram sent registers this socket for the board's output). :meth:`~HostConnection.send`
writes one message with one write and waits until it has left (tcdrain),
like the bridge; :meth:`~HostConnection.read` returns whatever the board sent.
"""

from __future__ import annotations

import contextlib
import socket

from hilbench.transports.readiness import readable
from hilbench.transports.udp import parse_address


class HostConnection:
    """See the module docstring. Use :meth:`open`."""

    def __init__(self, port: str, *, serial_port=None, sock: socket.socket | None = None) -> None:
        self.port = port
        self._serial = serial_port
        self._sock = sock

    @classmethod
    def open(cls, port: str, baud: int = 115_200) -> HostConnection:
        """Open ``port``: a serial device path or ``udp://HOST:PORT``; raises OSError or ValueError
        (:class:`~hilbench.transports.serial_url.NotAPort` for a file)."""
        if port.startswith("udp://"):
            host, udp_port = parse_address(port)
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.connect((host, udp_port))
            sock.setblocking(False)
            return cls(port, sock=sock)
        import serial

        from hilbench.transports.serial_url import check_port

        check_port(port)  # (a file: NotAPort, a usage error)
        try:
            ser = serial.Serial(port, baud, timeout=0, write_timeout=5)
        except serial.SerialException as exc:
            raise OSError(str(exc)) from None
        return cls(port, serial_port=ser)

    @property
    def is_udp(self) -> bool:
        return self._sock is not None

    def fileno(self) -> int:
        return self._sock.fileno() if self._sock is not None else self._serial.fileno()

    def send(self, data: bytes) -> None:
        """One write of ``data``, then wait until it is on the line."""
        if self._sock is not None:
            self._sock.send(data)
            return
        self._serial.write(data)
        self._serial.flush()  # tcdrain

    def register(self) -> None:
        """UDP: announce this socket to the board so it receives the output stream (no-op on serial)."""
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.send(b"")

    def read(self, timeout: float = 0.0) -> bytes:
        """Bytes the board sent, waiting up to ``timeout`` seconds for the first of them."""
        fd = self.fileno()
        if timeout > 0 and not readable([fd], timeout):
            return b""
        if self._sock is not None:
            out = []
            while True:
                try:
                    out.append(self._sock.recv(65536))
                except (BlockingIOError, InterruptedError):
                    break
                except ConnectionRefusedError:  # nobody listens yet (ICMP); nothing to read
                    break
            return b"".join(out)
        n = self._serial.in_waiting
        return self._serial.read(n) if n else b""

    def close(self) -> None:
        with contextlib.suppress(Exception):
            if self._sock is not None:
                self._sock.close()
            if self._serial is not None:
                self._serial.close()

    def __enter__(self) -> HostConnection:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
