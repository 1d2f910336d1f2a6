"""The capture parser as a rough-input target (:mod:`hilbench.fuzzing`)."""

from __future__ import annotations

import io
import random

from hilbench.fuzzing import FuzzTarget
from hilbench.protocols.dynamixel_targets import dynamixel_traffic
from hilbench.protocols.vel2d_targets import BOARD_LINE
from hilbench.transports.capture_file import CaptureError, CaptureParser, CaptureWriter


def capture_traffic(rng: random.Random, size: int) -> bytes:
    """A capture of a bus: chunks of two sources with measured times, and a gap."""
    buf = io.BytesIO()
    w = CaptureWriter(buf, baud=2_000_000, protocol="dynamixel", t0=0.0)
    t = 0.0
    data = dynamixel_traffic(rng, size)
    pos = 0
    while pos < len(data):
        n = rng.randrange(1, 300)
        t += rng.random() * 1e-3
        w.write(t, rng.choice(["dxl", "dxl-devices"]), data[pos : pos + n])
        pos += n
        if rng.random() < 0.001:
            w.gap(t, "dxl", rng.randrange(1, 1000))
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

    return cap.build_header(baud=2_000_000, protocol="dynamixel") + noise


#: A capture of the fastest line hilbench records (its bytes plus 12 per record).
CAPTURE = FuzzTarget("capture", "hilbench capture format (.hbcap, the TCP tap stream)", _CaptureReader,
                        BOARD_LINE, "capture of a 12.5 Mbit/s line", capture_traffic, frame=after_header,
                        refuses=(CaptureError,))  # a header of a newer format version (2..16): one line

__all__ = ["CAPTURE", "capture_traffic"]
