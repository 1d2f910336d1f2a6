"""pcap and pcapng files (Wireshark, tcpdump): their UDP datagrams with addresses and Unix times."""

from __future__ import annotations

from collections.abc import Iterator

from hilbench.transports.chunk import CaptureError, Chunk
from hilbench.transports.sources.base import (
    ReplaySource,
    Source,
    SourceError,
    SourceOpener,
    SourceUnavailable,
)


class PcapSource(ReplaySource):
    """The UDP datagrams of a pcap/pcapng file, replayed fast or at ``speed`` times the recorded pace.

    Times are the packets' Unix times (:attr:`wall_offset` 0); the protocol is ``udp``.
    """

    timestamps = "measured"
    protocol = "udp"
    #: Chunk times are Unix times: add 0 to get Unix time (a recorder keeps them as they are).
    wall_offset = 0.0

    def __init__(self, target: str, *, speed: float | None = None) -> None:
        from hilbench.transports.pcap import PcapReader

        try:
            self.reader = PcapReader(target)
        except FileNotFoundError:
            raise SourceUnavailable(f"{target}: no such file") from None
        except CaptureError as exc:
            raise SourceError(str(exc)) from None
        if speed is not None and speed <= 0:
            self.reader.close()
            self.check_speed(speed)
        self.name = self.reader.name
        self._start_replay(speed)

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        for chunk in self.reader:
            if self._stop.is_set():
                return
            if self.speed is not None and (yield from self._pace(chunk.t, idle)):
                return
            yield chunk

    def close(self) -> None:
        super().close()
        self.reader.close()


def open_pcap(spec: str, target: str, fragment: str, *, speed: float | None = None, **_: object) -> Source:
    return PcapSource(target, speed=speed)


PCAP = SourceOpener("pcap", open_pcap, suffixes=(".pcap", ".pcapng", ".cap"), usage="capture.pcap, capture.pcapng",
                    what="a Wireshark/tcpdump capture: its UDP datagrams with addresses and times")

__all__ = ["PCAP", "PcapSource", "open_pcap"]
