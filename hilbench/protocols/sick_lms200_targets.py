"""The SICK LMS 200 telegram decoder as a fuzz target (:mod:`hilbench.fuzzing`): what the unit sends in
continuous output, its fastest link, and clean traffic to mutate. Registered in ``pyproject.toml``
(``hilbench.fuzz_targets``)."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import sick_lms200 as lms

#: An LMS 200 at its fastest link speed, 500 kbaud 8N1 (RS-422).
LMS200_LINE = 500_000 / 10


def lms200_traffic(rng: random.Random, size: int) -> bytes:
    """An LMS 200 in continuous output: B0 telegrams of 181 or 361 values (cm), now and then an ACK of a
    host's request."""
    out = bytearray()
    while len(out) < size:
        if rng.random() < 0.05:
            out += bytes((lms.ACK,))
        n = rng.choice((181, 361))
        out += lms.reply(0xB0, lms.scan_data([rng.randrange(0, 8000) for _ in range(n)], units_mm=False))
    return bytes(out)


def _lms200() -> Counting:
    dec = lms.Decoder()
    # good: whole telegrams (a stray ACK or NAK byte in noise is a handshake, not a telegram)
    return Counting(dec.feed, list, lambda i: isinstance(i, lms.Frame), lambda: dec.dropped)


LMS200 = FuzzTarget("sick-lms200", "SICK LMS 200 telegram decoder", _lms200, LMS200_LINE, "500 kbaud RS-422",
                       lms200_traffic)


__all__ = ["LMS200", "LMS200_LINE", "lms200_traffic"]
