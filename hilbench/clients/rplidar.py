"""The RPLIDAR's host side: :class:`~hilbench.clients.rplidar.RplidarDriver` and its ``hilbench lidar`` client.

Registered as ``hilbench.clients`` entry point ``rplidar`` (:data:`CLIENT`),
with the option ``--express``; the codec is imported when the driver talks.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable

from hilbench.clients.scanners import ScannerClient, ScannerConnection, ScannerDriver


class RplidarDriver(ScannerDriver):
    """GET_INFO, GET_HEALTH, motor on (DTR cleared), SCAN or EXPRESS_SCAN; STOP and motor off."""

    protocol = "rplidar"

    def __init__(self, connection: ScannerConnection, tracker=None, *, express: bool = False,
                 motor: Callable[[bool], None] | None = None) -> None:
        super().__init__(connection, tracker)
        self.express = express
        self.motor = motor  # how to reach DTR when the port has no modem lines (a bench pty)

    def _set_motor(self, on: bool) -> None:
        if not self.connection.set_dtr(not on) and self.motor is not None:
            self.motor(on)

    def start(self) -> None:
        from hilbench.protocols import rplidar as rp

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
        from hilbench.protocols import rplidar as rp

        with contextlib.suppress(OSError):
            self.send(rp.request(rp.Cmd.STOP))
            self._set_motor(False)


class RplidarClient(ScannerClient):
    """Slamtec RPLIDAR host: motor on through DTR, SCAN (or EXPRESS_SCAN with --express)."""

    protocol = "rplidar"
    title = "Slamtec RPLIDAR host"
    driver = RplidarDriver
    default_on = ("serial",)  # a serial port and nothing else said: an RPLIDAR, the commonest

    @property
    def default_baud(self) -> int:  # type: ignore[override]
        """The A1's UART rate (``hilbench.protocols.rplidar.BAUD``)."""
        from hilbench.protocols.rplidar import BAUD

        return BAUD

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--express", action="store_true", help="RPLIDAR: express scan (legacy capsules)")

    def open(self, connection: ScannerConnection, args: argparse.Namespace | None = None, *,
             set_dtr: Callable[[bool], None] | None = None) -> RplidarDriver:
        motor = (lambda on: set_dtr(not on)) if set_dtr is not None else None  # the motor runs while DTR is low
        return RplidarDriver(connection, express=bool(getattr(args, "express", False)), motor=motor)


#: The client driver this module registers (entry point ``hilbench.clients``).
CLIENT = RplidarClient()

__all__ = ["CLIENT", "RplidarClient", "RplidarDriver"]
