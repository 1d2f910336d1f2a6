"""An SLCAN (LAWICEL) adapter on a pseudo-terminal: serial CAN tools join an emulated bus.

The pty behaves like a USB-CAN adapter speaking LAWICEL ASCII
(:mod:`hilbench.protocols.slcan`): python-can's ``slcan`` interface,
``cantools monitor -i slcan`` (and, untested here, SavvyCAN's LAWICEL connection or
Linux ``slcand``) open it as ``/dev/pts/N`` (or the stable link). Like the real
adapter it starts closed: frames flow after ``O`` (normal) or ``L``
(listen-only, sending refused with BEL), stop after ``C``; ``Sn``/``sXXYY``
set the bitrate while closed (BEL when open); ``Z1`` adds millisecond time
stamps; ``M``/``m`` set the SJA1000 acceptance filter; ``F`` reports status
flags, ``V``/``v``/``N`` version and serial number. Transmit commands are
confirmed with ``z``/``Z`` (CANUSB style), other commands with CR, errors
with BEL.

An adapter set to another bitrate than the bus sees nothing and is not seen
(on a real bus it would only produce errors): frames are not exchanged, the
``F`` flags show a bus error, and :attr:`SlcanAdapter.bitrate_mismatch` counts it.
"""

from __future__ import annotations

import logging
from typing import Any

from hilbench.protocols import slcan
from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.can_door import CanDoor
from hilbench.transports.pty import PtyPort

log = logging.getLogger(__name__)

#: What ``V`` and ``N`` answer (hardware 1.0, software 1.3; a serial number of four characters).
VERSION = "1013"
SERIAL = "HB01"


class SlcanAdapter(CanDoor):
    """The SLCAN door of a CAN host port: one emulated adapter behind a pty."""

    kind = "slcan"

    def __init__(self, name: str = "can", link: str | None = None) -> None:
        self.name = name
        self.pty = PtyPort(f"{name}-slcan", link=link)
        self.source = f"slcan {self.pty.path}"
        self.splitter = slcan.LineSplitter()
        self.open = False
        self.listen_only = False
        self.bitrate: int | None = None  # as the host set it (None: never set, the bus's rate)
        self.bus_bitrate = 0
        self.timestamps = False
        self.code = 0
        self.mask = 0xFFFFFFFF
        self.out = bytearray()
        self.sent = 0
        self.received = 0
        self.refused = 0
        self.bitrate_mismatch = 0  #: frames not exchanged: the adapter's bitrate is not the bus's
        self._medium: Any = None
        self._t0 = 0.0

    def attach(self, medium: Any) -> None:
        self._medium = medium
        self.bus_bitrate = medium.bitrate

    @property
    def path(self) -> str:
        return self.pty.client_path

    def describe(self) -> str:
        return self.path

    @property
    def _matched(self) -> bool:
        return self.bitrate is None or not self.bus_bitrate or self.bitrate == self.bus_bitrate

    # ------------------------------------------------------------------ host port duties

    def filenos(self) -> list[int]:
        return [self.pty.fileno()]

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        data = self.pty.read()
        out: list[tuple[str, CanFrame]] = []
        for line in self.splitter.feed(data):
            self._command(line, now, out)
        return out

    def _command(self, line: str, now: float, out: list[tuple[str, CanFrame]]) -> None:
        cmd = slcan.parse_command(line)
        op = cmd.op
        ok, bel = slcan.CR, slcan.BEL
        if op in "tTrR" and op:
            if not cmd.valid or not self.open or self.listen_only:
                self.refused += 1
                self.out += bel
                return
            self.out += (b"Z" if op in "TR" else b"z") + ok
            if self._matched:
                out.append((self.source, cmd.frame))  # type: ignore[arg-type]
                self.sent += 1
            else:
                self.bitrate_mismatch += 1
            return
        if op == "":
            self.out += ok  # python-can sends an empty command for "no data bitrate"
        elif op in ("O", "L"):
            if op == "L" or not self.open:
                self.listen_only = op == "L"
            self.open = True
            self._t0 = now
            self.out += ok
        elif op == "C":
            self.open = False
            self.listen_only = False
            # Frames an earlier client left unread in the pty must not greet the next one (every
            # client's opening sequence starts with C; the adapter's own queue empties on close too).
            self.out.clear()
            self.pty.discard_client_input()
            self.out += ok
        elif op == "S":
            rate = slcan.BITRATES.get(cmd.value)
            if self.open or rate is None:
                self.out += bel
            else:
                self.bitrate = rate
                if not self._matched:
                    log.warning("SLCAN %s: host set %d bit/s, the bus runs at %d bit/s: no frames will pass",
                                self.path, rate, self.bus_bitrate)
                self.out += ok
        elif op == "s":
            # BTR0/BTR1 of an SJA1000 at 8 MHz: accepted, the rate they give is not worked out.
            self.out += bel if self.open or len(cmd.value) != 4 else ok
        elif op == "F":
            self.out += f"F{self._flags():02X}".encode() + ok
        elif op == "V":
            self.out += f"V{VERSION}".encode() + ok
        elif op == "v":
            self.out += f"v{VERSION}".encode() + ok
        elif op == "N":
            self.out += f"N{SERIAL}".encode() + ok
        elif op == "Z":
            if cmd.value in ("0", "1"):
                self.timestamps = cmd.value == "1"
                self.out += ok
            else:
                self.out += bel
        elif op in ("M", "m"):
            try:
                value = int(cmd.value, 16)
            except ValueError:
                value = -1
            if self.open or len(cmd.value) != 8 or value < 0:
                self.out += bel
            else:
                if op == "M":
                    self.code = value
                else:
                    self.mask = value
                self.out += ok
        else:
            self.out += bel

    def _flags(self) -> int:
        flags = 0
        if self.pty.dropped:
            flags |= slcan.FLAG_DATA_OVERRUN
        if not self._matched:
            flags |= slcan.FLAG_BUS_ERROR
        if self._medium is not None:
            state = self._medium.controller_state(self.source)
            if state == "passive":
                flags |= slcan.FLAG_ERROR_PASSIVE | slcan.FLAG_ERROR_WARNING
            elif state == "bus-off":
                flags |= slcan.FLAG_BUS_ERROR
        return flags

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        if not self.open or source == self.source or frame.error:
            return  # LAWICEL adapters report errors through F, not as frames
        if not self._matched:
            self.bitrate_mismatch += 1
            return
        if not slcan.acceptance(frame, self.code, self.mask):
            return
        stamp = int((t - self._t0) * 1000) if self.timestamps else None
        self.out += slcan.encode_frame(frame, stamp)
        self.received += 1

    def flush(self) -> None:
        if self.out:
            self.pty.write(bytes(self.out))  # a full pty buffer drops (and counts) like a UART FIFO
            self.out.clear()

    def close(self) -> None:
        self.pty.close()


__all__ = ["SlcanAdapter"]
