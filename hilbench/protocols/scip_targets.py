"""The Hokuyo SCIP 2.0 reply decoder as a fuzz target (:mod:`hilbench.fuzzing`): what a unit streams, its
MD stream at full rate, and clean traffic to mutate. Registered in ``pyproject.toml``
(``hilbench.fuzz_targets``); the UST-10LX's TCP port has its own server target
(:mod:`hilbench.families.scip2_targets`)."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import scip

#: A UST-10LX's MD stream: 40 scans/s of 1 081 values, 3 characters each, in 64-character lines with their sums.
SCIP_LINE = 40 * (len(scip.data_lines(b"0" * 1081 * 3)) + 40)


def scip_traffic(rng: random.Random, size: int) -> bytes:
    """A SCIP 2.0 unit streaming MD scans (1 081 steps, 3-character values) after its "00" acknowledgement."""
    echo = b"MD0000108001000"
    out = bytearray(scip.reply(echo, "00"))
    ms = rng.randrange(1 << 24)
    while len(out) < size:
        values = [rng.randrange(20, 30000) for _ in range(1081)]
        out += scip.reply(echo, "99", scip.timestamp_line(ms) + scip.data_lines(scip.encode_values(values, 3)))
        ms += 25
    return bytes(out)


def _scip() -> Counting:
    dec = scip.ReplyDecoder()
    # good: replies whose every line's sum checks; lines that fail are what a damaged byte costs
    return Counting(dec.feed, list, lambda i: isinstance(i, scip.Reply) and not i.bad_sums,
                    lambda: dec.dropped + dec.bad_sums)


SCIP = FuzzTarget("scip2", "Hokuyo SCIP 2.0 reply decoder", _scip, SCIP_LINE,
                     "UST-10LX MD stream, 40 scans/s", scip_traffic)


__all__ = ["SCIP", "SCIP_LINE", "scip_traffic"]
