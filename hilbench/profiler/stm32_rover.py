"""The STM32 rover board's trace output as an instrument (entry point ``vel2d`` of ``hilbench.instruments``).

The board's UART carries its trace stamps, logs and run-time reports beside
the Vel2d frames; :class:`~hilbench.profiler.instrument.TraceInstrument` reads
them, with the board's defaults here.
"""

from __future__ import annotations

from hilbench.profiler.instrument import TraceInstrument


class RoverTraceInstrument(TraceInstrument):
    """Trace stamps (text and binary), logs and run-time reports of the STM32 rover board."""

    protocol = "vel2d"
    aliases = ("tracestamp",)
    # the bench names the board's side of its line `<endpoint>-board`
    device_sources = "*-board"
    #: The board's UART rate on the firmware branch heads (spec sheet stm32_board.md §1.1).
    default_baud = 115_200
    device_name = "stm32f767-rover"


#: The instrument this module registers (entry point ``vel2d`` of ``hilbench.instruments``).
INSTRUMENT = RoverTraceInstrument()

__all__ = ["INSTRUMENT", "RoverTraceInstrument"]
