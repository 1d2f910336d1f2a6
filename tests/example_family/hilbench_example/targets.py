"""The blinker's line decoder as a fuzz target: ``tools/fuzz.py`` and ``tools/rough.py --only blink`` drive it
on noise and on damaged traffic, as they drive hilbench's own decoders."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench_example.protocol import BLINK, PONG, LineDecoder, build

#: The fastest line a blinker sits on: 115 200 baud, 10 bits a byte.
LINE_RATE = 115_200 / 10


def traffic(rng: random.Random, size: int) -> bytes:
    """What a board sends: BLINK lines, now and then a PONG."""
    out = bytearray()
    n = 0
    while len(out) < size:
        n += 1
        out += build(PONG, rng.randrange(1, 100)) if rng.random() < 0.1 else build(BLINK, n)
    return bytes(out)


def _reader() -> Counting:
    decoder = LineDecoder()
    return Counting(decoder.feed, lambda: [], lambda message: 1, lambda: decoder.bad)


BLINK_LINES = FuzzTarget("blink", "Acme blinker lines (example plug-in)", _reader, LINE_RATE,
                         "115200 baud UART", traffic)
