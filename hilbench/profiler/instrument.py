"""The trace profiler as an instrument plug-in: a rover board's UART carries trace stamps, not a bus.

``hilbench monitor`` points a user at ``hilbench trace`` for this protocol
(:attr:`~hilbench.monitor.instrument.Instrument.verb`), and ``hilbench
trace`` accepts only sources whose instrument it is. :meth:`~TraceInstrument.sniff` tells
trace output in a raw capture (text stamp lines, logs, reports, binary words).
"""

from __future__ import annotations

import re

from hilbench.monitor.instrument import Instrument

#: Bytes of a text trace (stamp lines, logs, reports): printable ASCII and the line controls.
_TEXT = bytes(range(0x20, 0x7F)) + b"\t\r\n"
#: One binary trace word (spec: a 11xxxxxx byte, then three 10xxxxxx).
_WORD = re.compile(rb"[\xC0-\xFF][\x80-\xBF]{3}")


class TraceInstrument(Instrument):
    """Trace stamps (text and binary), logs and run-time reports of the rover board."""

    protocol = "vel2d"
    aliases = ("tracestamp",)
    title = "a board's trace output"
    verb = "trace"

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
        if good <= bad:  # more damage than trace: not a trace (--protocol vel2d still reads it)
            return 0.0
        return good / (good + bad + 1)


INSTRUMENT = TraceInstrument()

__all__ = ["INSTRUMENT", "TraceInstrument"]
