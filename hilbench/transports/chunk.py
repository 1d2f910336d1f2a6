"""A chunk of traffic: what every byte source yields and every capture reader returns.

The monitor pipeline's unit (sources, trackers, recorders, the tap server) is
a :class:`Chunk`: the bytes one party put on a medium and when. Readers of
recorded traffic (:mod:`~hilbench.transports.capture_file`,
:mod:`~hilbench.transports.pcap`) also report the damage they found
(:func:`sound_quality` is the report of an input without any) and raise
:class:`CaptureError` for an input they cannot read. This module imports
nothing heavy, so a source that reads no capture (a serial port, a UDP port,
a CAN bus) never loads the capture parser.
"""

from __future__ import annotations

from typing import NamedTuple

from hilbench.errors import FormatError


class Chunk(NamedTuple):
    """Bytes ``data`` that ``source`` put on the bus, complete at time ``t`` (seconds).

    ``lost`` > 0 (with empty ``data``) reports that many bytes of ``source``
    lost before they reached the reader. ``addr`` is set for a datagram:
    ``(source host, source port, destination host, destination port)``.
    """

    t: float
    source: str
    data: bytes
    lost: int = 0
    addr: tuple[str, int, str, int] | None = None


class CaptureError(FormatError):
    """A capture that cannot be read; the message is one line."""


def sound_quality() -> dict:
    """The data quality of an input without damage (the shape of
    :meth:`~hilbench.transports.capture_parser.CaptureParser.quality`)."""
    return {"truncated_bytes": 0, "corrupt_bytes": 0, "corruptions": 0, "time_faults": 0, "time_resets": 0,
            "unknown_records": 0, "findings": []}


__all__ = ["CaptureError", "Chunk", "sound_quality"]
