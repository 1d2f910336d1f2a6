"""The SICK LMS 200's host side: :class:`~hilbench.clients.sick_lms200.SickDriver` and its ``hilbench lidar`` client.

Registered as ``hilbench.clients`` entry point ``sick-lms200`` (:data:`CLIENT`,
aliases ``sick``, ``lms200``), with the option ``--lms-baud``. The line speeds
come from the protocol's one table (:data:`hilbench.protocols.sick_lms200.BAUD_MODES`).
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections.abc import Callable

from hilbench.clients.scanners import ScannerClient, ScannerConnection, ScannerDriver
from hilbench.errors import DeviceError
from hilbench.protocols import sick_lms200 as lms


class SickDriver(ScannerDriver):
    """Find the unit's line speed, change it if asked (mode 40/41/48, then the port follows), continuous
    output; mode 25 and the power-up speed again when done.

    An LMS 200 keeps a speed it was switched to until power-off, so a host that left it at 38 400 baud
    (or died before switching back) finds it there next time. As real drivers do (sicktoolbox's
    ``SickLMS2xx::Initialize``), :meth:`find_baud` tries the speeds in turn with a status request (31)
    and takes the one that gets a good reply; :meth:`stop` switches back to 9600 as sicktoolbox's
    ``Uninitialize`` does.
    """

    protocol = "sick-lms200"
    MODES = {v: k for k, v in lms.BAUD_MODES.items()}
    #: Line speeds an LMS 200 can run at, in the order they are tried (its power-up speed first, then in
    #: the order of the mode table).
    BAUDS = tuple(dict.fromkeys((lms.POWER_UP_BAUD, *lms.BAUD_MODES.values())))
    #: How long a status request waits for its reply at each speed (the reply: 160 bytes, 170 ms at 9600).
    PROBE_TIMEOUT = 1.0

    def __init__(self, connection: ScannerConnection, tracker=None, *, baud: int = lms.POWER_UP_BAUD) -> None:
        super().__init__(connection, tracker)
        self.baud = baud
        #: The speed the unit runs at now, once known.
        self.session_baud: int | None = None

    def answers_at(self, baud: int, timeout: float | None = None) -> bool:
        """Whether the unit answers a status request at ``baud`` (the port is left at ``baud``).

        The exchange is kept from the tracker: at a wrong speed a real unit's bytes are noise.
        """
        self.connection.set_baud(baud)
        with contextlib.suppress(OSError):
            while self.connection.read(0.0):  # what came at the old speed
                pass
        dec = lms.Decoder(handshakes=True)
        self.connection.write(lms.request(lms.Cmd.STATUS))
        deadline = time.monotonic() + (self.PROBE_TIMEOUT if timeout is None else timeout)
        while time.monotonic() < deadline:
            for item in dec.feed(self.connection.read(0.02)):
                # a status reply, or the scans of a unit left streaming at this speed
                if isinstance(item, lms.Frame) and item.is_reply and item.cmd in (0xB1, 0xB0):
                    return True
        return False

    def find_baud(self) -> int:
        """The unit's line speed (tried as :attr:`BAUDS` says, the asked-for one second); a
        :class:`~hilbench.errors.DeviceError` saying what was tried when none answers."""
        tried = list(dict.fromkeys((self.BAUDS[0], self.baud, *self.BAUDS)))
        for baud in tried:
            if self.answers_at(baud):
                self.session_baud = baud
                return baud
        raise DeviceError(f"{self.connection.name}: no LMS 200 answers a status request at "
                          f"{', '.join(map(str, tried))} baud (is it powered, on this port, and not used by "
                          f"another program?)")

    def _switch(self, baud: int, wait: float = 2.0) -> bool:
        tr = self.tracker
        replies = tr.replies
        self.send(lms.mode_request(self.MODES[baud]))
        ok = self.wait_for(lambda: tr.replies > replies, wait)
        self.connection.set_baud(baud)  # the reply came at the old speed; the LMS now runs at the new
        self.session_baud = baud
        return ok

    def start(self) -> None:
        if self.connection.kind == "serial":
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
            if self.session_baud not in (None, lms.POWER_UP_BAUD) and self.connection.kind == "serial":
                self.wait_for(lambda: tr.replies > replies, 1.0)
                self._switch(lms.POWER_UP_BAUD, wait=1.0)


class SickClient(ScannerClient):
    """SICK LMS 200 host: finds the unit's speed, switches it (--lms-baud), continuous output."""

    protocol = "sick-lms200"
    aliases = ("sick", "lms200")
    title = "SICK LMS 200 host"
    driver = SickDriver
    default_baud = lms.POWER_UP_BAUD

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--lms-baud", type=int, choices=lms.LINK_BAUDS, default=lms.POWER_UP_BAUD,
                            help=f"LMS 200: switch the line to this speed first (default {lms.POWER_UP_BAUD}, "
                                 "the power-up rate)")

    def open(self, connection: ScannerConnection, args: argparse.Namespace | None = None, *,
             set_dtr: Callable[[bool], None] | None = None) -> SickDriver:
        return SickDriver(connection, baud=getattr(args, "lms_baud", lms.POWER_UP_BAUD))


#: The client driver this module registers (entry point ``hilbench.clients``).
CLIENT = SickClient()

__all__ = ["CLIENT", "SickClient", "SickDriver"]
