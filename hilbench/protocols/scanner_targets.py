"""The laser scanners' decoders as rough-input targets (:mod:`hilbench.fuzzing`): what each unit sends, its
line, and clean traffic of its kind to mutate. Registered in ``pyproject.toml``; ``tools/fuzz.py`` and
``tools/rough.py`` drive them like the servo and board decoders (:mod:`hilbench.protocols.targets`)."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import rplidar as rp
from hilbench.protocols import scip
from hilbench.protocols import sick_lms200 as lms
from hilbench.protocols.problem import Problem

#: An RPLIDAR A1's UART, 115 200 baud 8N1.
RPLIDAR_LINE = 115_200 / 10
#: An LMS 200 at its fastest link speed, 500 kbaud 8N1 (RS-422).
LMS200_LINE = 500_000 / 10
#: A UST-10LX's MD stream: 40 scans/s of 1 081 values, 3 characters each, in 64-character lines with their sums.
SCIP_LINE = 40 * (len(scip.data_lines(b"0" * 1081 * 3)) + 40)


# --------------------------------------------------------------------------- RPLIDAR A1


def rplidar_traffic(rng: random.Random, size: int) -> bytes:
    """What an A1 sends a host: a health answer, then a standard scan's descriptor and its nodes, revolution
    after revolution (about 360 nodes each, some without a distance)."""
    out = bytearray(rp.descriptor(3, 0, rp.AnsType.DEVHEALTH) + rp.health_payload(0, 0))
    out += rp.descriptor(5, 1, rp.AnsType.MEASUREMENT)
    while len(out) < size:
        n = rng.randrange(340, 380)
        for k in range(n):
            dist = 0 if rng.random() < 0.05 else rng.randrange(150 * 4, 12000 * 4)
            out += rp.node(rng.randrange(1, 64), k * 360 * 64 // n, dist, k == 0)
    return bytes(out)


def _rplidar() -> Counting:
    dec = rp.ResponseDecoder()
    return Counting(dec.feed, list, lambda i: not isinstance(i, Problem), lambda: dec.dropped)


RPLIDAR = FuzzTarget("rplidar", "RPLIDAR A1 response decoder (descriptors, nodes, capsules)", _rplidar,
                        RPLIDAR_LINE, "115 200 baud UART", rplidar_traffic)


# --------------------------------------------------------------------------- SICK LMS 200


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


# --------------------------------------------------------------------------- Hokuyo SCIP 2.0


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


__all__ = ["LMS200", "LMS200_LINE", "RPLIDAR", "RPLIDAR_LINE", "SCIP", "SCIP_LINE", "lms200_traffic",
           "rplidar_traffic", "scip_traffic"]
