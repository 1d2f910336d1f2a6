"""The capture parser as a fuzz target (:mod:`hilbench.fuzzing`), with captures of its own to mutate.

The parser reads records (time, source, length, bytes) and never looks inside the bytes, so the sample
captures carry random payloads of an unknown protocol: the target is the format, not any family's traffic.
"""

from __future__ import annotations

import io
import random

from hilbench.fuzzing import FuzzTarget
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.capture_parser import CaptureParser
from hilbench.transports.chunk import CaptureError

#: The fastest line hilbench records: a 12.5 Mbit/s UART, 8N1 (a capture holds its bytes plus 12 per record).
CAPTURE_LINE = 12_500_000 / 10
#: The sample captures' line rate, in their header.
BAUD = 2_000_000


def capture_traffic(rng: random.Random, size: int) -> bytes:
    """A capture of a line: about ``size`` bytes of payload in chunks from two sources (a host and its devices)
    with measured times, and a gap now and then."""
    buf = io.BytesIO()
    w = CaptureWriter(buf, baud=BAUD, protocol="", t0=0.0)
    t = 0.0
    written = 0
    while written < size:
        n = rng.randrange(1, 300)
        t += rng.random() * 1e-3
        w.write(t, rng.choice(["host", "devices"]), rng.randbytes(n))
        written += n
        if rng.random() < 0.001:
            w.gap(t, "host", rng.randrange(1, 1000))
    w.flush()
    return buf.getvalue()


class _CaptureReader:
    def __init__(self) -> None:
        self.parser = CaptureParser()
        self.chunks = 0

    def feed(self, data: bytes) -> None:
        self.chunks += len(self.parser.feed(data))

    def finish(self) -> None:
        self.chunks += len(self.parser.finish())

    def good(self) -> int:
        return self.chunks

    def dropped(self) -> int:
        return self.parser.corrupt_bytes + self.parser.truncated_bytes


def after_header(noise: bytes) -> bytes:
    """Noise where a capture's records should be (raw noise is a raw dump: nothing to resynchronise)."""
    from hilbench.protocols import capture as cap

    return cap.build_header(baud=BAUD, protocol="") + noise


CAPTURE = FuzzTarget("capture", "hilbench capture format (.hbcap, the TCP tap stream)", _CaptureReader,
                     CAPTURE_LINE, "capture of a 12.5 Mbit/s line", capture_traffic, frame=after_header,
                     refuses=(CaptureError,))  # a header of a newer format version (2..16): one line

__all__ = ["CAPTURE", "CAPTURE_LINE", "capture_traffic"]
