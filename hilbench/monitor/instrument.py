"""Instruments: how hilbench watches one protocol's traffic (a tracker, its summary, its dashboard views).

An :class:`Instrument` is registered per protocol in the ``hilbench.instruments``
entry-point group. The generic frames use nothing else:
:class:`~hilbench.monitor.live.Monitor` feeds chunks to the instrument's
tracker, ``hilbench monitor`` adds the instrument's options and prints its
summary, and :class:`~hilbench.dashboard.Dashboard` shows its views. A tracker
is duck-typed (:class:`Tracker`): bytes in with times, state out, no I/O.

An instrument whose traffic another verb reads (a board's trace output is the
profiler's) sets :attr:`Instrument.verb`, so ``hilbench monitor`` points there.
"""

from __future__ import annotations

import argparse
import importlib
from typing import Any, ClassVar, Protocol


class Tracker(Protocol):
    """What the monitor frame needs of a tracker (fed under the monitor's lock, in bus order)."""

    protocol: str
    baud: int | None
    timestamps: bool
    t0: float | None
    t_last: float | None

    def feed(self, t: float, source: str, data: bytes) -> None:
        """Bytes ``source`` put on the medium, complete at time ``t``."""

    # Optional: ``feed_datagram(t, source, data, addr)`` takes a datagram with its addresses
    # ``(source host, source port, destination host, destination port)`` instead of :meth:`feed`.

    def gap(self, t: float, source: str, nbytes: int) -> None:
        """``nbytes`` from ``source`` were lost before reaching the monitor."""

    def flush(self, t: float | None = None) -> None:
        """The medium went idle: partial items are complete (or cut off)."""

    def tick(self, t: float) -> None:
        """Time passes with nothing on the medium (timeouts, silence rules)."""

    def finish(self) -> None:
        """The source ended."""


class Instrument:
    """Base class of instrument plug-ins; subclasses set the class attributes and build trackers."""

    #: The protocol it watches (a source's or endpoint's ``protocol``).
    protocol: ClassVar[str] = ""
    #: Other names of the protocol.
    aliases: ClassVar[tuple[str, ...]] = ()
    #: A few words for listings ("Dynamixel Protocol 2.0 bus").
    title: ClassVar[str] = ""
    #: The verb that reads this protocol (``"monitor"``; ``"trace"`` for trace output).
    verb: ClassVar[str] = "monitor"
    #: ``"module:ATTRIBUTE"`` of its dashboard view set, imported only when a dashboard is shown.
    views_path: ClassVar[str | None] = None
    #: Classes of UDP datagrams its traffic comes in (:meth:`classify_datagram`), which the UDP monitor counts
    #: beside XRCE-DDS and RTPS (the rover board's ``vel2d`` frames and trace ``stamps``).
    datagram_classes: ClassVar[tuple[str, ...]] = ()

    def sniff(self, data: bytes) -> float:
        """How sure (0..1) it is that raw ``data`` (the start of a source) is its protocol."""
        return 0.0

    def classify_datagram(self, data: bytes) -> str | None:
        """Which of its :attr:`datagram_classes` one UDP datagram's payload is, or None (called for every
        datagram the UDP monitor cannot tell as XRCE-DDS or RTPS: keep it cheap, import inside)."""
        return None

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Options of its own for ``hilbench monitor`` and ``tap`` (names must not clash with others')."""

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        """Tracker options from parsed arguments (raise :class:`~hilbench.errors.UsageError` on bad ones)."""
        return {}

    def input_files(self, args: argparse.Namespace) -> list[str]:
        """The files its own options read (a CAN bus's ``--dbc``, ``--eds``): no output may replace them."""
        return []

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> Tracker:
        """A new tracker for a source with this line rate and (real or no) times."""
        raise NotImplementedError

    def summary(self, tracker: Tracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict[str, Any]:
        """The JSON summary of what the tracker saw."""
        raise NotImplementedError

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        """The summary as a person reads it, on a rich console."""
        import json

        console.print_json(json.dumps(report))

    def views(self) -> Any:
        """Its dashboard view set (:class:`~hilbench.dashboard.app.ViewSet`), imported on first use."""
        if self.views_path is None:
            return None
        module, _, attr = self.views_path.partition(":")
        return getattr(importlib.import_module(module), attr)


__all__ = ["Instrument", "Tracker"]
