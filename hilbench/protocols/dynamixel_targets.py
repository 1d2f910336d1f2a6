"""The Dynamixel Protocol 2.0 and 1.0 decoders as fuzz targets (:mod:`hilbench.fuzzing`): how to drive each
with bytes, the bus they read at its fastest, and a servo bus's clean traffic to mutate. Registered in
``pyproject.toml`` (``hilbench.fuzz_targets``)."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as dxl1
from hilbench.protocols.problem import Problem

#: A Dynamixel bus at 4.5 Mbaud (the fastest Baud Rate code the servos of both protocols share), 8N1.
DYNAMIXEL_LINE = 4_500_000 / 10


# --------------------------------------------------------------------------- Protocol 2.0


def dynamixel_traffic(rng: random.Random, size: int) -> bytes:
    """A servo bus's traffic: Sync Reads of present position with their replies, Sync Writes, Reads,
    Pings, now and then an error status or a device that stays silent."""
    out = bytearray()
    ids = list(range(1, rng.randrange(2, 21)))
    while len(out) < size:
        kind = rng.random()
        if kind < 0.5:
            out += dxl.instruction_packet_unstuffed(dxl.BROADCAST_ID, dxl.Instruction.SYNC_READ,
                                                    bytes((132, 0, 4, 0, *ids)))
            for i in ids:
                if rng.random() > 0.02:
                    out += dxl.status_packet(i, 0x80 if rng.random() < 0.01 else 0, rng.randbytes(4))
        elif kind < 0.8:
            out += dxl.instruction_packet_unstuffed(dxl.BROADCAST_ID, dxl.Instruction.SYNC_WRITE, bytes(
                (116, 0, 4, 0)) + b"".join(bytes((i,)) + rng.randbytes(4) for i in ids))
        elif kind < 0.95:
            i = rng.choice(ids)
            out += dxl.instruction_packet(i, dxl.Instruction.READ, bytes((146, 0, 1, 0)))
            out += dxl.status_packet(i, 0, rng.randbytes(1))
        else:
            i = rng.choice(ids)
            out += dxl.instruction_packet(i, dxl.Instruction.PING) + dxl.status_packet(i, 0, b"\x1e\x04\x2a")
    return bytes(out)


def _dynamixel() -> Counting:
    dec = dxl.Decoder()
    return Counting(dec.feed, dec.flush, lambda i: not isinstance(i, Problem), lambda: dec.bytes_skipped)


DYNAMIXEL = FuzzTarget("dynamixel", "Dynamixel Protocol 2.0 decoder", _dynamixel, DYNAMIXEL_LINE,
                          "4.5 Mbaud RS-485 bus", dynamixel_traffic)


# --------------------------------------------------------------------------- Protocol 1.0


def dynamixel1_traffic(rng: random.Random, size: int) -> bytes:
    """A Protocol 1.0 bus: Reads with their statuses, Writes, Sync Writes, Pings."""
    out = bytearray()
    while len(out) < size:
        i = rng.randrange(0, 0xFE)
        kind = rng.random()
        if kind < 0.5:
            out += dxl1.build(i, dxl1.Instruction1.READ, bytes((36, 2)))
            out += dxl1.build(i, 0, rng.randbytes(2))
        elif kind < 0.8:
            out += dxl1.build(dxl1.BROADCAST_ID, dxl1.Instruction1.SYNC_WRITE,
                              bytes((30, 2)) + b"".join(bytes((k,)) + rng.randbytes(2) for k in range(1, 7)))
        else:
            out += dxl1.build(i, dxl1.Instruction1.PING) + dxl1.build(i, 0)
    return bytes(out)


def _dynamixel1() -> Counting:
    dec = dxl1.Decoder1()
    return Counting(dec.feed, dec.flush, lambda i: isinstance(i, dxl1.Packet1), lambda: dec.bytes_skipped)


DYNAMIXEL1 = FuzzTarget("dynamixel1", "Dynamixel Protocol 1.0 decoder", _dynamixel1, DYNAMIXEL_LINE,
                           "4.5 Mbaud RS-485 bus", dynamixel1_traffic)


__all__ = ["DYNAMIXEL", "DYNAMIXEL1", "DYNAMIXEL_LINE", "dynamixel1_traffic", "dynamixel_traffic"]
