"""The Dynamixel bus monitor's tracker as a fuzz target (:mod:`hilbench.fuzzing`)."""

from __future__ import annotations

from hilbench.fuzzing import FuzzTarget
from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.protocols.dynamixel_targets import DYNAMIXEL_LINE, dynamixel_traffic


class _TrackerReader:
    """Bytes of one source at byte time on a 2 Mbaud line: decoded, paired, tracked."""

    def __init__(self) -> None:
        self.tracker = BusTracker(baud=2_000_000)
        self.n = 0

    def feed(self, data: bytes) -> None:
        self.n += len(data)
        self.tracker.feed(self.n * 5e-6, "bus", data)

    def finish(self) -> None:
        from hilbench.monitor.servo_bus.summary import summary

        self.tracker.finish()
        summary(self.tracker)  # the summary must survive whatever was tracked

    def good(self) -> int:
        return sum(d.packets for d in self.tracker.decoders.values())

    def dropped(self) -> int:
        return sum(d.bytes_skipped for d in self.tracker.decoders.values())


TRACKER = FuzzTarget("monitor-dynamixel", "Dynamixel bus monitor (decoder, pairing, device state)",
                        _TrackerReader, DYNAMIXEL_LINE, "4.5 Mbaud RS-485 bus", dynamixel_traffic,
                        kind="instrument")

__all__ = ["TRACKER"]
