"""pcap and pcapng files (Wireshark, tcpdump): their UDP datagrams with addresses and Unix times."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

from hilbench.transports.capture_file import CaptureError, Chunk
from hilbench.transports.sources.base import Source, SourceError, SourceOpener


class PcapSource(Source):
    """The UDP datagrams of a pcap/pcapng file, replayed fast or at ``speed`` times the recorded pace.

    Times are the packets' Unix times (:attr:`wall_offset` 0); the protocol is ``udp``.
    """

    live = False
    timestamps = "measured"
    protocol = "udp"
    #: Chunk times are Unix times: add 0 to get Unix time (a recorder keeps them as they are).
    wall_offset = 0.0

    def __init__(self, target: str, *, speed: float | None = None) -> None:
        from hilbench.transports.pcap import PcapReader

        try:
            self.reader = PcapReader(target)
        except FileNotFoundError:
            raise SourceError(f"{target}: no such file") from None
        except CaptureError as exc:
            raise SourceError(str(exc)) from None
        if speed is not None and speed <= 0:
            self.reader.close()
            raise SourceError(f"replay speed must be positive, got {speed}")
        self.name = self.reader.name
        self.speed = speed
        self._stop = threading.Event()
        self._origin: tuple[float, float] | None = None

    def clock(self) -> float | None:
        if self.speed is None or self._origin is None:
            return None
        t_cap, t_mono = self._origin
        return t_cap + (time.monotonic() - t_mono) * self.speed

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        for chunk in self.reader:
            if self._stop.is_set():
                return
            if self.speed is not None:
                if self._origin is None:
                    self._origin = (chunk.t, time.monotonic())
                due = self._origin[1] + (chunk.t - self._origin[0]) / self.speed
                while (wait := due - time.monotonic()) > 0:
                    if self._stop.wait(min(wait, idle or wait)):
                        return
                    if idle is not None and due - time.monotonic() > 0:
                        yield None
            yield chunk

    def close(self) -> None:
        self._stop.set()
        self.reader.close()


def open_pcap(spec: str, target: str, fragment: str, *, speed: float | None = None, **_: object) -> Source:
    return PcapSource(target, speed=speed)


PCAP = SourceOpener("pcap", open_pcap, suffixes=(".pcap", ".pcapng", ".cap"), usage="capture.pcap, capture.pcapng",
                    what="a Wireshark/tcpdump capture: its UDP datagrams with addresses and times")

__all__ = ["PCAP", "PcapSource", "open_pcap"]
