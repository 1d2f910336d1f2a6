"""The trace profiler as an instrument plug-in: a rover board's UART carries trace stamps, not a bus.

``hilbench monitor`` points a user at ``hilbench profile`` for this protocol
(:attr:`~hilbench.monitor.instrument.Instrument.verb`), and ``hilbench
profile`` accepts only sources whose instrument it is. :meth:`~TraceInstrument.sniff` tells
trace output in a raw capture (text stamp lines, logs, reports, binary words).
"""

from __future__ import annotations

from hilbench.monitor.instrument import Instrument


class TraceInstrument(Instrument):
    """Trace stamps (text and binary), logs and run-time reports of the rover board."""

    protocol = "vel2d"
    aliases = ("tracestamp",)
    title = "a board's trace output"
    verb = "profile"

    def sniff(self, data: bytes) -> float:
        from hilbench.protocols.problem import Problem
        from hilbench.protocols.tracestamp_stream import StreamDecoder

        dec = StreamDecoder()
        items = dec.feed(data[:8192]) + dec.flush()
        # A damaged-words report stands for all the words it covers: random bytes hold a few well-formed
        # binary words (a 11xxxxxx byte then three 10xxxxxx: one in 256) among hundreds of broken ones.
        bad = sum(i.count or 1 for i in items if type(i) is Problem)  # words (count) or one line
        good = sum(1 for i in items if type(i) is not Problem)
        if good <= bad:  # more damage than trace: not a trace (--protocol vel2d still reads it)
            return 0.0
        return good / (good + bad + 1)


INSTRUMENT = TraceInstrument()

__all__ = ["INSTRUMENT", "TraceInstrument"]
