"""Host-side drivers of laser scanners (real or emulated): open the link, start scans, feed a tracker.

A :class:`ScannerLink` is the byte pipe (a serial port or a TCP socket). A
driver (:class:`RplidarDriver`, :class:`SickDriver`, :class:`ScipDriver`)
speaks just enough of its protocol to get scans flowing and to stop them
again; every byte each way goes to a scanner tracker
(:mod:`hilbench.monitor.scanners.tracker`), which decodes the scans, so
``hilbench lidar`` and ``hilbench monitor`` count the same way::

    link = ScannerLink.open("/dev/ttyUSB0", baud=115200)
    drv = RplidarDriver(link)
    drv.start()
    while drv.tracker.scans < 10:
        drv.pump(0.1)
    drv.stop()
"""

from __future__ import annotations

import contextlib
import errno
import socket
import time
from collections.abc import Callable

from hilbench.errors import DeviceError
from hilbench.monitor.scanners.tracker import RplidarTracker, ScannerTracker, ScipTracker, SickTracker
from hilbench.protocols import rplidar as rp
from hilbench.protocols import scip
from hilbench.protocols import sick_lms200 as lms


class ScannerLink:
    """A serial port (pyserial) or TCP socket, read and written in chunks."""

    def __init__(self, kind: str, handle, name: str) -> None:
        self.kind = kind
        self.handle = handle
        self.name = name

    @classmethod
    def open(cls, target: str, baud: int | None = None) -> ScannerLink:
        """``tcp://HOST:PORT`` or ``HOST:PORT`` opens a socket; anything else a serial port."""
        if target.startswith("tcp://") or (":" in target and not target.startswith("/")):
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
    """Base: a link, a tracker fed with both directions, start/stop."""

    tracker_class: type[ScannerTracker] = ScannerTracker

    def __init__(self, link: ScannerLink, tracker: ScannerTracker | None = None) -> None:
        self.link = link
        self.tracker = tracker or self.tracker_class(timestamps=True)

    def send(self, data: bytes) -> None:
        self.link.write(data)
        self.tracker.feed(time.monotonic(), "app", data)

    def pump(self, timeout: float = 0.05) -> int:
        """Read what arrived (waiting up to ``timeout``) into the tracker; returns the byte count."""
        data = self.link.read(timeout)
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


class RplidarDriver(ScannerDriver):
    """GET_INFO, GET_HEALTH, motor on (DTR cleared), SCAN or EXPRESS_SCAN; STOP and motor off."""

    tracker_class = RplidarTracker

    def __init__(self, link: ScannerLink, tracker=None, *, express: bool = False,
                 motor: Callable[[bool], None] | None = None) -> None:
        super().__init__(link, tracker)
        self.express = express
        self.motor = motor  # how to reach DTR when the port has no modem lines (a bench pty)

    def _set_motor(self, on: bool) -> None:
        if not self.link.set_dtr(not on) and self.motor is not None:
            self.motor(on)

    def start(self) -> None:
        tr = self.tracker
        self.send(rp.request(rp.Cmd.GET_INFO))
        self.wait_for(lambda: bool(tr.device_info), 1.0)
        self.send(rp.request(rp.Cmd.GET_HEALTH))
        self.wait_for(lambda: tr.health != "unknown", 1.0)
        self._set_motor(True)
        if self.express:
            self.send(rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)))
        else:
            self.send(rp.request(rp.Cmd.SCAN))

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            self.send(rp.request(rp.Cmd.STOP))
            self._set_motor(False)


class SickDriver(ScannerDriver):
    """Find the unit's link speed, change it if asked (mode 40/41/48, then the port follows), continuous
    output; mode 25 and the power-up speed again when done.

    An LMS 200 keeps a speed it was switched to until power-off, so a host that left it at 38 400 baud
    (or died before switching back) finds it there next time. As real drivers do (sicktoolbox's
    ``SickLMS2xx::Initialize``), :meth:`find_baud` tries the speeds in turn with a status request (31)
    and takes the one that gets a good reply; :meth:`stop` switches back to 9600 as sicktoolbox's
    ``Uninitialize`` does.
    """

    tracker_class = SickTracker
    MODES = {v: k for k, v in lms.BAUD_MODES.items()}
    #: Link speeds an LMS 200 can run at, in the order they are tried (its power-up speed first).
    BAUDS = (lms.POWER_UP_BAUD, 38_400, 19_200, 500_000)
    #: How long a status request waits for its reply at each speed (the reply: 160 bytes, 170 ms at 9600).
    PROBE_TIMEOUT = 1.0

    def __init__(self, link: ScannerLink, tracker=None, *, baud: int = 9600) -> None:
        super().__init__(link, tracker)
        self.baud = baud
        #: The speed the unit runs at now, once known.
        self.session_baud: int | None = None

    def answers_at(self, baud: int, timeout: float | None = None) -> bool:
        """Whether the unit answers a status request at ``baud`` (the port is left at ``baud``).

        The exchange is kept from the tracker: at a wrong speed a real unit's bytes are noise.
        """
        self.link.set_baud(baud)
        with contextlib.suppress(OSError):
            while self.link.read(0.0):  # what came at the old speed
                pass
        dec = lms.Decoder(handshakes=True)
        self.link.write(lms.request(lms.Cmd.STATUS))
        deadline = time.monotonic() + (self.PROBE_TIMEOUT if timeout is None else timeout)
        while time.monotonic() < deadline:
            for item in dec.feed(self.link.read(0.02)):
                # a status reply, or the scans of a unit left streaming at this speed
                if isinstance(item, lms.Frame) and item.is_reply and item.cmd in (0xB1, 0xB0):
                    return True
        return False

    def find_baud(self) -> int:
        """The unit's link speed (tried as :attr:`BAUDS` says, the asked-for one second); a
        :class:`~hilbench.errors.DeviceError` saying what was tried when none answers."""
        tried = list(dict.fromkeys((self.BAUDS[0], self.baud, *self.BAUDS)))
        for baud in tried:
            if self.answers_at(baud):
                self.session_baud = baud
                return baud
        raise DeviceError(f"{self.link.name}: no LMS 200 answers a status request at "
                          f"{', '.join(map(str, tried))} baud (is it powered, on this port, and not used by "
                          f"another program?)")

    def _switch(self, baud: int, wait: float = 2.0) -> bool:
        tr = self.tracker
        replies = tr.replies
        self.send(lms.mode_request(self.MODES[baud]))
        ok = self.wait_for(lambda: tr.replies > replies, wait)
        self.link.set_baud(baud)  # the reply came at the old speed; the LMS now runs at the new
        self.session_baud = baud
        return ok

    def start(self) -> None:
        if self.link.kind == "serial":
            self.find_baud()
        else:  # a serial server on TCP: its own port has the speed
            self.session_baud = self.baud
        if self.session_baud != self.baud:
            self._switch(self.baud)
        self.send(lms.mode_request(lms.Mode.CONTINUOUS))

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            tr = self.tracker
            replies = tr.replies
            self.send(lms.mode_request(lms.Mode.POLLED))
            if self.session_baud not in (None, lms.POWER_UP_BAUD) and self.link.kind == "serial":
                self.wait_for(lambda: tr.replies > replies, 1.0)
                self._switch(lms.POWER_UP_BAUD, wait=1.0)


class ScipDriver(ScannerDriver):
    """PP (the unit's steps), BM, MD over the whole field; QT stops."""

    tracker_class = ScipTracker

    def start(self) -> None:
        tr = self.tracker
        replies = tr.replies
        self.send(b"PP\n")
        self.wait_for(lambda: tr.replies > replies, 2.0)
        p = tr.params
        self.send(b"BM\n")
        self.send(scip.request("MD", {"start": p["AMIN"], "end": p["AMAX"], "cluster": 0, "skip": 0, "scans": 0}))

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            self.send(b"QT\n")


DRIVERS = {"rplidar": RplidarDriver, "sick-lms200": SickDriver, "scip2": ScipDriver}

__all__ = ["DRIVERS", "RplidarDriver", "ScannerDriver", "ScannerLink", "ScipDriver", "SickDriver"]
