"""Profiles from Dynamixel bus captures (Protocol 2.0 and 1.0): the family's inferrer plug-in.

The ``hilbench.inferrers`` entry point ``dynamixel`` (:data:`INFERRER`)
reads ``dynamixel`` and ``dynamixel1`` traffic with the servo-bus kit
(:mod:`hilbench.families.servo_bus_inference`); this module says what the
bytes mean: the instructions of each protocol, who owes which status (a
Fast Sync/Bulk Read's one combined packet from ID FE, the USB2AX's one
combined reply from ID FD to its SYNC_READ), what a Ping reply carries (the
model number and firmware in Protocol 2.0, nothing in 1.0), and the models
each bus may hold. An ID no model fits becomes a ``control-table`` board
(:mod:`hilbench.protocols.dynamixel_custom_board`) of the registers its host
touched.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from typing import Any

from hilbench.bench.capture_profile import Table
from hilbench.families.dynamixel import DYNAMIXEL_BAUDS, PROTOCOL1_BAUDS, PROTOCOL1_TRAFFIC, speaks_protocol1
from hilbench.families.servo_bus_inference import (
    Damaged,
    DecoderSplitter,
    ItemDecoder,
    Owed,
    Reply,
    Request,
    ServoBusInferrer,
    ServoDialect,
    hex_number,
)
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols.control_table import Model
from hilbench.protocols.dynamixel_custom_board import CONTROL_TABLE
from hilbench.protocols.dynamixel_models import MODELS
from hilbench.protocols.problem import Problem
from hilbench.transports.chunk import Chunk

_U16 = struct.Struct("<H")
_HH = struct.Struct("<HH")
_I = dxl.Instruction
_ACKED = {_I.WRITE, _I.REG_WRITE, _I.ACTION, _I.FACTORY_RESET, _I.REBOOT, _I.CLEAR, _I.BACKUP}


def _custom_board(dev_id: int, number: int | None, firmware: int | None, registers: list[dict[str, Any]]) -> Table:
    table = Table()
    table.set("model", CONTROL_TABLE)
    table.set("id", dev_id)
    table.set("model_number", hex_number(number if number is not None else 0),
              "from its Ping reply" if number is not None else "none seen: 0")
    if firmware is not None:
        table.set("firmware", firmware)
    table.set("registers", registers, "the ranges its host read and wrote")
    return table


# ------------------------------------------------------------------------------------------- Protocol 2.0


class _Protocol2Decoder(ItemDecoder):
    def __init__(self) -> None:
        self.dec = dxl.Decoder()
        self.t = 0.0

    def feed(self, chunk: Chunk, owes: Callable[[int, int], bool]) -> list:
        self.t = chunk.t
        return [self._item(i, chunk.t, chunk.source) for i in self.dec.feed(chunk.data, chunk.t)]

    def flush(self) -> list:
        return [self._item(i, self.t, "") for i in self.dec.flush(self.t)]

    @staticmethod
    def _item(it: Any, t: float, source: str) -> Any:
        if isinstance(it, Problem):
            return Damaged(t, it.raw, it.kind)
        if isinstance(it, dxl.StatusPacket):
            return Reply(t, it.id, it.error, it.data, it.raw, source)
        try:
            return _request(it, t, source)
        except (struct.error, IndexError, ValueError):
            return Damaged(t, it.raw, "layout")


def _request(pkt: dxl.InstructionPacket, t: float, source: str) -> Request:
    ins, dev, p = pkt.instruction, pkt.id, pkt.params
    req = Request(t, pkt.raw, pkt.name, dev, source=source)
    unicast = dev != dxl.BROADCAST_ID
    if ins == _I.PING:
        if unicast:
            req.owed.append(Owed(dev, "ping"))
        else:
            req.any_may_answer = True
    elif ins == _I.READ:
        address, length = _HH.unpack(p)
        req.reads.append((dev, address, length))
        if unicast:
            req.owed.append(Owed(dev, "read", address, length))
    elif ins in (_I.WRITE, _I.REG_WRITE):
        (address,) = _U16.unpack_from(p)
        if len(p) < 3:
            raise ValueError("no data")
        req.writes.append((dev, address, bytes(p[2:])))
        if unicast:
            req.owed.append(Owed(dev, "ack"))
    elif ins in (_I.SYNC_READ, _I.FAST_SYNC_READ):
        address, length = _HH.unpack_from(p)
        for i in p[4:]:
            req.reads.append((i, address, length))
            req.owed.append(Owed(i, "read", address, length))
        if ins == _I.FAST_SYNC_READ:
            req.combined = dxl.BROADCAST_ID
    elif ins in (_I.BULK_READ, _I.FAST_BULK_READ):
        if len(p) % 5:
            raise ValueError("bulk read entries")
        for k in range(0, len(p), 5):
            i = p[k]
            address, length = _HH.unpack_from(p, k + 1)
            req.reads.append((i, address, length))
            req.owed.append(Owed(i, "read", address, length))
        if ins == _I.FAST_BULK_READ:
            req.combined = dxl.BROADCAST_ID
    elif ins == _I.SYNC_WRITE:
        address, length = _HH.unpack_from(p)
        if not length or (len(p) - 4) % (length + 1):
            raise ValueError("sync write entries")
        for k in range(4, len(p), length + 1):
            req.writes.append((p[k], address, bytes(p[k + 1 : k + 1 + length])))
    elif ins == _I.BULK_WRITE:
        k = 0
        while k < len(p):
            i = p[k]
            address, length = _HH.unpack_from(p, k + 1)
            data = bytes(p[k + 5 : k + 5 + length])
            if len(data) != length:
                raise ValueError("bulk write entries")
            req.writes.append((i, address, data))
            k += 5 + length
    elif ins in _ACKED and unicast:
        req.owed.append(Owed(dev, "ack"))
    return req


class Protocol2Dialect(ServoDialect):
    """Dynamixel Protocol 2.0: X and MX(2.0) servos, the XL-320, custom boards."""

    traffic = "dynamixel"
    family = "dynamixel"
    title = "Dynamixel Protocol 2.0"
    endpoint_name = "dxl"
    endpoint_extra: dict[str, Any] = {}
    bauds = DYNAMIXEL_BAUDS
    default_baud = 57_600
    models = tuple(m for m in MODELS.values() if m.protocol == 2)
    model_address = 0
    ping_length = 3
    data_offset = 9  # FF FF FD 00 ID LEN LEN 55 ERR
    check_size = 2
    read_level = 1
    ack_level = 2

    def decoder(self) -> ItemDecoder:
        return _Protocol2Decoder()

    def splitter(self) -> DecoderSplitter:
        return DecoderSplitter(dxl.Decoder(), lambda item: isinstance(item, dxl.StatusPacket))

    def ping_data(self, reply: Reply) -> tuple[int, int | None] | None:
        if len(reply.data) != 3:
            return None
        return _U16.unpack_from(reply.data)[0], reply.data[2]

    def damaged_ping(self, raw: bytes, dev_id: int) -> tuple[int, int | None] | None:
        # FF FF FD 00 ID 07 00 55 ERR MODEL_L MODEL_H FW CRC CRC
        if len(raw) == 14 and raw[4] == dev_id and raw[5:8] == b"\x07\x00\x55":
            return _U16.unpack_from(raw, 9)[0], raw[11]
        return None

    def split_combined(self, reply: Reply, request: Request) -> list[Reply]:
        slices = dxl.split_fast_reply(reply.raw, [o.length for o in request.owed])
        return [Reply(reply.t, s.id, s.error, s.data, b"", reply.source) for s in slices if s.crc_ok]

    def position_range(self, model: Model) -> tuple[int, int]:
        if model.motion is not None:
            return 0, model.motion.position_max
        return -1_048_575, 1_048_575

    def custom_board(self, dev_id: int, number: int | None, firmware: int | None,
                     registers: list[dict[str, Any]]) -> Table:
        return _custom_board(dev_id, number, firmware, registers)


# ------------------------------------------------------------------------------------------- Protocol 1.0

_P1 = p1.Instruction1
_P1_INSTRUCTIONS = frozenset(int(i) for i in _P1)
_P1_ACKED = {_P1.WRITE, _P1.REG_WRITE, _P1.ACTION, _P1.RESET, _P1.REBOOT}


class _Protocol1Decoder(ItemDecoder):
    """Protocol 1.0 packets: instruction and status share one layout, so a packet is a reply when its ID
    owes one of its length, or when its code is no instruction (as the Protocol 1.0 monitor tells them)."""

    def __init__(self, instructions: frozenset[int], request: Callable[[p1.Packet1, float, str], Request]) -> None:
        self.dec = p1.Decoder1()
        self.instructions = instructions
        self.request = request
        self.t = 0.0

    def feed(self, chunk: Chunk, owes: Callable[[int, int], bool]) -> Iterator:
        self.t = chunk.t
        # one by one: whether a packet is a reply depends on what the packets before it in the chunk asked
        # (a raw dump is read in large chunks holding many request/reply pairs)
        return (self._item(i, chunk.t, chunk.source, owes) for i in self.dec.feed(chunk.data, chunk.t))

    def flush(self) -> list:
        return [self._item(i, self.t, "", lambda i, n: False) for i in self.dec.flush(self.t)]

    def _item(self, it: Any, t: float, source: str, owes: Callable[[int, int], bool]) -> Any:
        if isinstance(it, Problem):
            return Damaged(t, it.raw, it.kind)
        if owes(it.id, len(it.params)) or it.code not in self.instructions:
            return Reply(t, it.id, it.code, it.params, it.raw, source)
        try:
            return self.request(it, t, source)
        except (struct.error, IndexError, ValueError):
            return Damaged(t, it.raw, "layout")


def _p1_request(pkt: p1.Packet1, t: float, source: str) -> Request:
    ins, dev, p = pkt.code, pkt.id, pkt.params
    name = p1.INSTRUCTION_NAMES.get(ins, f"0x{ins:02x}")
    req = Request(t, pkt.raw, name, dev, source=source)
    unicast = dev != p1.BROADCAST_ID
    if ins == _P1.PING:
        if unicast:
            req.owed.append(Owed(dev, "ping"))
    elif ins == _P1.READ:
        address, length = p[0], p[1]
        if len(p) != 2:
            raise ValueError("read")
        req.reads.append((dev, address, length))
        if unicast:
            req.owed.append(Owed(dev, "read", address, length))
    elif ins in (_P1.WRITE, _P1.REG_WRITE):
        if len(p) < 2:
            raise ValueError("no data")
        req.writes.append((dev, p[0], bytes(p[1:])))
        if unicast:
            req.owed.append(Owed(dev, "ack"))
    elif ins == _P1.SYNC_WRITE:
        address, length = p[0], p[1]
        if not length or (len(p) - 2) % (length + 1):
            raise ValueError("sync write entries")
        for k in range(2, len(p), length + 1):
            req.writes.append((p[k], address, bytes(p[k + 1 : k + 1 + length])))
    elif ins == _P1.SYNC_READ:  # the USB2AX's: one combined reply from ID FD
        address, length = p[0], p[1]
        for i in p[2:]:
            req.reads.append((i, address, length))
            req.owed.append(Owed(i, "read", address, length))
        req.combined = p1.USB2AX_ID
    elif ins == _P1.BULK_READ:
        if not p or p[0] != 0 or (len(p) - 1) % 3:
            raise ValueError("bulk read entries")
        for k in range(1, len(p), 3):
            length, i, address = p[k], p[k + 1], p[k + 2]
            req.reads.append((i, address, length))
            req.owed.append(Owed(i, "read", address, length))
    elif ins in _P1_ACKED and unicast:
        req.owed.append(Owed(dev, "ack"))
    return req


class Protocol1Dialect(ServoDialect):
    """Dynamixel Protocol 1.0: AX, MX with 1.0 firmware, X series switched to Protocol 1.0; a USB2AX."""

    traffic = PROTOCOL1_TRAFFIC
    family = "dynamixel"
    title = "Dynamixel Protocol 1.0"
    endpoint_name = "dxl"
    endpoint_extra = {"protocol_version": 1}
    bauds = PROTOCOL1_BAUDS
    default_baud = 1_000_000
    models = tuple(sorted((m for m in MODELS.values() if m.protocol == 1 or speaks_protocol1(m)),
                          key=lambda m: m.protocol != 1))
    model_address = 0
    ping_length = 0
    data_offset = 5  # FF FF ID LEN ERR
    check_size = 1
    read_level = 1
    ack_level = 2

    def decoder(self) -> ItemDecoder:
        return _Protocol1Decoder(_P1_INSTRUCTIONS, _p1_request)

    def splitter(self) -> DecoderSplitter:
        return DecoderSplitter(p1.Decoder1(), lambda item: not isinstance(item, Problem))

    def split_combined(self, reply: Reply, request: Request) -> list[Reply]:
        out, pos = [], 0
        for o in request.owed:
            data = reply.data[pos : pos + o.length]
            pos += o.length
            if len(data) == o.length and data != bytes([p1.USB2AX_MISSING]) * o.length:
                out.append(Reply(reply.t, o.id, 0, data, b"", reply.source))
        return out

    def profile_model(self, model: Model) -> str:
        return model.name

    def position_range(self, model: Model) -> tuple[int, int]:
        if model.motion is not None:
            return 0, model.motion.position_max
        return -1_048_575, 1_048_575


#: The ``hilbench.inferrers`` plug-in: Dynamixel Protocol 2.0 and 1.0 buses.
INFERRER = ServoBusInferrer("Dynamixel servo buses (Protocol 2.0 and 1.0)", (Protocol2Dialect(), Protocol1Dialect()))

__all__ = ["INFERRER", "Protocol1Dialect", "Protocol2Dialect"]
