"""The RPLIDAR response decoder as a fuzz target (:mod:`hilbench.fuzzing`): what an A1 sends a host, its
UART, and clean traffic to mutate. Registered in ``pyproject.toml`` (``hilbench.fuzz_targets``)."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import rplidar as rp
from hilbench.protocols.problem import Problem

#: An RPLIDAR A1's UART, 115 200 baud 8N1.
RPLIDAR_LINE = 115_200 / 10


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


__all__ = ["RPLIDAR", "RPLIDAR_LINE", "rplidar_traffic"]
