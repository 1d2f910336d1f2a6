"""The CAN host port (endpoint ``type = "can"``): one emulated bus, several doors for host programs.

A real CAN bus is reached through whatever adapter a tool speaks, so one CAN
endpoint opens every door at once, each a party on the same emulated bus
(:class:`~hilbench.transports.can_medium.CanMedium`):

===================  ======================================================  =====================================
profile key          door                                                    who uses it
===================  ======================================================  =====================================
``socketcand``       socketcand server on 127.0.0.1 (default: on, port 0,    python-can ``socketcand``, can.viewer,
                     channel ``can0``):                                      can.logger, cantools monitor, canopen,
                     :mod:`~hilbench.transports.socketcand_server`           (SavvyCAN: untested)
``slcan``            LAWICEL adapter on a pty (default: on; a path makes a   python-can ``slcan``, cantools monitor
                     stable link): :mod:`~hilbench.transports.slcan_port`    (slcand, SavvyCAN: untested)
``virtual``          python-can ``virtual`` channel (default: off; also      code in the bench's own process
                     opened on demand by ``open_bus()``)
``socketcan``        a kernel interface such as ``vcan0`` (default: off);    can-utils, Wireshark, everything
                     skipped, with the reason in the manifest, where the     SocketCAN
                     kernel has no AF_CAN
===================  ======================================================  =====================================

Profile form::

    [endpoints.can]
    type = "can"
    protocol = "can"
    bitrate = 500_000
    socketcand = { port = 0, bind = "127.0.0.1", channel = "can0", beacon = false }   # or false
    slcan = true               # or "~/robot/slcan0" (a stable link), or false
    virtual = "rover-bus"      # or false
    socketcan = "vcan0"        # or false

The manifest lists ``socketcand`` (``host``, ``port``, ``channel``),
``slcan`` (the pty), ``virtual`` and ``socketcan`` (each None when closed;
``socketcan_error`` says why SocketCAN was skipped), and ``path``: the
socketcand URL that ``hilbench monitor`` opens.
"""

from __future__ import annotations

import logging
import os
import threading
import uuid
from pathlib import Path
from typing import Any

from hilbench.errors import OptionError
from hilbench.protocols import socketcand as sc
from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.host_port import HostPort, bind_address, port_number
from hilbench.transports.listener import BindError

log = logging.getLogger(__name__)

SOCKETCAND_KEYS = {"port": 0, "bind": "127.0.0.1", "channel": "can0", "beacon": False, "rawmode_delay_ms": 100}


def _socketcand_options(value: Any) -> dict[str, Any] | None:
    if value is False:
        return None
    if value is True or value is None:
        value = {}
    if not isinstance(value, dict):
        raise OptionError("socketcand", f"expected a table (port, bind, channel, beacon) or false, got {value!r}")
    for key in value:
        if key not in SOCKETCAND_KEYS:
            raise OptionError(f"socketcand.{key}", f"unknown key (expected one of: {', '.join(SOCKETCAND_KEYS)})")
    out = {**SOCKETCAND_KEYS, **value}
    out["port"] = port_number(out["port"], "socketcand.port")
    out["bind"] = bind_address(out["bind"], "socketcand.bind")
    channel = out["channel"]
    if not isinstance(channel, str) or not 0 < len(channel) <= sc.MAX_BUS_NAME or " " in channel:
        raise OptionError("socketcand.channel", f"expected a bus name of 1..{sc.MAX_BUS_NAME} characters without "
                                                f"spaces, got {channel!r}")
    if not isinstance(out["beacon"], bool):
        raise OptionError("socketcand.beacon", f"expected true or false, got {out['beacon']!r}")
    delay = out["rawmode_delay_ms"]
    if isinstance(delay, bool) or not isinstance(delay, int | float) or not 0 <= delay <= 5000:
        raise OptionError("socketcand.rawmode_delay_ms", f"expected 0..5000, got {delay!r}")
    return out


def _name_option(value: Any, key: str, *, allow_true: bool) -> Any:
    if value is False or value is None:
        return None
    if value is True and allow_true:
        return True
    if isinstance(value, str) and value:
        return value
    extra = "true, " if allow_true else ""
    raise OptionError(key, f"expected {extra}a name string or false, got {value!r}")


class CanPort(HostPort):
    """Every door of one CAN endpoint; a :class:`~hilbench.transports.can_medium.CanMedium` carries it."""

    kind = "can"
    carries = "frames"
    profile_keys = {"socketcand": {}, "slcan": True, "virtual": None, "socketcan": None}

    def __init__(self, name: str = "can", *, socketcand: dict[str, Any] | None = None, slcan: Any = True,
                 virtual: str | None = None, socketcan: str | None = None) -> None:
        self.name = name
        self.doors: list[Any] = []
        self.socketcand = None
        self.slcan = None
        self.virtual = None
        self.socketcan = None
        self.socketcan_error: str | None = None
        self._medium: Any = None
        self._lock = threading.Lock()
        try:
            if socketcand is not None:
                from hilbench.transports.socketcand_server import SocketcandServer

                try:
                    self.socketcand = SocketcandServer(name, bind=socketcand["bind"], port=socketcand["port"],
                                                       channel=socketcand["channel"], beacon=socketcand["beacon"],
                                                       rawmode_delay=socketcand["rawmode_delay_ms"] / 1000)
                except BindError as exc:  # the profile keys that chose the address
                    exc.what = "socketcand server (TCP port)"
                    exc.key = "socketcand.port" if exc.port_taken else "socketcand.bind"
                    raise
                self.doors.append(self.socketcand)
            if slcan:
                from hilbench.transports.slcan_port import SlcanAdapter

                link = os.path.expanduser(slcan) if isinstance(slcan, str) else None
                self.slcan = SlcanAdapter(name, link=link)
                self.doors.append(self.slcan)
            if virtual:
                self.open_virtual(virtual)
            if socketcan:
                from hilbench.transports.socketcan import SocketCanDoor

                try:
                    self.socketcan = SocketCanDoor.open(socketcan)
                    self.doors.append(self.socketcan)
                except OSError as exc:
                    self.socketcan_error = str(exc)
                    log.warning("endpoint %s: %s; SocketCAN door skipped", name, exc)
        except Exception:
            self.close()
            raise

    # ------------------------------------------------------------------ profile

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        return {
            "socketcand": _socketcand_options(raw.get("socketcand", {})),
            "slcan": _name_option(raw.get("slcan", True), "slcan", allow_true=True),
            "virtual": _name_option(raw.get("virtual"), "virtual", allow_true=False),
            "socketcan": _name_option(raw.get("socketcan"), "socketcan", allow_true=False),
        }

    @classmethod
    def open(cls, name: str, options: dict[str, Any], *, link_dir: str | os.PathLike[str] | None = None,
             **_: Any) -> CanPort:
        slcan = options.get("slcan", True)
        if slcan and link_dir is not None:
            slcan = str(Path(link_dir) / name)
        return cls(name, socketcand=options.get("socketcand"), slcan=slcan, virtual=options.get("virtual"),
                   socketcan=options.get("socketcan"))

    # ------------------------------------------------------------------ doors

    def open_virtual(self, channel: str | None = None) -> str:
        """Open the python-can ``virtual`` door (a fresh unique channel if none is named); returns its channel."""
        from hilbench.transports.can_virtual import VirtualChannel

        with self._lock:
            if self.virtual is not None:
                return self.virtual.channel
            door = VirtualChannel(channel or f"hilbench-{self.name}-{uuid.uuid4().hex[:8]}")
            if self._medium is not None:
                door.attach(self._medium)
            self.virtual = door
            self.doors = [*self.doors, door]  # a new list: the bus thread may be iterating the old one
        if self._medium is not None:
            self._medium.wake()  # the bus thread waits on the new door's descriptor from its next round
        return door.channel

    def open_bus(self, **kwargs: Any) -> Any:
        """A python-can bus on this endpoint's bus, in this process (its ``virtual`` door, opened if need be):
        ``bench.endpoint("can").port.open_bus()``; ``kwargs`` go to ``can.Bus``. Shut it down when done."""
        import can

        return can.Bus(interface="virtual", channel=self.open_virtual(), **kwargs)

    def attach(self, medium: Any) -> None:
        """The medium this port is a host of (doors learn its bitrate and clock)."""
        self._medium = medium
        for door in self.doors:
            door.attach(medium)

    # ------------------------------------------------------------------ the medium's side

    def filenos(self) -> list[int]:
        return [fd for door in self.doors for fd in door.filenos()]

    def fileno(self) -> int:
        return self.filenos()[0]

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        out: list[tuple[str, CanFrame]] = []
        for door in self.doors:
            out += door.read_frames(now)
        return out

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        for door in self.doors:
            door.write_frame(t, source, frame)

    def flush(self) -> None:
        for door in self.doors:
            door.flush()

    def deadline(self) -> float | None:
        times = [d for d in (door.deadline() for door in self.doors) if d is not None]
        return min(times) if times else None

    def wall_deadline(self) -> float | None:
        times = [d for d in (door.wall_deadline() for door in self.doors) if d is not None]
        return min(times) if times else None

    def poll(self, now: float) -> list[tuple[str, CanFrame]]:
        out: list[tuple[str, CanFrame]] = []
        for door in self.doors:
            out += door.poll(now)
        return out

    def read(self) -> bytes:
        """Not a byte stream: CAN media call :meth:`read_frames`."""
        raise NotImplementedError("a CAN host port carries frames (read_frames)")

    def write(self, data: bytes) -> int:
        raise NotImplementedError("a CAN host port carries frames (write_frame)")

    # ------------------------------------------------------------------ description

    @property
    def client_path(self) -> str:
        """What ``hilbench monitor`` opens: the socketcand URL (else the SLCAN pty)."""
        if self.socketcand is not None:
            return self.socketcand.url
        if self.slcan is not None:
            return f"slcan://{self.slcan.path}"
        if self.virtual is not None:
            return f"virtual://{self.virtual.channel}"
        return f"socketcan://{self.socketcan.channel}" if self.socketcan is not None else ""

    @property
    def address(self) -> tuple[str, int] | None:
        """The socketcand server's address (``hilbench emulate`` warns when it is beyond loopback)."""
        return self.socketcand.address if self.socketcand is not None else None

    def describe(self) -> dict[str, Any]:
        return {
            "path": self.client_path,
            "socketcand": self.socketcand.describe() if self.socketcand is not None else None,
            "slcan": self.slcan.path if self.slcan is not None else None,
            "virtual": self.virtual.channel if self.virtual is not None else None,
            "socketcan": self.socketcan.channel if self.socketcan is not None else None,
            "socketcan_error": self.socketcan_error,
        }

    def status(self) -> dict[str, Any]:
        """Each door's counters that has any (the socketcand server's clients, refusals and drops)."""
        return {door.kind: door.status() for door in self.doors if hasattr(door, "status")}

    def close(self) -> None:
        for door in self.doors:
            try:
                door.close()
            except Exception:
                log.exception("closing %s", door)
        self.doors = []

    def __repr__(self) -> str:
        return f"CanPort({self.name!r}, {self.client_path})"


__all__ = ["CanPort"]
