"""Profiles from Feetech bus captures (STS/SCS servos: the SO-100/SO-101 arms): the family's inferrer plug-in.

The ``hilbench.inferrers`` entry point ``feetech`` (:data:`INFERRER`) reads
``feetech`` traffic with the servo-bus kit
(:mod:`hilbench.families.servo_bus_inference`). Feetech's packets are
Protocol 1.0-framed (instructions and statuses told apart as
the Protocol 1.0 monitor does); what differs is said here:
SYNC_READ 0x82 answered servo by servo in request order, a broadcast PING
answered by every servo, the model number at address 3 (big-endian on the
SCS), Response Status Level 0 answering reads and pings only.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from hilbench.families.feetech import FEETECH_BAUDS
from hilbench.families.servo_bus_inference import (
    Damaged,
    DecoderSplitter,
    ItemDecoder,
    Owed,
    Reply,
    Request,
    ServoBusInferrer,
    ServoDialect,
)
from hilbench.protocols import feetech as ft
from hilbench.protocols.control_table import Model
from hilbench.protocols.feetech_models import MODELS
from hilbench.protocols.problem import Problem
from hilbench.transports.chunk import Chunk

_I = ft.Instruction
_INSTRUCTIONS = frozenset(int(i) for i in _I)
_ACKED = {_I.WRITE, _I.REG_WRITE, _I.ACTION, _I.RESET}


def _request(pkt: ft.Packet1, t: float, source: str) -> Request:
    ins, dev, p = pkt.code, pkt.id, pkt.params
    req = Request(t, pkt.raw, ft.INSTRUCTION_NAMES.get(ins, f"0x{ins:02x}"), dev, source=source)
    unicast = dev != ft.BROADCAST_ID
    if ins == _I.PING:
        if unicast:
            req.owed.append(Owed(dev, "ping"))
        else:
            req.any_may_answer = True
    elif ins == _I.READ:
        if len(p) != 2:
            raise ValueError("read")
        req.reads.append((dev, p[0], p[1]))
        if unicast:
            req.owed.append(Owed(dev, "read", p[0], p[1]))
    elif ins in (_I.WRITE, _I.REG_WRITE):
        if len(p) < 2:
            raise ValueError("no data")
        req.writes.append((dev, p[0], bytes(p[1:])))
        if unicast:
            req.owed.append(Owed(dev, "ack"))
    elif ins == _I.SYNC_READ:
        if len(p) < 2:
            raise ValueError("sync read")
        for i in p[2:]:
            req.reads.append((i, p[0], p[1]))
            req.owed.append(Owed(i, "read", p[0], p[1]))
    elif ins == _I.SYNC_WRITE:
        address, length = p[0], p[1]
        if not length or (len(p) - 2) % (length + 1):
            raise ValueError("sync write entries")
        for k in range(2, len(p), length + 1):
            req.writes.append((p[k], address, bytes(p[k + 1 : k + 1 + length])))
    elif ins in _ACKED and unicast:
        req.owed.append(Owed(dev, "ack"))
    return req


class _Decoder(ItemDecoder):
    """Feetech packets: a reply when its ID owes one of its length, or when its code is no instruction."""

    def __init__(self) -> None:
        self.dec = ft.Decoder1()
        self.t = 0.0

    def feed(self, chunk: Chunk, owes) -> Iterator:
        self.t = chunk.t
        # one by one: whether a packet is a reply depends on what the packets before it in the chunk asked
        # (a raw dump is read in large chunks holding many request/reply pairs)
        return (self._item(i, chunk.t, chunk.source, owes) for i in self.dec.feed(chunk.data, chunk.t))

    def flush(self) -> list:
        return [self._item(i, self.t, "", lambda i, n: False) for i in self.dec.flush(self.t)]

    @staticmethod
    def _item(it: Any, t: float, source: str, owes) -> Any:
        if isinstance(it, Problem):
            return Damaged(t, it.raw, it.kind)
        if owes(it.id, len(it.params)) or it.code not in _INSTRUCTIONS:
            return Reply(t, it.id, it.code, it.params, it.raw, source)
        try:
            return _request(it, t, source)
        except (IndexError, ValueError):
            return Damaged(t, it.raw, "layout")


class FeetechDialect(ServoDialect):
    """Feetech STS/SCS servos."""

    traffic = "feetech"
    family = "feetech"
    title = "Feetech STS/SCS"
    endpoint_name = "bus"
    bauds = FEETECH_BAUDS
    default_baud = 1_000_000
    models = tuple(MODELS.values())
    model_address = 3
    ping_length = 0
    data_offset = 5  # FF FF ID LEN ERR
    check_size = 1
    read_level = 0
    ack_level = 1

    def decoder(self) -> ItemDecoder:
        return _Decoder()

    def splitter(self) -> DecoderSplitter:
        return DecoderSplitter(ft.Decoder1(), lambda item: not isinstance(item, Problem))

    def position_range(self, model: Model) -> tuple[int, int]:
        return 0, model.motion.position_max if model.motion else 4095


#: The ``hilbench.inferrers`` plug-in: Feetech STS/SCS buses.
INFERRER = ServoBusInferrer("Feetech STS/SCS servo buses", (FeetechDialect(),))

__all__ = ["INFERRER", "FeetechDialect"]
