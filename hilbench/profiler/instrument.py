"""The trace profiler as an instrument plug-in: a board's UART carries trace stamps, not a bus.

``hilbench monitor`` points a user at ``hilbench trace`` for the protocols
of trace instruments (:attr:`~hilbench.monitor.instrument.Instrument.verb`),
and ``hilbench trace`` accepts only sources whose instrument it is.
:meth:`~TraceInstrument.sniff` tells trace output in a raw capture (text stamp
lines, logs, reports, binary words). A device family whose board writes trace
stamps registers a :class:`TraceInstrument` under its bus protocol with the
device's defaults (:attr:`~TraceInstrument.device_sources`,
:attr:`~TraceInstrument.default_baud`, :attr:`~TraceInstrument.device_name`):
the STM32 rover board's is :mod:`hilbench.profiler.stm32_rover`.
"""

from __future__ import annotations

import re
from typing import ClassVar

from hilbench.monitor.instrument import Instrument

#: Bytes of a text trace (stamp lines, logs, reports): printable ASCII and the line controls.
_TEXT = bytes(range(0x20, 0x7F)) + b"\t\r\n"
#: One binary trace word (spec: a 11xxxxxx byte, then three 10xxxxxx).
_WORD = re.compile(rb"[\xC0-\xFF][\x80-\xBF]{3}")


class TraceInstrument(Instrument):
    """Trace stamps (text and binary), logs and run-time reports of a board; subclasses name the protocol."""

    title = "a board's trace output"
    verb = "trace"
    #: The chunk sources of a bench line that carry the board's output (a glob): a bench names the host's
    #: side after the endpoint and the device's side after the device (None: every source).
    device_sources: ClassVar[str | None] = None
    #: The rate a serial port to the board is opened at when the user gives none.
    default_baud: ClassVar[int | None] = None
    #: The process name of an exported trace (``hilbench trace --export``) when the user gives none.
    device_name: ClassVar[str] = "board"
    datagram_classes = ("stamps",)

    def classify_datagram(self, data: bytes) -> str | None:
        """``"stamps"`` for a board's trace output sent over UDP: binary stamp words (every byte >= 0x80, a
        11xxxxxx byte every 4) or text lines of stamps, logs and reports."""
        n = len(data)
        if not n:
            return None
        if data[0] >= 0xC0:
            return "stamps" if all(b >= 0x80 for b in data[:64]) else None
        if data[0] < 0x80 and data.count(b"\n") and all(b < 0x80 for b in data[:256]):
            from hilbench.protocols.tracestamp import classify

            line = data.split(b"\n", 1)[0]
            return "stamps" if classify(line) not in ("error", "blank") else None
        return None

    def sniff(self, data: bytes) -> float:
        sample = data[:8192]
        # Most captures the monitor is asked about are not traces: bytes that are neither text nor binary
        # words say so without the decoder (and numpy, which it imports: a monitor's start-up).
        traceish = len(sample) - len(sample.translate(None, _TEXT)) + 4 * len(_WORD.findall(sample))
        if traceish * 2 < len(sample):
            return 0.0
        from hilbench.protocols.problem import Problem
        from hilbench.protocols.tracestamp_stream import StreamDecoder

        dec = StreamDecoder()
        items = dec.feed(sample) + dec.flush()
        # A damaged-words report stands for all the words it covers: random bytes hold a few well-formed
        # binary words (a 11xxxxxx byte then three 10xxxxxx: one in 256) among hundreds of broken ones.
        bad = sum(i.count or 1 for i in items if type(i) is Problem)  # words (count) or one line
        good = sum(1 for i in items if type(i) is not Problem)
        if good <= bad:  # more damage than trace: not a trace (--protocol of the instrument still reads it)
            return 0.0
        return good / (good + bad + 1)


def trace_instruments() -> list[TraceInstrument]:
    """The registered trace instruments (every family's whose boards write trace stamps), hilbench's first."""
    from hilbench import registry

    return registry.instruments.find(lambda inst: isinstance(inst, TraceInstrument))


def trace_instrument(protocol: str | None) -> TraceInstrument | None:
    """The trace instrument of ``protocol`` (a source's), else None."""
    if not protocol:
        return None
    return next((i for i in trace_instruments() if protocol in (i.protocol, *i.aliases)), None)


def default_baud(fallback: int = 115_200) -> int:
    """The rate a serial port is opened at for ``hilbench trace``: the first trace instrument's that has
    one, else ``fallback``."""
    return next((i.default_baud for i in trace_instruments() if i.default_baud), fallback)


__all__ = ["TraceInstrument", "default_baud", "trace_instrument", "trace_instruments"]
