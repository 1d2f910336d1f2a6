"""The kit of host-side laser-scanner drivers (real or emulated): open the connection, start scans, feed a tracker.

A :class:`ScannerConnection` is the byte pipe (a serial port or a TCP socket). A
driver (a :class:`ScannerDriver` subclass in its family's own module, e.g.
:class:`~hilbench.clients.rplidar.RplidarDriver`) speaks just enough of its
protocol to get scans flowing and to stop them again; every byte each way
goes to the tracker of the protocol's instrument (the one ``hilbench monitor``
uses, found through the registry), which decodes the scans, so ``hilbench
lidar`` and ``hilbench monitor`` count the same way::

    connection = ScannerConnection.open("/dev/ttyUSB0", baud=115200)
    drv = RplidarDriver(connection)
    drv.start()
    while drv.tracker.scans < 10:
        drv.pump(0.1)
    drv.stop()

A family makes its driver available to ``hilbench lidar`` with a
:class:`ScannerClient` registered in the ``hilbench.clients`` entry-point group.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, ClassVar

from hilbench import registry
from hilbench.clients.base import ClientDriver
from hilbench.errors import UsageError

if TYPE_CHECKING:
    from hilbench.monitor.scanners.tracker import ScannerTracker


class ScannerConnection:
    """A serial port (pyserial) or TCP socket, read and written in chunks."""

    def __init__(self, kind: str, handle, name: str) -> None:
        self.kind = kind
        self.handle = handle
        self.name = name

    @staticmethod
    def kind_of(target: str) -> str:
        """``"tcp"`` for ``tcp://HOST:PORT`` or ``HOST:PORT``, else ``"serial"``."""
        return "tcp" if target.startswith("tcp://") or (":" in target and not target.startswith("/")) else "serial"

    @classmethod
    def open(cls, target: str, baud: int | None = None) -> ScannerConnection:
        """``tcp://HOST:PORT`` or ``HOST:PORT`` opens a socket; anything else a serial port."""
        if cls.kind_of(target) == "tcp":
            host, _, port = target.removeprefix("tcp://").rpartition(":")
            sock = socket.create_connection((host or "127.0.0.1", int(port)), timeout=5)
            sock.settimeout(0.05)
            return cls("tcp", sock, f"tcp://{host}:{port}")
        import serial

        port = serial.Serial(target, baud or 115200, timeout=0.05)
        return cls("serial", port, target)

    def write(self, data: bytes) -> None:
        if self.kind == "tcp":
            self.handle.sendall(data)
        else:
            self.handle.write(data)

    def read(self, timeout: float = 0.05) -> bytes:
        if self.kind == "tcp":
            self.handle.settimeout(timeout)
            try:
                data = self.handle.recv(65536)
            except TimeoutError:
                return b""
            if not data:
                raise ConnectionError(f"{self.name}: the scanner closed the connection")
            return data
        self.handle.timeout = timeout
        first = self.handle.read(1)
        return first + self.handle.read(self.handle.in_waiting) if first else b""

    def set_baud(self, baud: int) -> None:
        if self.kind == "serial":
            self.handle.baudrate = baud

    def set_dtr(self, level: bool) -> bool:
        """Drive DTR; False where the port has no modem lines (a pty)."""
        if self.kind != "serial":
            return False
        try:
            self.handle.dtr = level
        except OSError as exc:
            if exc.errno in (errno.ENOTTY, errno.EINVAL):
                return False
            raise
        return True

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.handle.close()


class ScannerDriver:
    """Base: a connection, a tracker fed with both directions, start/stop."""

    #: The protocol it speaks: its tracker is that protocol's instrument's (``hilbench monitor``'s).
    protocol: ClassVar[str] = ""

    def __init__(self, connection: ScannerConnection, tracker: ScannerTracker | None = None) -> None:
        self.connection = connection
        self.tracker = tracker or self.new_tracker()

    def new_tracker(self) -> ScannerTracker:
        """A tracker of :attr:`protocol` from its registered instrument, with real times."""
        instrument = registry.instrument_for(self.protocol)
        if instrument is None:
            raise UsageError(f"no instrument decodes {self.protocol or 'this driver'}'s traffic")
        return instrument.make_tracker(baud=None, timestamps=True)

    def send(self, data: bytes) -> None:
        self.connection.write(data)
        self.tracker.feed(time.monotonic(), "app", data)

    def pump(self, timeout: float = 0.05) -> int:
        """Read what arrived (waiting up to ``timeout``) into the tracker; returns the byte count."""
        data = self.connection.read(timeout)
        if data:
            self.tracker.feed(time.monotonic(), "device", data)
        return len(data)

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.pump(0.02)
        return True

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError


class ScannerClient(ClientDriver):
    """A laser scanner's host side for ``hilbench lidar`` (role ``scanner``): subclasses name their
    :attr:`driver` and may add options (:meth:`~hilbench.clients.base.ClientDriver.add_arguments`) that
    :meth:`open` reads."""

    role = "scanner"
    #: The :class:`ScannerDriver` subclass it runs.
    driver: ClassVar[type[ScannerDriver]] = ScannerDriver
    #: Connection kinds (:meth:`~hilbench.clients.scanners.ScannerConnection.kind_of`: ``"serial"``, ``"tcp"``) whose scanner is taken to speak this
    #: protocol when nothing says which (no ``--protocol``, not a bench).
    default_on: ClassVar[tuple[str, ...]] = ()

    def open(self, connection: ScannerConnection, args: argparse.Namespace | None = None, *,
             set_dtr: Callable[[bool], None] | None = None) -> ScannerDriver:
        """A driver on ``connection`` with the verb's parsed options (None: the defaults). ``set_dtr`` sets the
        port's DTR where the connection cannot (a bench pty seen without ``hilbench run``'s shim)."""
        return self.driver(connection)


__all__ = ["ScannerClient", "ScannerDriver", "ScannerConnection"]
