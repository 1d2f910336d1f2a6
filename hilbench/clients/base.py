"""Client drivers: the host side of one protocol's devices, as a verb drives them (``hilbench.clients``).

A device family that a host-side verb can drive registers a
:class:`ClientDriver` in the ``hilbench.clients`` entry-point group, under
its protocol (as its bus kind and instrument are). The verb of the client's
:attr:`~ClientDriver.role` finds it there and names no family itself: ``hilbench
lidar`` drives every client of role ``scanner``
(:class:`~hilbench.clients.scanners.ScannerClient`), takes ``--protocol``
choices from their protocols and aliases, adds each one's own options
(:meth:`~ClientDriver.add_arguments`, e.g. the SICK LMS 200's ``--lms-baud``)
and opens a serial port at its :attr:`~ClientDriver.default_baud`.

A client driver module is imported when its verb builds its parser: it should
import its protocol's codec and trackers where it uses them, not at the top.
"""

from __future__ import annotations

import argparse
from typing import ClassVar


class ClientDriver:
    """Base class of client plug-ins; subclasses set the class attributes (and a role's own methods)."""

    #: The protocol it speaks (its entry-point name; the bus kind's and the instrument's protocol).
    protocol: ClassVar[str] = ""
    #: Other names a user may give the protocol by (``--protocol sick``).
    aliases: ClassVar[tuple[str, ...]] = ()
    #: Which verb drives it: ``"scanner"`` (``hilbench lidar``).
    role: ClassVar[str] = ""
    #: A few words for listings ("SICK LMS 200 host").
    title: ClassVar[str] = ""
    #: The line rate a serial port to the device is opened at (None: the verb's default).
    default_baud: ClassVar[int | None] = None

    @property
    def names(self) -> tuple[str, ...]:
        """Its protocol and aliases."""
        return (self.protocol, *self.aliases)

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Options of its own for its role's verb (names must not clash with the verb's or other clients')."""


__all__ = ["ClientDriver"]
