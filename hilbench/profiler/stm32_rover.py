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
    # its UDP door carries Vel2d frames one way and the trace output the other (the UDP monitor counts both)
    datagram_classes = ("vel2d", "stamps")

    def classify_datagram(self, data: bytes) -> str | None:
        from hilbench.protocols import vel2d

        if len(data) == vel2d.FRAME_SIZE and vel2d.crc(data[:24]) == int.from_bytes(data[24:28], "little"):
            return "vel2d"
        return super().classify_datagram(data)


#: The instrument this module registers (entry point ``vel2d`` of ``hilbench.instruments``).
INSTRUMENT = RoverTraceInstrument()

__all__ = ["INSTRUMENT", "RoverTraceInstrument"]
